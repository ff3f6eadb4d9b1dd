"""The paper's real-robot tasks (its appendix "Real-World Setups") as presets for training and rollouts.

`obsbench preset --preset real-one-arm|real-two-arms` prints the policy fields for stock `lerobot-train` (ACT at
lr 5e-5, chunk 20 / 40, the crop box in the ChArUco world frame jittered by ±1 cm, ResNet-50 / PointNet);
`obsbench rollout --task NAME` takes the number of rollouts and the episode time from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot_obsbench.errors import ConfigError


@dataclass(frozen=True)
class RealTask:
    name: str
    description: str  # the task string recorded with every frame
    arms: int  # 1: obsbench_koch_follower + koch_leader; 2: obsbench_bi_koch_follower + obsbench_bi_koch_leader
    preset: str  # `obsbench preset --preset ...` for lerobot-train
    demos: int  # the paper's demonstration count
    epochs: int  # the paper's training epochs over those demonstrations
    rollouts: int  # the paper's evaluation rollouts
    episode_time_s: float  # recording and rollout budget per episode (not stated in the paper)


REAL_TASKS = {
    task.name: task
    for task in (
        RealTask("reach_cube", "reach towards the cube and touch it", 1, "real-one-arm", 45, 100, 20, 15.0),
        RealTask("pick_cube", "pick up the cube and hold it in the air", 1, "real-one-arm", 45, 500, 20, 20.0),
        RealTask(
            "fold_cloth",
            "grasp one side of the cloth with both grippers and fold it in half",
            2,
            "real-two-arms",
            50,
            1000,
            20,
            30.0,
        ),
    )
}


def real_task(name: str) -> RealTask:
    if name not in REAL_TASKS:
        raise ConfigError(f"Unknown real task {name!r}; choose one of {', '.join(REAL_TASKS)}.")
    return REAL_TASKS[name]
