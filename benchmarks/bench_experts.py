"""Each task's scripted expert on demonstration seeds: how often it succeeds and in how many steps, against the
task's episode budget (`max_steps`, which should hold twice the mean and the longest episode).

Each episode gets three times the budget, so a slow success is counted and its length measured, not cut off.
Without cameras (they do not change the physics).

    .venv/bin/python -m benchmarks.bench_experts [--simulator maniskill] [--tasks PickCube-v1 ...] [--episodes 20]
        [--out FILE]

Writes benchmarks/results/experts.json (`--simulator metaworld`: every Meta-World task LeRobot lists, into
experts_metaworld.json). The cost model prices recordings and frame_epochs budgets by the mean lengths
(`python -m benchmarks.refresh_rates`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.common import write
from lerobot_obsbench.envs.catalog import make_task_env, task_record
from lerobot_obsbench.envs.metaworld.tasks import metaworld_tasks

TASKS = [
    "PushCubeWide-v1",
    "PullCubeWide-v1",
    "PickCube-v1",
    "LiftPegUpright-v1",
    "StackCube-v1",
    "PegInsertionSide-v1",
]
FIRST_SEED = 100_000  # the first demonstration seed (docs/simulation.md#seeds-resuming-and-outputs)


def measure(task: str, episodes: int) -> dict:
    spec = task_record(task)
    env = make_task_env(task, cameras=(), image_size=32, episode_length=3 * spec.max_steps)
    lengths, start = [], time.perf_counter()
    try:
        for seed in range(FIRST_SEED, FIRST_SEED + episodes):
            env.reset(seed=seed)
            expert, steps, info = spec.make_expert(env), 0, {"is_success": False}
            while not info["is_success"] and steps < 3 * spec.max_steps and (action := expert.act()) is not None:
                info = env.step(action)[4]
                steps += 1
            if info["is_success"]:
                lengths.append(steps)
    finally:
        env.close()
    mean = float(np.mean(lengths)) if lengths else None
    return {
        "task": task,
        "episodes": episodes,
        "successes": len(lengths),
        "mean_steps": None if mean is None else round(mean, 1),
        "max_steps_taken": max(lengths) if lengths else None,
        "budget": spec.max_steps,
        "budget_over_mean": None if mean is None else round(spec.max_steps / mean, 2),
        "seconds": round(time.perf_counter() - start, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--simulator", choices=("maniskill", "metaworld"), default="maniskill")
    parser.add_argument("--tasks", nargs="+", help="default: the simulator's tasks")
    parser.add_argument("--episodes", type=int, choices=range(1, 10_001), metavar="N", default=20)
    parser.add_argument("--out", type=Path, default=None, help="default benchmarks/results/experts[_metaworld].json")
    args = parser.parse_args()
    metaworld = args.simulator == "metaworld"
    rows = []
    for task in args.tasks or (list(metaworld_tasks()) if metaworld else TASKS):
        rows.append(measure(task, args.episodes))
        print(rows[-1], flush=True)
    write("experts_metaworld" if metaworld else "experts", {"first_seed": FIRST_SEED, "rows": rows}, args.out)


if __name__ == "__main__":
    main()
