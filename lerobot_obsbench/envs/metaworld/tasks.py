"""The Meta-World tasks OBSBench knows: LeRobot's own list, read from the file LeRobot's `metaworld` env reads (the
task names, their descriptions, DP3's difficulty groups and each task's scripted expert), so the two never
disagree and LeRobot's Meta-World users find their task names here.

Each task runs with one camera or more of the Sawyer scene's (`CAMERAS`; LeRobot renders `corner2`, moved as it
moves it). The oracle control reads Meta-World's two object slots (the second all zeros where a task has one
object) and the goal, a position given the identity rotation, so every value of the oracle's input is named
`<object>.<component>` as on the ManiSkill tasks, and every task's oracle reads the same 21 values.
"""

from __future__ import annotations

import difflib
import json
import re
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

from lerobot_obsbench.envs.base_task import TaskError

# The Sawyer scene's cameras (Meta-World's XML), and the one LeRobot's Meta-World env renders.
CAMERAS = ("topview", "corner", "corner2", "corner3", "behindGripper", "gripperPOV")
DEFAULT_CAMERA = "corner2"
# LeRobot moves `corner2` here (metres, world frame) and turns its image half a turn; OBSBench does the same, so a
# LeRobot Meta-World user sees the frames they know (the turn is folded into the camera pose).
CORNER2_POSITION = (0.75, 0.075, 0.7)
TURNED_CAMERAS = ("corner2",)
MAX_STEPS = 500  # Meta-World's episode budget (`max_path_length`), which LeRobot's env keeps
CONTROL_FPS = 80  # steps per second (LeRobot's Meta-World env: 5 physics steps of 2.5 ms)
ROBOT_TYPE = "sawyer"
# The oracle's objects: Meta-World's two object slots, then the goal.
PRIVILEGED_OBJECTS = ("object", "object2", "goal")
METAWORLD_PREFIX = "metaworld-"  # LeRobot's task prefix
DIFFICULTIES = ("easy", "medium", "hard", "very_hard")  # DP3's groups, as LeRobot names them


# The table top and the space above it that the arm reaches, the table's surface kept (metres, world frame: xmin
# xmax ymin ymax zmin zmax): DP3's one box for every task, and the bounds of each task's own.
TABLE_WORKSPACE = (-0.6, 0.6, 0.2, 1.0, -0.01, 0.6)
# Each task's crop box inside it, measured from its expert's episodes (`workspaces.py`); a task it lacks crops the
# whole table.
WORKSPACES_FILE = Path(__file__).with_name("workspaces.json")


@dataclass(frozen=True)
class MetaWorldTask:
    """One Meta-World task: its name (`drawer-open-v3`), LeRobot's description, DP3's difficulty group and the
    class name of its scripted expert in `metaworld.policies`; the other fields answer what the benchmark asks of
    any task (as a ManiSkill `Task` does)."""

    name: str
    description: str
    difficulty: str
    expert: str
    privileged_actors: tuple[str, ...] = PRIVILEGED_OBJECTS
    max_steps: int = MAX_STEPS
    camera_names: tuple[str, ...] = CAMERAS
    default_camera: str = DEFAULT_CAMERA
    workspace: tuple[float, ...] = TABLE_WORKSPACE
    fps: int = CONTROL_FPS
    robot_type: str = ROBOT_TYPE
    goal: tuple = ()  # no goal observation, as in LeRobot's env and DP3
    sub_success: tuple[str, ...] = ()
    objects: tuple = ()  # no object sizes for the diagnostics' pixel and point counts yet
    asset_group: None = None  # Meta-World ships its models
    camera: None = None  # the scene's cameras as Meta-World (and LeRobot) place them
    # 1.0 for every task, though a few experts fail now and then (docs/metaworld.md, "Cost"): the recorder logs
    # every failed attempt, and the cost model prices none
    expert_success_rate: float = 1.0
    # Meta-World's one action: the hand's displacement (mocap) and the gripper's effort
    control_mode: str = "mocap_delta_pos"

    def make_expert(self, env) -> MetaWorldExpert:
        """The scripted expert driving `env` (a `MetaWorldEnv` of this task)."""
        return MetaWorldExpert(env)


class MetaWorldExpert:
    """Meta-World's scripted policy for the env's task (`metaworld.policies`, as LeRobot maps it), acting on the
    env's last Meta-World observation; it never stops on its own (the episode's budget or success ends it)."""

    def __init__(self, env):
        import metaworld.policies

        self.env = env
        self.policy = getattr(metaworld.policies, env.spec_.expert)()

    def act(self):
        import numpy as np

        return np.asarray(self.policy.get_action(self.env.metaworld_observation), dtype=np.float32)


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
    boxes = json.loads(WORKSPACES_FILE.read_text())["tasks"] if WORKSPACES_FILE.exists() else {}
    return {
        name: MetaWorldTask(
            name,
            description,
            difficulty.get(name, "unrated"),
            config["TASK_POLICY_MAPPING"][name],
            workspace=tuple(boxes.get(name, TABLE_WORKSPACE)),
        )
        for name, description in config["TASK_DESCRIPTIONS"].items()
    }


def tasks_of(difficulty: str) -> list[str]:
    """The tasks of one of DP3's difficulty groups."""
    if difficulty not in DIFFICULTIES:
        raise TaskError(f"Meta-World difficulty must be one of {', '.join(DIFFICULTIES)}; got {difficulty!r}")
    return list(_lerobot_config()["DIFFICULTY_TO_TASKS"].get(difficulty, []))


def is_metaworld_name(name: str) -> bool:
    """Whether `name` is written as a Meta-World task (LeRobot's `metaworld-` prefix, or lower-case words joined
    by hyphens ending in a version, `drawer-open-v3`), known or not; ManiSkill's are CamelCase (`PickCube-v1`)."""
    return name.startswith(METAWORLD_PREFIX) or re.fullmatch(r"[a-z0-9]+(-[a-z0-9]+)*-v\d+", name) is not None


def metaworld_task(name: str) -> MetaWorldTask:
    """The task named `name` (LeRobot's `metaworld-` prefix accepted); an unknown name is refused with the
    closest names."""
    tasks = metaworld_tasks()
    task = tasks.get(name.removeprefix(METAWORLD_PREFIX))
    if task is None:
        close = difflib.get_close_matches(name.removeprefix(METAWORLD_PREFIX), list(tasks), n=3, cutoff=0.5)
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise TaskError(
            f"unknown Meta-World task {name!r}{hint} ({len(tasks)} tasks, LeRobot's names, e.g. drawer-open-v3; "
            "every one: lerobot_obsbench.envs.metaworld.tasks.metaworld_tasks())"
        )
    return task
