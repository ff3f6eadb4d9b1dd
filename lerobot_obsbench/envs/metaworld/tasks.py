"""The Meta-World tasks OBSBench knows: LeRobot's own list, read from the file LeRobot's `metaworld` env reads (the
task names, their descriptions, DP3's difficulty groups and each task's scripted expert), so the two never
disagree and LeRobot's Meta-World users find their task names here.

Each task runs with one camera or more of the Sawyer scene's (`CAMERAS`; LeRobot renders `corner2`, moved as it
moves it). The oracle control reads the poses of the task's objects (one or two; Meta-World's observation holds
two slots) and of its goal, a position given the identity rotation, so every value of the oracle's input is named
`<object>.<component>` as on the ManiSkill tasks.
"""

from __future__ import annotations

import difflib
import json
from dataclasses import dataclass
from functools import cache
from importlib import resources

from lerobot_obsbench.envs.base_task import TaskError

# The Sawyer scene's cameras (Meta-World's XML), and the one LeRobot's Meta-World env renders.
CAMERAS = ("topview", "corner", "corner2", "corner3", "behindGripper", "gripperPOV")
DEFAULT_CAMERA = "corner2"
# LeRobot moves `corner2` here (metres, world frame) and turns its image half a turn; OBSBench does the same, so a
# LeRobot Meta-World user sees the frames they know (the turn is folded into the camera pose).
CORNER2_POSITION = (0.75, 0.075, 0.7)
TURNED_CAMERAS = ("corner2",)
MAX_STEPS = 500  # Meta-World's episode budget (`max_path_length`), which LeRobot's env keeps
DIFFICULTIES = ("easy", "medium", "hard", "very_hard")  # DP3's groups, as LeRobot names them


@dataclass(frozen=True)
class MetaWorldTask:
    """One Meta-World task: its name (`drawer-open-v3`), LeRobot's description, DP3's difficulty group and the
    class name of its scripted expert in `metaworld.policies`."""

    name: str
    description: str
    difficulty: str
    expert: str


@cache
def _lerobot_config() -> dict:
    """LeRobot's Meta-World config, read as a file: importing `lerobot.envs.metaworld` imports Meta-World itself."""
    text = resources.files("lerobot.envs").joinpath("metaworld_config.json").read_text()
    return json.loads(text)


@cache
def metaworld_tasks() -> dict[str, MetaWorldTask]:
    """Every Meta-World task LeRobot lists, by name, in LeRobot's order."""
    config = _lerobot_config()
    difficulty = {task: group for group, tasks in config["DIFFICULTY_TO_TASKS"].items() for task in tasks}
    return {
        name: MetaWorldTask(name, description, difficulty.get(name, "unrated"), config["TASK_POLICY_MAPPING"][name])
        for name, description in config["TASK_DESCRIPTIONS"].items()
    }


def tasks_of(difficulty: str) -> list[str]:
    """The tasks of one of DP3's difficulty groups."""
    if difficulty not in DIFFICULTIES:
        raise TaskError(f"Meta-World difficulty must be one of {', '.join(DIFFICULTIES)}; got {difficulty!r}")
    return list(_lerobot_config()["DIFFICULTY_TO_TASKS"].get(difficulty, []))


def metaworld_task(name: str) -> MetaWorldTask:
    """The task named `name` (LeRobot's `metaworld-` prefix accepted); an unknown name is refused with the
    closest names."""
    tasks = metaworld_tasks()
    task = tasks.get(name.removeprefix("metaworld-"))
    if task is None:
        close = difflib.get_close_matches(name.removeprefix("metaworld-"), list(tasks), n=3, cutoff=0.5)
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise TaskError(
            f"unknown Meta-World task {name!r}{hint} ({len(tasks)} tasks, LeRobot's names, e.g. drawer-open-v3; "
            "every one: lerobot_obsbench.envs.metaworld.tasks.metaworld_tasks())"
        )
    return task


def check_cameras(task: MetaWorldTask, cameras: list[str] | tuple[str, ...]) -> None:
    """Refuse a camera the Sawyer scene does not have, naming the ones it has (none: the env renders nothing, for
    the blind and oracle controls)."""
    unknown = [camera for camera in cameras if camera not in CAMERAS]
    if unknown:
        raise TaskError(
            f"Meta-World task {task.name} has no camera {', '.join(map(repr, unknown))}; its cameras: "
            f"{', '.join(CAMERAS)} (LeRobot's is {DEFAULT_CAMERA})"
        )
