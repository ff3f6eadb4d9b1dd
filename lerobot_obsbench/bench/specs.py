"""What one training run and one evaluation are, and their identities.

Identity: a run is what it trains (`RunSpec.run_id`, the SHA-256 of the training config); an evaluation is a
record against a run (`EvalSpec.eval_id`: run id + checkpoint, seed split, episodes, perturbation, episode
budget). Adding a perturbation or episodes to a finished grid evaluates the existing checkpoints and trains
nothing; how often checkpoints are saved is not part of a run's identity (it does not change the weights).

Training budgets (`RunSpec.budget_unit`):
- `steps`: optimizer steps;
- `samples`: training samples (steps x batch size);
- `demo_epochs`: the paper's epochs — one randomly sampled frame per demonstration per epoch, so
  steps = ceil(demo_epochs x demos / batch size);
- `frame_epochs`: passes over every frame of every demonstration (steps depend on the episodes' lengths).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass

from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.presets import policy_flags, preset_args, preset_overrides
from lerobot_obsbench.rlbench.paper_tasks import grid_task_name
from lerobot_obsbench.schema import DEFAULT_POINT_FEATURES

BUDGET_UNITS = {
    "steps": "optimizer steps",
    "samples": "training samples (optimizer steps x batch size)",
    "demo_epochs": "the paper's epochs: one randomly sampled frame per demonstration per epoch",
    "frame_epochs": "passes over every frame of every demonstration",
}


RLBENCH_CONTROL_MODE = "ee_pose_planning"  # RLBench's EndEffectorPoseViaPlanning, absolute world-frame poses
CLIP_GOAL = "clip_vit_b16"  # the language goal's encoder, as RLBench runs record it


# --policy.* fields a grid sets through its own axes and options: an override of one would train another value
# than the run's id and results record
AXIS_FIELDS = {
    "type": "policies",
    "obs_space": "obs_spaces",
    "encoder": "encoders",
    "augment": "augmentations",
    "optimizer_lr": "learning_rates",
    "cameras": "cameras",
    "device": "`obsbench run --device`",
}


class GridError(ObsBenchError, ValueError):
    """A grid file names something that does not exist or does not fit together."""


def _digest(config: dict) -> str:
    canonical = json.dumps(config, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class RunSpec:
    """One training run: everything that determines the trained weights."""

    task: str
    obs_space: str
    encoder: str
    policy: str
    seed: int
    lr: float
    demos: int
    preset: str
    batch_size: int
    budget_unit: str  # one of BUDGET_UNITS
    budget: float
    image_size: int
    cameras: tuple[str, ...]
    control_mode: str
    policy_overrides: tuple[tuple[str, object], ...] = ()
    # RLBench: the text encoder of the language goal the demonstrations carry ("" = none)
    language_goal: str = ""
    # the training augmentation recipe (`--policy.augment`; "" = none)
    augment: str = ""

    def config(self) -> dict:
        data = asdict(self)
        data["cameras"] = list(self.cameras)
        data["policy_overrides"] = dict(self.policy_overrides)
        for name in ("language_goal", "augment"):  # added later: left out at their default, so older runs keep ids
            if not data[name]:
                del data[name]
        return data

    @property
    def run_id(self) -> str:
        return _digest(self.config())

    def policy_args(self) -> list[str]:
        """The `--policy.<field>=<value>` arguments lerobot-train gets for this run (all but its type and device),
        as lerobot-train's parser reads them: each field once, the run's own values (its axes and overrides) over
        the preset's."""
        overrides = dict(self.policy_overrides)
        sizes = preset_args(
            self.preset, self.policy, self.obs_space, self.encoder, user_fields={*AXIS_FIELDS, *overrides}
        )
        return [
            f"--policy.obs_space={self.obs_space}",
            *sizes,
            f"--policy.encoder={self.encoder}",
            f"--policy.cameras=[{','.join(self.cameras)}]",
            *policy_flags(overrides),
            *([f"--policy.augment={self.augment}"] if self.augment else []),
            f"--policy.optimizer_lr={self.lr}",
        ]

    @property
    def point_features(self) -> str:
        """The features its policy's points carry: the run's override, else its preset's, else the default."""
        overrides = dict(self.policy_overrides)
        if "point_features" in overrides:
            return str(overrides["point_features"])
        preset = preset_overrides(self.preset, self.policy, self.obs_space, self.encoder)
        return str(preset.get("point_features", DEFAULT_POINT_FEATURES))

    @property
    def method(self) -> str:
        """Column label in reports: what differs between the compared methods (the recipe, where there is one)."""
        return f"{self.policy}/{self.obs_space}/{self.encoder}" + (f"/{self.augment}" if self.augment else "")

    @property
    def demo_key(self) -> str:
        """Runs sharing this key train on (a prefix of) the same demonstration dataset."""
        key = f"{self.task}-{self.image_size}px-{'+'.join(self.cameras)}-{self.control_mode}"
        return key.replace("/", "_") + (f"-{self.language_goal}" if self.language_goal else "")

    @property
    def rlbench_task(self) -> str | None:
        """The RLBench task this run trains on, None for a ManiSkill task."""
        return grid_task_name(self.task)

    def steps(self, demo_frames: int | None = None) -> int:
        """Optimizer steps of the budget; `demo_frames` (frames in the run's demonstrations) is needed for
        frame_epochs only."""
        if self.budget_unit == "steps":
            return max(1, int(self.budget))
        if self.budget_unit == "samples":
            return max(1, math.ceil(self.budget / self.batch_size))
        if self.budget_unit == "demo_epochs":
            return max(1, math.ceil(self.budget * self.demos / self.batch_size))
        if demo_frames is None:
            raise GridError("frame_epochs budgets need the demonstrations' frame count")
        return max(1, math.ceil(self.budget * demo_frames / self.batch_size))

    @classmethod
    def from_config(cls, config: dict) -> RunSpec:
        data = dict(config)
        data["cameras"] = tuple(data["cameras"])
        data["policy_overrides"] = tuple(sorted(data.get("policy_overrides", {}).items()))
        return cls(**data)


@dataclass(frozen=True)
class EvalSpec:
    """One evaluation of a run's checkpoint: `checkpoint` is "last", "best" (the best on the validation seeds)
    or "step:N"; `split` the seed list ("test": 0, 1, ...; "validation": 10000, ...)."""

    run_id: str
    checkpoint: str
    split: str
    episodes: int
    perturbation: str  # "none" or kind:value
    max_steps: int  # episode budget

    def config(self) -> dict:
        return asdict(self)

    @property
    def eval_id(self) -> str:
        return _digest(self.config())
