"""Evaluation speed against the lockstep batch size N (`obsbench eval --eval.batch_size N`), side by side in one run:

- with the policy: `envs.evaluate.evaluate` of each checkpoint on the same seeds at each N, in episodes per
  minute (wall time from env start to the last episode, as a grid's evaluation unit sees it) and per-seed results
  (the same at every N, or the difference is reported);
- without the policy: env steps per second of N envs stepped together with random actions (`envs.vector`),
  after they started, and the start-up time of the N envs.

    .venv/bin/python -m benchmarks.bench_eval [--checkpoints DIR ...] [--task PushCubeWide-v1] [--episodes 24]
        [--sizes 1 2 3 4] [--device cpu] [--sim-backend auto] [--out FILE]

On a GPU: `--device cuda --sizes 1 64 256 --episodes 256` (auto: ManiSkill's GPU simulation for N > 1).

The default checkpoints are the `quick` grid's DP3 point-cloud policy (most episodes succeed early) and its blind
control (most run the whole 50 steps), as `make main` trains them; the task and image size are the grid's. Writes
benchmarks/results/eval_<device>.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.common import ROOT, write
from lerobot_obsbench.envs.evaluate import choose_sim_backend, evaluate, make_eval_envs


def quick_checkpoint(obs_space: str) -> Path | None:
    """The last checkpoint of the quick grid's run on `obs_space`, if `make main` left one here."""
    for run in sorted((ROOT / "outputs" / "bench" / "quick" / "runs").glob("*/run.json")):
        if json.loads(run.read_text()).get("obs_space") == obs_space:
            found = sorted(run.parent.glob("train/checkpoints/*/pretrained_model"))
            if found:
                return found[-1]
    return None


def with_policy(checkpoint: Path, args) -> list[dict]:
    rows, reference = [], None
    for size in args.sizes:
        start = time.perf_counter()
        result = evaluate(
            checkpoint,
            args.task,
            args.episodes,
            device=args.device,
            progress=False,
            batch_size=size,
            sim_backend=args.sim_backend,
        )
        seconds = time.perf_counter() - start
        outcome = {k: result["per_seed"][k] for k in ("success", "length")}
        reference = reference or outcome
        row = {
            "batch_size": size,
            "sim_backend": result["sim_backend"],
            "episodes_per_min": round(60 * args.episodes / seconds, 1),
            "seconds": round(seconds, 1),
            "env_steps": int(sum(result["per_seed"]["length"])),
            "same_results_as_first": outcome == reference,
            **outcome,
        }
        rows.append(row)
        print(
            f"{checkpoint.parts[-5] if len(checkpoint.parts) > 5 else checkpoint} N={size}: "
            f"{row['episodes_per_min']} episodes/min ({row['seconds']} s), same results: {row['same_results_as_first']}"
        )
    return rows


def env_steps_per_second(env_kwargs: dict, size: int, steps: int, sim_backend: str) -> dict:
    sim = choose_sim_backend(sim_backend, env_kwargs["device"], size, None)
    start = time.perf_counter()
    envs = make_eval_envs(env_kwargs, size, sim)
    started = time.perf_counter() - start
    try:
        depth = envs.reset(list(range(size)))["robot_state"][f"depth.{env_kwargs['cameras'][0]}"]
        rng = np.random.default_rng(0)
        slots = list(range(size))
        begin = time.perf_counter()
        for _ in range(steps):
            envs.step(slots, rng.uniform(-1, 1, (size, 7)).astype(np.float32))
        rate = size * steps / (time.perf_counter() - begin)
    finally:
        envs.close()
    return {
        "batch_size": size,
        "sim_backend": sim,
        "env_steps_per_s": round(rate, 1),
        "start_s": round(started, 1),
        "depth": f"{depth.dtype} on {getattr(depth, 'device', 'host')}",  # what the policy's observation holds
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoints", type=Path, nargs="+", default=None)
    parser.add_argument("--task", default="PushCubeWide-v1")
    parser.add_argument("--episodes", type=int, default=24)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--steps", type=int, default=100, help="env steps per slot without the policy")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--sim-backend", default="auto", help="auto, physx_cpu or physx_cuda (obsbench eval's)")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    checkpoints = args.checkpoints or [quick_checkpoint("pointcloud"), quick_checkpoint("none")]
    if None in checkpoints:
        parser.error("no --checkpoints given and no quick-grid checkpoints under outputs/bench/quick (run make main)")
    config = json.loads((checkpoints[0] / "config.json").read_text())
    image_size = config["camera_resolution"][0]
    policies = {str(c.relative_to(ROOT) if c.is_relative_to(ROOT) else c): with_policy(c, args) for c in checkpoints}
    env_kwargs = dict(
        task=args.task, cameras=config.get("cameras") or ["base_camera"], image_size=image_size, device=args.device
    )
    without_policy = []
    for size in args.sizes:
        row = env_steps_per_second(env_kwargs, size, args.steps, args.sim_backend)
        without_policy.append(row)
        print(f"N={size} without the policy: {row['env_steps_per_s']} env steps/s (start {row['start_s']} s)")
    best = {}
    for name, rows in policies.items():
        top = max(rows, key=lambda r: r["episodes_per_min"])
        best[name] = top["batch_size"]
        print(f"{name}: best N={top['batch_size']}, {top['episodes_per_min'] / rows[0]['episodes_per_min']:.2f}x N=1")
    write(
        f"eval_{args.device.split(':')[0]}",
        {
            "task": args.task,
            "image_size": image_size,
            "episodes": args.episodes,
            "device": args.device,
            "with_policy": policies,
            "without_policy": without_policy,
            "best_batch_size": best,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
