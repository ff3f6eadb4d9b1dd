"""OBSBench ManiSkill3 tasks: `--env.type=obsbench` and gymnasium ids `obsbench/<task>`; Meta-World's
(`envs.metaworld`): `--env.type=obsbench_metaworld` and `obsbench_metaworld/<task>`.

Importing this package is cheap: ManiSkill itself is imported only when an env is made.
"""

import gymnasium as gym

from lerobot_obsbench.envs import metaworld, tasks  # noqa: F401  (register Meta-World and every task module)
from lerobot_obsbench.envs.base_task import TASKS, TaskError, eval_seeds, task_spec
from lerobot_obsbench.envs.configuration import ObsBenchEnvConfig

for _name, _task in TASKS.items():
    if f"obsbench/{_name}" not in gym.registry:
        # max_episode_steps here only declares the default; ObsBenchEnv passes the configured budget to
        # ManiSkill, and gym.make's TimeLimit (read by lerobot-eval as _max_episode_steps) follows the kwarg.
        gym.register(
            id=f"obsbench/{_name}",
            entry_point="lerobot_obsbench.envs.maniskill:make_obsbench_env",
            kwargs={"task": _name},
            max_episode_steps=_task.max_steps,
        )

__all__ = ["TASKS", "ObsBenchEnvConfig", "TaskError", "eval_seeds", "task_spec"]
