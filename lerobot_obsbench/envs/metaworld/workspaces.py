"""Each Meta-World task's crop box, measured: the region its scripted expert's hand and the task's objects and goal
pass through in its successful episodes from the demonstration seeds, widened by `MARGIN` (objects and fingers
reach beyond the points measured), from the table's surface up, and never beyond the table's box
(`TABLE_WORKSPACE`). Bounds are rounded outwards to the centimetre, so the same episodes give the same box on any
machine.

    python -m lerobot_obsbench.envs.metaworld.workspaces [--episodes 20] [--tasks reach-v3 ...]

rewrites `workspaces.json` beside this file (the tasks named, the others kept), which `metaworld_tasks()` reads; a
task it lacks crops the whole table. Physics only (no camera): a few seconds a task.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from lerobot_obsbench.envs.base_task import DEMO_SEED_START
from lerobot_obsbench.envs.metaworld.tasks import TABLE_WORKSPACE, WORKSPACES_FILE, metaworld_task, metaworld_tasks
from lerobot_obsbench.numeric import number_argument

MARGIN = 0.1  # metres around every measured position
MAX_ATTEMPTS = 3  # seeds tried per successful episode wanted
HAND, OBJECT, OBJECT2 = slice(0, 3), slice(4, 7), slice(11, 14)  # in Meta-World's observation


def task_positions(task: str, episodes: int) -> np.ndarray:
    """(N, 3) world positions of the hand, the objects (a slot Meta-World leaves empty is skipped) and the goal at
    every step of the scripted expert's first `episodes` successful episodes from the demonstration seeds up, as
    `obsbench demos` keeps them (a failed attempt's wandering is in no demonstration)."""
    from lerobot_obsbench.envs.metaworld.env import MetaWorldEnv

    spec = metaworld_task(task)
    env = MetaWorldEnv(task, cameras=[])
    positions, successes = [], 0
    try:
        for seed in range(DEMO_SEED_START, DEMO_SEED_START + MAX_ATTEMPTS * episodes):
            env.reset(seed=seed)
            expert = spec.make_expert(env)
            episode = [np.asarray(env._env._target_pos, dtype=np.float64)]
            for _ in range(env.max_steps):
                obs = env.metaworld_observation
                episode += [obs[HAND], obs[OBJECT]] + ([obs[OBJECT2]] if np.any(obs[OBJECT2]) else [])
                if env.step(expert.act())[2]:
                    positions += episode
                    successes += 1
                    break
            if successes == episodes:
                return np.asarray(positions, dtype=np.float64)
    finally:
        env.close()
    raise RuntimeError(f"{task}: its expert succeeded {successes} times in {MAX_ATTEMPTS * episodes} attempts")


def crop_box(positions: np.ndarray) -> tuple[float, ...]:
    """(xmin, xmax, ymin, ymax, zmin, zmax): `positions` widened by `MARGIN`, from the table's surface
    (`TABLE_WORKSPACE`'s zmin) up, inside `TABLE_WORKSPACE`, rounded outwards to the centimetre."""
    table = np.asarray(TABLE_WORKSPACE).reshape(3, 2)
    low = np.maximum(np.floor((positions.min(axis=0) - MARGIN) * 100) / 100, table[:, 0])
    high = np.minimum(np.ceil((positions.max(axis=0) + MARGIN) * 100) / 100, table[:, 1])
    low[2] = table[2, 0]
    return tuple(round(float(value), 2) for value in np.stack([low, high], axis=1).ravel())


def measure(tasks: list[str], episodes: int) -> dict[str, list[float]]:
    boxes = {}
    for task in tasks:
        boxes[task] = list(crop_box(task_positions(task, episodes)))
        print(f"{task}: {boxes[task]}", flush=True)
    return boxes


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=number_argument(whole=True, minimum=1), default=20, help="successful ones")
    parser.add_argument("--tasks", nargs="+", help="default: every task LeRobot lists")
    args = parser.parse_args(argv)
    tasks = [metaworld_task(name).name for name in args.tasks] if args.tasks else list(metaworld_tasks())
    path = WORKSPACES_FILE
    stored = json.loads(path.read_text()) if path.exists() else {}
    if args.tasks and stored and stored.get("episodes") != args.episodes:
        raise SystemExit(
            f"{path} was measured over {stored['episodes']} episodes a task; measure with --episodes "
            f"{stored['episodes']}, or every task (no --tasks) with another count"
        )
    boxes = {**(stored.get("tasks", {}) if args.tasks else {}), **measure(tasks, args.episodes)}
    record = {
        "about": "each Meta-World task's crop box (m, world frame: xmin xmax ymin ymax zmin zmax), measured by "
        "lerobot_obsbench/envs/metaworld/workspaces.py",
        "command": "python -m lerobot_obsbench.envs.metaworld.workspaces",
        "episodes": args.episodes,
        "first_seed": DEMO_SEED_START,
        "margin_m": MARGIN,
        "tasks": {name: boxes[name] for name in metaworld_tasks() if name in boxes},
    }
    path.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {len(record['tasks'])} tasks' boxes to {path}")


if __name__ == "__main__":
    main()
