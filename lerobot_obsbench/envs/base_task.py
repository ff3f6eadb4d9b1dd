"""What OBSBench knows about a ManiSkill3 task, in one place per task, and the fixed seed lists.

Each task is a `Task` subclass in its own module of `lerobot_obsbench.envs.tasks` (discovered on import, so
adding a task is adding one module), documented in ManiSkill's style: description, randomizations, success
conditions, plus the scripted expert's strategy and its measured success rate. A task names its episode
budget, the goal observation it gives the policy, the object the gripper must hold (for the `grasp`
milestone), its sub-success milestones and its expert.

Seeds: demonstrations use seeds from DEMO_SEED_START upwards; evaluation uses `eval_seeds` (and checkpoint
selection VALIDATION_SEEDS). The three ranges never overlap, so no evaluation episode was seen in training.
"""

from __future__ import annotations

import difflib
import math
from typing import ClassVar

import numpy as np

from lerobot_obsbench.errors import ObsBenchError, UnsupportedError

EVAL_SEED_START = 0  # evaluation: seeds 0 .. 9_999 (the paper uses 400 episodes per task)
VALIDATION_SEED_START = 10_000  # checkpoint selection: 10_000 .. 19_999
DEMO_SEED_START = 100_000  # demonstrations: 100_000 and up
CUBE_HALF_SIZE = 0.02  # metres: ManiSkill's cubes (PushCube, PullCube, PickCube, StackCube)
# The `reach` and `lift` milestones: the gripper's centre this close to the object's (metres), and the held object
# this far above its height at the episode's start.
REACH_DISTANCE = 0.015
LIFT_HEIGHT = 0.02


SPLITS = {
    "test": (EVAL_SEED_START, VALIDATION_SEED_START),
    "validation": (VALIDATION_SEED_START, 2 * VALIDATION_SEED_START),
}


def eval_seeds(n: int, split: str = "test") -> list[int]:
    """The documented held-out seeds: test 0, 1, ..., n-1; validation (checkpoint selection) 10000, ...,
    10000 + n - 1. Neither overlaps the other or the demonstrations' seeds."""
    if split not in SPLITS:
        raise TaskError(f"Unknown seed split {split!r}; choose one of {', '.join(SPLITS)}")
    start, stop = SPLITS[split]
    if not 0 < n <= stop - start:
        raise TaskError(f"episodes must be in 1..{stop - start}; got {n}")
    return list(range(start, start + n))


class TaskError(ObsBenchError, ValueError):
    """Unknown task, a task whose assets are missing, or a task declared wrongly."""


class MilestoneError(TaskError, KeyError):
    """A milestone the task does not define (a KeyError, as a missing key is)."""


def bounding_radius(*half_sizes: float) -> float:
    """Radius of the sphere around a box of these half sizes (metres), rounded up to the millimetre: a crop box or
    a camera check that holds the sphere holds the box in any rotation."""
    return math.ceil(math.hypot(*half_sizes) * 1000) / 1000


def to_numpy(x) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def first(value) -> np.ndarray:
    """A single env's value (ManiSkill returns batches of one) as a flat NumPy array."""
    return to_numpy(value).reshape(-1)


def spawn_cube_and_target(ms_env, half_size: tuple[float, float]) -> None:
    """Move each env's `obj` to an xy drawn in [-half_size, half_size] (one x, then one y, from its episode
    generator: what a single env with that seed draws) and its `goal_region` with it, keeping their offset: the wide
    variants of ManiSkill's push and pull tasks."""
    from mani_skill.utils.structs import Pose

    xs, ys = (ms_env._batched_episode_rng.uniform(-h, h) for h in half_size)
    cube, goal = to_numpy(ms_env.obj.pose.p), to_numpy(ms_env.goal_region.pose.p)
    offset = goal - cube
    ms_env.obj.set_pose(Pose.create_from_pq(p=np.stack([xs, ys, cube[:, 2]], 1), q=ms_env.obj.pose.q))
    ms_env.goal_region.set_pose(
        Pose.create_from_pq(
            p=np.stack([xs + offset[:, 0], ys + offset[:, 1], goal[:, 2]], 1), q=ms_env.goal_region.pose.q
        )
    )


class Task:
    """One OBSBench task on ManiSkill3. Subclasses set the class attributes and document the task."""

    # OBSBench's task id, e.g. "PickCube-v1" (ManiSkill's, unless the task is a variant of a ManiSkill task).
    name: ClassVar[str]
    # The ManiSkill task it runs; None: `name`.
    maniskill_id: ClassVar[str | None] = None
    # Steps per episode, in evaluation and in recording: ManiSkill's own budget for the task, raised where the
    # scripted expert needs more than half of it on average to twice the expert's mean episode length (the rule
    # ManiSkill's imitation baselines evaluate by: a cloned policy is slower than its expert); checked against the
    # expert's episodes by tests/envs/test_sim.py.
    max_steps: ClassVar[int]
    # One line for dataset task strings and listings.
    description: ClassVar[str]
    # `extra` observation keys -> sizes that form observation.environment_state (the goal given to the policy).
    goal: ClassVar[dict[str, int]] = {}
    # Attribute of the ManiSkill env holding the object to grasp (the `grasp` milestone); None: no grasp.
    grasped: ClassVar[str | None] = None
    # Per-episode milestones reported next to success, each achieved at some step of the episode.
    sub_success: ClassVar[tuple[str, ...]] = ()
    # Scripted expert class (`envs.experts.WaypointExpert` subclass); None: demos must come from `import-h5`.
    expert: ClassVar[type | None] = None
    # Share of the expert's attempts that succeed (the docstring says where it was measured): a grid's dry run
    # prices the failed attempts that recording its demonstrations takes by it.
    expert_success_rate: ClassVar[float] = 1.0
    # The one control mode the task acts by; None: ManiSkill's controllers, chosen by the grid or the command
    # (`control_mode`).
    control_mode: ClassVar[str | None] = None
    # ManiSkill asset download id when the task needs downloaded assets.
    asset_group: ClassVar[str | None] = None
    # Attributes of the ManiSkill env holding the actors whose poses (xyz + quaternion wxyz, 7 values each, in this
    # order) demonstrations record as observation.privileged_state: the input of the oracle control `state`.
    privileged_actors: ClassVar[tuple[str, ...]] = ()
    # The objects a seeing policy must find, among `privileged_actors`: attribute -> bounding-sphere radius in
    # metres. The diagnostics count the point tokens and pixels that fall on them.
    objects: ClassVar[dict[str, float]] = {}
    # The cameras the task renders (ManiSkill's sensors; `observation.*.<cam>` keys), so a typo is refused before a
    # simulator starts.
    camera_names: ClassVar[tuple[str, ...]] = ("base_camera",)
    # The camera demonstrations and grids render unless told otherwise.
    default_camera: ClassVar[str] = "base_camera"
    # ManiSkill's tabletop tasks step their controllers at 20 Hz: the rate demonstrations are recorded at.
    fps: ClassVar[int] = 20
    robot_type: ClassVar[str] = "panda"  # every task's robot, as LeRobot datasets record it (robot_type)
    # The task's own `base_camera` (OBSBench's, replacing ManiSkill's): eye and target points in the world frame
    # (metres) and the field of view (radians). None: ManiSkill's camera.
    camera: ClassVar[tuple[tuple[float, float, float], tuple[float, float, float], float] | None] = None
    # Point-cloud crop box around the task's objects (xmin, xmax, ymin, ymax, zmin, zmax; world frame, metres),
    # given to point-cloud runs of the benchmark grids. None: the policy's default box.
    workspace: ClassVar[tuple[float, float, float, float, float, float] | None] = None

    @property
    def env_id(self) -> str:
        return self.maniskill_id or self.name

    def initialize(self, ms_env) -> bool:
        """After ManiSkill's own reset of all its envs: change each episode's initial state (a variant's
        randomization, drawn from env i's `ms_env._batched_episode_rng[i]`, so it follows that env's seed).
        Returns whether it changed anything."""
        return False

    def privileged_state(self, ms_env):
        """The oracle's observation: the poses of `privileged_actors`, (num_envs, 7 * O) float32 tensor."""
        import torch

        return torch.cat([getattr(ms_env, name).pose.raw_pose for name in self.privileged_actors], dim=1).float()

    def episode_start(self, ms_env) -> dict:
        """What the milestones compare with, taken when the episodes start: the grasped object's height."""
        return {} if self.grasped is None else {"height": getattr(ms_env, self.grasped).pose.p[..., 2].reshape(-1)}

    def milestone(self, name: str, ms_env, info: dict, success, start: dict):
        """Whether milestone `name` holds at this step, per env: (num_envs,) bool tensor (`ms_env`: the unwrapped
        ManiSkill env, `info` its batched step info, `success` its (num_envs,) success, `start` what
        `episode_start` took). Shared rules: `reach` (the gripper's centre within REACH_DISTANCE of the grasped
        object's), `grasp` (the gripper holds it) and `lift` (held LIFT_HEIGHT above where it started)."""
        if name == "reach":
            held = getattr(ms_env, self.grasped).pose.p
            return (held - ms_env.agent.tcp.pose.p).norm(dim=-1).reshape(-1) <= REACH_DISTANCE
        if name == "grasp":
            return ms_env.agent.is_grasping(getattr(ms_env, self.grasped)).reshape(-1).bool()
        if name == "lift":
            held = getattr(ms_env, self.grasped)
            raised = held.pose.p[..., 2].reshape(-1) >= start["height"] + LIFT_HEIGHT
            return raised & ms_env.agent.is_grasping(held).reshape(-1).bool()
        raise MilestoneError(f"{self.name} has no rule for milestone {name!r}")

    def make_expert(self, env):
        if self.expert is None:
            raise UnsupportedError(
                f"No scripted expert for {self.name} yet (experts: "
                f"{', '.join(n for n, t in TASKS.items() if t.expert)}). "
                "Convert official ManiSkill demonstrations instead: obsbench import-h5 --h5 FILE.h5 --out DIR "
                "(--asset-dir DIR for a task with downloaded assets)."
            )
        return self.expert(env)


TASKS: dict[str, Task] = {}


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator adding a task to TASKS (a name registered twice is an error)."""
    if cls.name in TASKS:
        raise TaskError(f"task {cls.name!r} is registered twice ({type(TASKS[cls.name]).__module__}, {cls.__module__})")
    unknown = [name for name in cls.objects if name not in cls.privileged_actors]
    if unknown:
        raise TaskError(f"task {cls.name!r}: objects {unknown} are not among its privileged_actors")
    held = [name for name in ("reach", "grasp", "lift") if name in cls.sub_success]
    if held and cls.grasped is None:
        raise TaskError(f"task {cls.name!r} reports milestones {held} but names no grasped object")
    if not 0 < cls.expert_success_rate <= 1:
        raise TaskError(f"task {cls.name!r}: expert_success_rate must be in (0, 1]; got {cls.expert_success_rate}")
    TASKS[cls.name] = cls()
    return cls


def check_cameras(spec: Task, cameras, rendered: list[str] | None = None) -> None:
    """Refuse `cameras` the task does not render, naming those it does (`rendered`: a built env's sensors)."""
    available = list(spec.camera_names if rendered is None else rendered)
    unknown = [cam for cam in cameras if cam not in available]
    if unknown:
        raise TaskError(f"cameras {unknown}: {spec.name} has no such camera; its cameras are {available}")


def task_spec(name: str) -> Task:
    if name not in TASKS:
        close = difflib.get_close_matches(str(name), TASKS, n=3)
        hint = f" (did you mean {' or '.join(close)}?)" if close else ""
        raise TaskError(f"Unknown task {name!r}{hint}. OBSBench tasks: {', '.join(TASKS)}.")
    return TASKS[name]


def missing_assets(spec: Task) -> list[str]:
    """ManiSkill data sources the task needs that are not on disk (checked without ManiSkill's stdin prompt)."""
    if spec.asset_group is None:
        return []
    from mani_skill.utils import assets

    ids = (
        assets.expand_data_group_into_individual_data_source_ids(spec.asset_group)
        if spec.asset_group in assets.DATA_GROUPS
        else [spec.asset_group]
    )
    return [i for i in ids if not assets.is_data_source_downloaded(i)]


def asset_help(spec: Task, asset_dir: str | None) -> str:
    where = asset_dir or "~/.maniskill"
    return (
        f"{spec.name} needs ManiSkill assets '{spec.asset_group}', which are not in {where}/data. This machine "
        f"cannot download them; on one with internet run\n  MS_ASSET_DIR={where} python -m "
        f"mani_skill.utils.download_asset {spec.asset_group}\nthen copy that directory here and point the "
        f"command at it: --env.asset_dir={where} (lerobot-train, lerobot-eval, obsbench eval), --asset-dir {where} "
        "(obsbench doctor, obsbench import-h5), or MS_ASSET_DIR for any of them."
    )
