"""Success-rate evaluation of a trained policy on the fixed held-out seeds of an OBSBench task.

Episode i uses seed `eval_seeds(n, split)[i]` (test: 0, 1, ..., n-1; validation, for checkpoint selection:
10000, ...) for the env and for torch's generator, so a given checkpoint, task and seed list always gives the
same result on the same machine. The policy sees exactly
what stock `lerobot-eval` would feed it (LeRobot's `preprocess_observation`, then the checkpoint's own
pre/post-processors).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from lerobot_obsbench.envs.base_task import eval_seeds, task_spec
from lerobot_obsbench.envs.maniskill import CONTROL_FPS, DEFAULT_CONTROL_MODE, STATE_DIM, ObsBenchEnv
from lerobot_obsbench.outputs import write_json_atomic, write_text_atomic
from lerobot_obsbench.policies.loading import load_policy
from lerobot_obsbench.schema import check_compatibility
from lerobot_obsbench.stats import per_seed, success_summary


def check_compatible(config, env: ObsBenchEnv) -> None:
    """Refuse a policy whose cameras, image size, state or action do not match the env (clear message)."""
    check_compatibility(config, env.cameras, (env.image_size, env.image_size), STATE_DIM, env.action_space.shape[0])


def _batched(obs):
    if isinstance(obs, dict):
        return {k: _batched(v) for k, v in obs.items()}
    return np.expand_dims(obs, 0)


def evaluate(
    policy_path: str | Path,
    task: str,
    episodes: int,
    image_size: int | None = None,
    control_mode: str = DEFAULT_CONTROL_MODE,
    episode_length: int | None = None,
    device: str = "cpu",
    video_dir: Path | None = None,
    asset_dir: str | None = None,
    perturbation: str | None = None,
    progress: bool = True,
    split: str = "test",
    progress_file: Path | None = None,
) -> dict:
    """Success rate of a checkpoint over the `split`'s first `episodes` seeds (`eval_seeds`). The policy runs on
    `device` and so does the simulator's renderer (its GPU for cuda). `progress_file` receives
    {"done", "episodes", "successes"} after every episode (for a grid's live progress)."""
    from lerobot.envs.utils import preprocess_observation

    spec = task_spec(task)
    policy, pre, post = load_policy(policy_path, device)
    cameras = getattr(policy.config, "cameras", None) or ["base_camera"]
    resolution = getattr(policy.config, "camera_resolution", None)
    size = image_size or (resolution[0] if resolution else 128)
    steps = episode_length or spec.max_steps
    env = ObsBenchEnv(
        task,
        cameras=cameras,
        image_size=size,
        control_mode=control_mode,
        asset_dir=asset_dir,
        episode_length=steps,
        perturbation=perturbation,
        device=device,
    )
    check_compatible(policy.config, env)
    records = []
    start = time.time()
    label = f"eval {task}" + (f" [{perturbation}]" if perturbation not in (None, "none") else "")
    seeds = eval_seeds(episodes, split)
    bar = tqdm(seeds, desc=label, unit="ep", disable=not progress)
    for seed in bar:
        torch.manual_seed(seed)
        obs, info = env.reset(seed=seed)
        policy.reset()
        frames = [env.render()] if video_dir else None
        length = 0
        while length < steps:
            length += 1
            batch = pre(preprocess_observation(_batched(obs)))
            with torch.inference_mode():
                action = post(policy.select_action(batch))
            obs, _, terminated, truncated, info = env.step(action[0].cpu().numpy())
            if frames is not None:
                frames.append(env.render())
            if info["is_success"] or terminated or truncated:
                break
        records.append(
            {
                "seed": seed,
                "success": bool(info["is_success"]),
                "length": length,
                **{k.removeprefix("sub_success/"): bool(v) for k, v in info.items() if k.startswith("sub_success/")},
            }
        )
        if frames is not None:
            from lerobot.utils.io_utils import write_video

            video_dir.mkdir(parents=True, exist_ok=True)
            write_video(str(video_dir / f"{task}_seed{seed}.mp4"), np.stack(frames), fps=CONTROL_FPS)
        wins = sum(r["success"] for r in records)
        bar.set_postfix(success=f"{wins}/{len(records)}")
        if progress_file is not None:
            write_json_atomic(progress_file, {"done": len(records), "episodes": len(seeds), "successes": wins})
    env.close()
    sub = {name: round(sum(r[name] for r in records) / len(records), 4) for name in spec.sub_success}
    return {
        "task": task,
        "policy_path": str(policy_path),
        "obs_space": getattr(policy.config, "obs_space", None),
        "policy_type": policy.config.type,
        **success_summary([r["success"] for r in records]),
        "seeds": [r["seed"] for r in records],
        "sub_success": sub,
        "episode_length_mean": round(float(np.mean([r["length"] for r in records])), 2),
        "per_episode": records,
        "per_seed": per_seed(
            [r["seed"] for r in records], [r["success"] for r in records], [r["length"] for r in records]
        ),
        "image_size": size,
        "control_mode": control_mode,
        "perturbation": perturbation or "none",
        "wall_s": round(time.time() - start, 1),
    }


def write_result(result: dict, out: Path | None) -> None:
    if out is not None:
        write_text_atomic(out, json.dumps(result, indent=2) + "\n")
