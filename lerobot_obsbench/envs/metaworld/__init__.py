"""Meta-World (MuJoCo) tasks as OBSBench tasks, beside the ManiSkill ones: LeRobot's own Meta-World task list
(`tasks.py`), the env that renders what the plugin's sensor schema needs (`env.py`: colour, metric depth, the
camera's intrinsics and pose, the robot state, the oracle's object poses) and the headless OpenGL it renders with
(`rendering.py`).

Importing this package is cheap: Meta-World and MuJoCo are imported only when an env is made. It chooses MuJoCo's
headless OpenGL back-end (`MUJOCO_GL`, unless set) now, since MuJoCo reads it once, when it is first imported, and
ManiSkill imports MuJoCo too.
"""

import gymnasium as gym

from lerobot_obsbench.envs.metaworld.configuration import GYM_NAMESPACE, MetaWorldEnvConfig
from lerobot_obsbench.envs.metaworld.rendering import prefer_headless_gl
from lerobot_obsbench.envs.metaworld.tasks import MAX_STEPS, metaworld_tasks

prefer_headless_gl()
for _name in metaworld_tasks():
    if f"{GYM_NAMESPACE}/{_name}" not in gym.registry:
        gym.register(
            id=f"{GYM_NAMESPACE}/{_name}",
            entry_point="lerobot_obsbench.envs.metaworld.env:MetaWorldEnv",
            kwargs={"task": _name},
            max_episode_steps=MAX_STEPS,
        )

__all__ = ["MetaWorldEnvConfig"]
