"""The OBSBench ManiSkill3 tasks, what each needs, and the fixed seed lists.

Seeds: demonstrations use seeds from DEMO_SEED_START upwards; evaluation uses EVAL_SEEDS (and checkpoint
selection VALIDATION_SEEDS). The three ranges never overlap, so no evaluation episode was seen in training.
"""

from __future__ import annotations

from dataclasses import dataclass

EVAL_SEED_START = 0  # evaluation: seeds 0 .. 9_999 (the paper uses 400 episodes per task)
VALIDATION_SEED_START = 10_000  # checkpoint selection: 10_000 .. 19_999
DEMO_SEED_START = 100_000  # demonstrations: 100_000 and up


def eval_seeds(n: int) -> list[int]:
    """The documented held-out evaluation seeds: 0, 1, ..., n-1."""
    if not 0 < n <= VALIDATION_SEED_START - EVAL_SEED_START:
        raise ValueError(f"episodes must be in 1..{VALIDATION_SEED_START}; got {n}")
    return list(range(EVAL_SEED_START, EVAL_SEED_START + n))


@dataclass(frozen=True)
class TaskSpec:
    name: str
    max_steps: int  # ManiSkill's own episode budget
    goal_keys: tuple[str, ...] = ()  # `extra` observation keys that form observation.environment_state
    asset_group: str | None = None  # ManiSkill asset download id when the task needs downloaded assets
    sub_success: tuple[str, ...] = ()  # per-episode milestones reported next to success
    description: str = ""


TASKS: dict[str, TaskSpec] = {
    t.name: t
    for t in (
        TaskSpec("PickCube-v1", 50, ("goal_pos",), description="pick up the red cube and move it to the goal"),
        TaskSpec("StackCube-v1", 50, sub_success=("grasp",), description="stack the red cube on the green cube"),
        TaskSpec("PegInsertionSide-v1", 100, sub_success=("grasp", "align", "insert"),
                 description="insert the peg into the hole of the box from the side"),
        TaskSpec("PushCube-v1", 50, description="push the cube into the goal region"),
        TaskSpec("PullCube-v1", 50, ("goal_pos",), description="pull the cube back into the goal region"),
        TaskSpec("LiftPegUpright-v1", 50, description="lift the lying peg into an upright pose"),
        TaskSpec("PlugCharger-v1", 200, sub_success=("grasp",), description="plug the charger into the socket"),
        TaskSpec("TurnFaucet-v1", 200, asset_group="partnet_mobility_faucet",
                 description="turn the faucet handle (needs PartNet-Mobility assets)"),
    )
}


class TaskError(ValueError):
    """Unknown task, or a task whose assets are missing."""


def task_spec(name: str) -> TaskSpec:
    if name not in TASKS:
        raise TaskError(f"Unknown task {name!r}. OBSBench tasks: {', '.join(TASKS)}.")
    return TASKS[name]


def missing_assets(spec: TaskSpec) -> list[str]:
    """ManiSkill data sources the task needs that are not on disk (checked without ManiSkill's stdin prompt)."""
    if spec.asset_group is None:
        return []
    from mani_skill.utils import assets

    ids = (assets.expand_data_group_into_individual_data_source_ids(spec.asset_group)
           if spec.asset_group in assets.DATA_GROUPS else [spec.asset_group])
    return [i for i in ids if not assets.is_data_source_downloaded(i)]


def asset_help(spec: TaskSpec, asset_dir: str | None) -> str:
    where = asset_dir or "~/.maniskill"
    return (
        f"{spec.name} needs ManiSkill assets '{spec.asset_group}', which are not in {where}/data. This machine "
        f"cannot download them; on one with internet run\n  MS_ASSET_DIR={where} python -m "
        f"mani_skill.utils.download_asset {spec.asset_group}\nthen copy that directory here and pass "
        f"--env.asset_dir={where} (or set MS_ASSET_DIR)."
    )
