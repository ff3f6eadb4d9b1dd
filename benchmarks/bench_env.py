"""Env speed: steps/s of raw ManiSkill (state only; one 128² rgb+depth camera) vs the plugin's ObsBenchEnv
(same camera, converted to the schema), and expert episodes (attempts, successful or not) per minute with the
plugin's recorder path vs the same expert on raw ManiSkill, side by side in one run.

    .venv/bin/python -m benchmarks.bench_env [--steps 100] [--episodes 3] [--out FILE]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from benchmarks.common import write
from lerobot_obsbench import schema
from lerobot_obsbench.envs.base_task import TASKS
from lerobot_obsbench.envs.maniskill import ObsBenchEnv, import_maniskill


def steps_per_second(env, steps: int, action_space) -> float:
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    start = time.perf_counter()
    for _ in range(steps):
        env.step(rng.uniform(-1, 1, action_space.shape).astype(np.float32))
    return steps / (time.perf_counter() - start)


def expert_episodes_per_minute(env, expert_cls, episodes: int, step_fn) -> tuple[float, float]:
    start, wins = time.perf_counter(), 0
    for seed in range(100_000, 100_000 + episodes):
        env.reset(seed=seed)
        expert = expert_cls(env)
        for _ in range(100):
            action = expert.act()
            if action is None:
                break
            if step_fn(action):
                wins += 1
                break
    return 60 * episodes / (time.perf_counter() - start), wins / episodes


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--task", default="PickCube-v1")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    import_maniskill()
    kw = dict(control_mode="pd_ee_delta_pose", num_envs=1)
    cam = dict(sensor_configs=dict(width=args.size, height=args.size))
    raw_state = gym.make(args.task, obs_mode="state", **kw)
    raw_rgbd = gym.make(args.task, obs_mode="rgb+depth", **cam, **kw)
    plugin = ObsBenchEnv(args.task, image_size=args.size)
    space = plugin.action_space
    # interleave the two camera paths so both see the same machine load
    rates = {"raw_state": [], "raw_rgb_depth": [], "plugin_rgb_depth": []}
    for _ in range(3):
        rates["raw_state"].append(steps_per_second(raw_state, args.steps * 5, space))
        rates["raw_rgb_depth"].append(steps_per_second(raw_rgbd, args.steps, space))
        rates["plugin_rgb_depth"].append(steps_per_second(plugin, args.steps, space))
    steps = {k: round(float(np.median(v)), 1) for k, v in rates.items()}
    overhead = steps["raw_rgb_depth"] / steps["plugin_rgb_depth"] - 1
    print(
        f"{args.task} steps/s: raw state {steps['raw_state']}, raw rgb+depth {steps['raw_rgb_depth']}, plugin "
        f"{steps['plugin_rgb_depth']} -> wrapper overhead {overhead:.1%}"
    )
    raw_state.close()
    raw_rgbd.close()
    plugin.close()

    demos = {}
    for task, expert_cls in ((name, spec.expert) for name, spec in TASKS.items() if spec.expert):
        ours = ObsBenchEnv(task, image_size=args.size)

        def plugin_step(action, env=ours):
            obs, _, _, _, info = env.step(action)
            schema.env_observation_to_frame(obs)  # what the recorder stores each step
            return info["is_success"]

        per_min, success = expert_episodes_per_minute(ours, expert_cls, args.episodes, plugin_step)
        raw = gym.make(task, obs_mode="rgb+depth", **cam, **kw)
        raw.unwrapped_ms = raw.unwrapped

        def raw_step(action, env=raw):
            _, _, _, _, info = env.step(action)
            return bool(info["success"][0])

        raw_per_min, _ = expert_episodes_per_minute(raw, expert_cls, args.episodes, raw_step)
        demos[task] = {
            "plugin_episodes_per_min": round(per_min, 1),
            "raw_episodes_per_min": round(raw_per_min, 1),
            "expert_success_in_run": success,
        }
        print(
            f"{task}: {per_min:.1f} expert episodes/min with the plugin, {raw_per_min:.1f} raw ManiSkill "
            f"(expert success {success:.0%} of {args.episodes})"
        )
        ours.close()
        raw.close()
    write(
        "env",
        {
            "task": args.task,
            "image_size": args.size,
            "steps_per_s": steps,
            "wrapper_overhead": round(overhead, 3),
            "target_overhead": 0.2,
            "demos": demos,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
