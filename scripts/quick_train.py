#!/usr/bin/env python
"""The README's main job for now: the smallest real end-to-end training run of the plugin.

1. writes a synthetic OBSBench-schema dataset with stock LeRobot (move the gripper above a red cube placed at
   random; the cube's position is NOT given to the policy, so it must find it in its observations);
2. trains obs_act with stock `lerobot-train` on the first 30 episodes, once per observation space, with the
   small CPU preset;
3. scores each checkpoint on 6 held-out episodes: mean L1 error of the predicted (normalised) action chunk,
   next to the error of always predicting the mean training action.

Lower than the mean-action error means the policy uses what it sees. This is a pipeline check on a toy task,
not a benchmark result: the simulator benchmark (`obsbench run`) replaces it.

    .venv/bin/python scripts/quick_train.py [--steps 300] [--spaces pointcloud rgb] [--out outputs/quick]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
TRAIN_EPISODES, TEST_EPISODES = 30, 6
WORKSPACE = "[-0.5,0.5,-0.5,0.5,0.005,0.5]"


def make_dataset(out: Path) -> Path:
    from scripts.make_synthetic_dataset import write_dataset

    done = out / "meta" / "info.json"
    if done.is_file():
        return out
    shutil.rmtree(out, ignore_errors=True)  # a half-written dataset from a killed run: it is cheap to redo
    return write_dataset(out, TRAIN_EPISODES + TEST_EPISODES, frames=10, size=48, seed=3, with_goal=False)


def train(dataset: Path, run_dir: Path, obs_space: str, steps: int) -> Path:
    from lerobot_obsbench.presets import preset_args

    ckpt = run_dir / "checkpoints" / "last" / "pretrained_model"
    if ckpt.is_dir():
        print(f"[{obs_space}] checkpoint exists, skipping training: {ckpt}")
        return ckpt
    shutil.rmtree(run_dir, ignore_errors=True)
    cmd = [
        str(Path(sys.executable).parent / "lerobot-train"), "--policy.type=obs_act", f"--policy.obs_space={obs_space}",
        "--policy.device=cpu", *preset_args("cpu", "obs_act", obs_space), f"--policy.workspace={WORKSPACE}",
        "--policy.optimizer_lr=1e-3", "--dataset.repo_id=local/quick", f"--dataset.root={dataset}",
        f"--dataset.episodes=[{','.join(str(i) for i in range(TRAIN_EPISODES))}]", "--batch_size=16",
        f"--steps={steps}", f"--save_freq={steps}", f"--log_freq={max(steps // 10, 1)}", "--num_workers=0",
        "--wandb.enable=false", f"--output_dir={run_dir}",
    ]
    print(f"[{obs_space}] {' '.join(cmd)}", flush=True)
    subprocess.run(cmd, check=True, stdin=subprocess.DEVNULL, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    return ckpt


@torch.no_grad()
def score(dataset: Path, ckpt: Path) -> dict:
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_obsbench.policies.obs_act.modeling_obs_act import ObsACTPolicy

    policy = ObsACTPolicy.from_pretrained(ckpt).eval()
    pre, _ = make_pre_post_processors(policy.config, pretrained_path=str(ckpt))
    meta = LeRobotDatasetMetadata("local/quick", root=dataset)
    deltas = resolve_delta_timestamps(policy.config, meta)

    def batch(episodes):
        ds = LeRobotDataset("local/quick", root=dataset, episodes=episodes, delta_timestamps=deltas)
        return pre(next(iter(torch.utils.data.DataLoader(ds, batch_size=len(ds)))))

    train_actions = batch(list(range(TRAIN_EPISODES)))["action"]
    test = batch(list(range(TRAIN_EPISODES, TRAIN_EPISODES + TEST_EPISODES)))
    valid = ~test["action_is_pad"][..., None]
    error = ((policy.model(test)[0] - test["action"]).abs() * valid).sum() / (valid.sum() * test["action"].shape[-1])
    baseline = ((train_actions.mean(dim=0) - test["action"]).abs() * valid).sum() / (valid.sum() * test["action"].shape[-1])
    return {"heldout_l1": round(error.item(), 4), "mean_action_l1": round(baseline.item(), 4),
            "ratio": round(error.item() / baseline.item(), 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--spaces", nargs="+", default=["pointcloud", "rgb"])
    parser.add_argument("--out", type=Path, default=ROOT / "outputs" / "quick")
    args = parser.parse_args()
    import lerobot_obsbench  # noqa: F401

    start = time.time()
    dataset = make_dataset(args.out / "dataset")
    results = {}
    for space in args.spaces:
        t0 = time.time()
        ckpt = train(dataset, args.out / f"obs_act_{space}", space, args.steps)
        results[space] = {**score(dataset, ckpt), "train_and_score_s": round(time.time() - t0, 1)}
    summary = {"task": "synthetic reach-the-cube (48x48, cube position hidden)", "policy": "obs_act (cpu preset)",
               "steps": args.steps, "train_episodes": TRAIN_EPISODES, "heldout_episodes": TEST_EPISODES,
               "results": results, "wall_s": round(time.time() - start, 1)}
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"\n{'space':12s} {'held-out L1':>12s} {'mean-action L1':>15s} {'ratio':>6s}")
    for space, r in results.items():
        print(f"{space:12s} {r['heldout_l1']:12.3f} {r['mean_action_l1']:15.3f} {r['ratio']:6.2f}")
    print(f"(lower is better; ratio < 1 means the policy uses its observations) - {args.out / 'summary.json'}")


if __name__ == "__main__":
    main()
