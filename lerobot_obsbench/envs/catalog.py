"""Every task the benchmark runs, whichever simulator simulates it: a name -> its task record, a ManiSkill `Task`
(envs/tasks/) or a `MetaWorldTask` (envs/metaworld/), told apart by how the name is written (`PickCube-v1`,
`drawer-open-v3`). Both records answer what the shared machinery asks of a task (demonstrations, evaluation,
grids, the cost model): its episode budget, cameras, crop box, expert and the oracle's objects."""

from __future__ import annotations

from lerobot_obsbench.envs.base_task import TASKS, TaskError, task_spec
from lerobot_obsbench.envs.metaworld.tasks import MetaWorldTask, is_metaworld_name, metaworld_task


def task_record(name: str):
    """The record of the task named `name`; an unknown name is refused with its simulator's closest names (a ManiSkill
    name written in lower case, which reads as a Meta-World one, with the ManiSkill name it stands for)."""
    if not is_metaworld_name(name):
        return task_spec(name)
    try:
        return metaworld_task(name)
    except TaskError as err:
        maniskill = [task for task in TASKS if task.lower() == name.lower()]
        if maniskill:
            raise TaskError(
                f"unknown task {name!r}: ManiSkill's task names are written in CamelCase; did you mean {maniskill[0]}?"
            ) from None
        raise err from None


def is_metaworld(record) -> bool:
    return isinstance(record, MetaWorldTask)


def make_task_env(task: str, **kwargs):
    """The env of `task`, in the sensor schema: Meta-World's (`MetaWorldEnv`) or ManiSkill's (`ObsBenchEnv`); a
    module-level function, so worker processes can build it."""
    if is_metaworld_name(task):
        from lerobot_obsbench.envs.metaworld.env import MetaWorldEnv

        return MetaWorldEnv(task, **kwargs)
    from lerobot_obsbench.envs.maniskill import ObsBenchEnv

    return ObsBenchEnv(task, **kwargs)
