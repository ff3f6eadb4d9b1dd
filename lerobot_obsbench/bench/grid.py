"""Benchmark grid files: YAML naming tasks x observation spaces x encoders x policies x seeds x learning rates x
demo counts, the training budget, and the evaluations (episodes, episode budget, zero-shot perturbations,
checkpoint selection).

`load_grid(path_or_preset)` validates everything before anything runs (unknown task, space, encoder, policy,
perturbation or field: a `GridError` listing the valid choices). `Grid.expand()` gives one `RunSpec` per
training run and `Grid.evaluations(run)` the `EvalSpec`s of its test evaluations.

Identity: a run is what it trains (`RunSpec.run_id`, the SHA-256 of the training config); an evaluation is a
record against a run (`EvalSpec.eval_id`: run id + checkpoint, seed split, episodes, perturbation, episode
budget). Adding a perturbation or episodes to a finished grid evaluates the existing checkpoints and trains
nothing; how often checkpoints are saved is not part of a run's identity (it does not change the weights).

Training budgets, exactly one per policy, each a number or a mapping policy -> number:
- `steps`: optimizer steps;
- `samples`: training samples (steps x batch size);
- `demo_epochs`: the paper's epochs — one randomly sampled frame per demonstration per epoch, so
  steps = ceil(demo_epochs x demos / batch size);
- `frame_epochs`: passes over every frame of every demonstration (steps depend on the episodes' lengths).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import yaml

from lerobot_obsbench.bench.package_data import GRIDS, path_or_shipped, shipped
from lerobot_obsbench.envs.base_task import TASKS, TaskError, check_cameras, task_spec
from lerobot_obsbench.envs.maniskill import DEFAULT_CONTROL_MODE
from lerobot_obsbench.envs.perturbations import parse_perturbation
from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.numeric import check_number, check_numbers
from lerobot_obsbench.presets import PRESETS, policy_flags, preset_args, preset_encoder
from lerobot_obsbench.rlbench.evaluate import MAX_STEPS as RLBENCH_MAX_STEPS
from lerobot_obsbench.rlbench.evaluate import camera_view_for
from lerobot_obsbench.rlbench.paper_tasks import CAMERAS as RLBENCH_CAMERAS
from lerobot_obsbench.rlbench.paper_tasks import IMAGE_SIZE as RLBENCH_IMAGE_SIZE
from lerobot_obsbench.rlbench.paper_tasks import WORKSPACE as RLBENCH_WORKSPACE
from lerobot_obsbench.rlbench.paper_tasks import RLBenchTaskError, grid_task_name, rlbench_task
from lerobot_obsbench.schema import CONTROL_SPACES, MIN_IMAGE_SIZE, OBS_SPACES, POLICY_TYPES, reads_points

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


def _as_list(value, name: str) -> list:
    if value is None:
        raise GridError(f"grid field {name!r} is required")
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if not values:
        raise GridError(f"grid field {name!r} is empty: it needs at least one value")
    return values


def _named_policies_in_grid_terms(policies: list, name: str) -> None:
    """A named type (act_pcd, ...) is one policy type, space and encoder; a grid lists those on their own axes."""
    from lerobot_obsbench.policies.named import NAMED_POLICIES

    named = next((p for p in policies if p in NAMED_POLICIES), None)
    if named is not None:
        policy, space, encoder = NAMED_POLICIES[named]
        raise GridError(
            f"{name}: policies lists {named}, a named type; a grid sets its parts on their own axes: "
            f"policies: [{policy}], obs_spaces: [{space}], encoders: {{{space}: [{encoder}]}}"
        )


def _choose(values: list, valid, name: str) -> list:
    bad = [v for v in values if v not in valid]
    if bad:
        raise GridError(f"unknown {name} {bad}; valid choices: {', '.join(valid)}")
    return values


@dataclass
class Grid:
    """A parsed, validated grid file (fields: docs/benchmark.md)."""

    name: str
    tasks: list[str]
    obs_spaces: list[str]
    policies: list[str]
    seeds: list[int]
    learning_rates: list[float]
    demos: list[int]
    preset: str = "cpu"
    encoders: dict[str, list[str]] = field(default_factory=dict)  # obs_space -> encoders
    # obs_space -> training augmentation recipes (`--policy.augment`; "" = none), each a method of its own in the
    # report; a space not listed trains without augmentation
    augmentations: dict[str, list[str]] = field(default_factory=dict)
    # training budget: exactly one unit per policy (module docstring); a number or a mapping policy -> number
    steps: float | dict[str, float] | None = None
    samples: float | dict[str, float] | None = None
    demo_epochs: float | dict[str, float] | None = None
    frame_epochs: float | dict[str, float] | None = None
    # task -> its own budget in the unit its policies are given (e.g. {PickCube-v1: 30000}), for every space alike:
    # a task that needs more steps than the others before its oracle clears blind
    task_budgets: dict[str, float] = field(default_factory=dict)
    batch_size: int | dict[str, int] = 32
    # evenly spaced checkpoints saved during training (for resuming and for checkpoint selection)
    checkpoints: int | dict[str, int] = 4
    # > 0: every checkpoint is evaluated on this many validation episodes and the best one is also evaluated
    # on the test seeds (the report shows it by default); 0: the last checkpoint only
    validation_episodes: int = 0
    # optimizer steps whose checkpoints the test seeds also evaluate (the nominal scene): each run's learning curve,
    # ending at its last checkpoint; a run's curve has the steps below its budget (each step must lie below some
    # run's). The checkpoints are saved besides `checkpoints`' and kept
    eval_checkpoints: list[int] = field(default_factory=list)
    # demonstrations recorded beyond the most any run trains on, never trained on: each trained run's diagnostics
    # (open-loop action error, objects' pixel size and point-token share; bench/diagnostics.py) are computed on
    # them. 0: no diagnostics but the loss curve
    held_out_demos: int = 0
    image_size: int = 128
    cameras: list[str] = field(default_factory=lambda: ["base_camera"])
    control_mode: str = DEFAULT_CONTROL_MODE
    eval_episodes: int = 50
    # ManiSkill evaluations: episodes run in lockstep, each env in a process of its own, one batched policy call
    # per step (envs/evaluate.py); None: the measured default for the device. Not part of a run's identity.
    eval_batch_size: int | None = None
    # steps per evaluation episode; None: each task's own budget
    episode_length: int | None = None
    perturbations: list[str] = field(default_factory=list)
    policy_overrides: dict[str, object] = field(default_factory=dict)
    # obs_space -> `--policy.*` fields for that space's runs only (e.g. {rgb: {encoder_norm: batch}}), applied over
    # policy_overrides
    space_overrides: dict[str, dict[str, object]] = field(default_factory=dict)
    variants: list[dict[str, object]] = field(default_factory=lambda: [{}])  # extra --policy.* sets, one axis
    # evaluate the checkpoints another grid trained (its output directory) instead of training
    checkpoints_from: str | None = None
    # RLBench tasks (`rlbench/<task>`): PerAct-format data, DIR/train/<task> imported as the demonstrations,
    # DIR/test/<task> (and DIR/val/<task> for validation_episodes) replayed by the evaluation protocol
    rlbench_data: str | None = None
    # RLBench: CLIP ViT-B/16 weights (a local file) for the language goal; None: no language goal
    clip_weights: str | None = None
    description: str = ""

    def per_policy(self, name: str, policy: str):
        value = getattr(self, name)
        return value.get(policy) if isinstance(value, dict) else value

    def budget(self, policy: str) -> tuple[str, float]:
        given = {unit: self.per_policy(unit, policy) for unit in BUDGET_UNITS}
        given = {unit: value for unit, value in given.items() if value is not None}
        if len(given) != 1:
            raise GridError(
                f"{self.name}: give exactly one training budget for {policy}, as a number or a mapping "
                f"policy -> number: " + "; ".join(f"`{u}` ({what})" for u, what in BUDGET_UNITS.items())
            )
        return next(iter(given.items()))

    def expand(self) -> list[RunSpec]:
        runs = []
        for task, space, policy, variant, demos, lr, seed in itertools.product(
            self.tasks, self.obs_spaces, self.policies, self.variants, self.demos, self.learning_rates, self.seeds
        ):
            unit, budget = self.budget(policy)
            budget = self.task_budgets.get(task, budget)
            overrides = {
                **task_overrides(task, space),
                **self.policy_overrides,
                **self.space_overrides.get(space, {}),
                **variant,
            }
            rlbench = grid_task_name(task) is not None
            for encoder, augment in itertools.product(self.encoders[space], self.augmentations.get(space, [""])):
                runs.append(
                    RunSpec(
                        task=task,
                        obs_space=space,
                        encoder=encoder,
                        policy=policy,
                        seed=seed,
                        lr=lr,
                        demos=demos,
                        preset=self.preset,
                        batch_size=int(self.per_policy("batch_size", policy)),
                        budget_unit=unit,
                        budget=budget,
                        image_size=self.image_size,
                        cameras=tuple(self.cameras),
                        control_mode=RLBENCH_CONTROL_MODE if rlbench else self.control_mode,
                        policy_overrides=tuple(sorted(overrides.items())),
                        language_goal=CLIP_GOAL if rlbench and self.clip_weights else "",
                        augment=augment,
                    )
                )
        return runs

    def max_steps(self, run: RunSpec) -> int:
        return int(self.episode_length or (RLBENCH_MAX_STEPS if run.rlbench_task else task_spec(run.task).max_steps))

    def test_checkpoints(self) -> tuple[str, ...]:
        return ("last", "best") if self.validation_episodes else ("last",)

    def curve(self, run: RunSpec) -> tuple[int, ...]:
        """The steps of `run`'s learning curve before its last checkpoint: the eval_checkpoints below its budget."""
        return tuple(step for step in sorted(self.eval_checkpoints) if step < run.steps())

    def evaluations(self, run: RunSpec) -> list[EvalSpec]:
        """The run's test evaluations: each tested checkpoint, nominally and under every perturbation, then its
        learning curve's earlier checkpoints (nominally)."""
        return [
            EvalSpec(run.run_id, checkpoint, "test", self.eval_episodes, perturbation, self.max_steps(run))
            for checkpoint in self.test_checkpoints()
            for perturbation in ("none", *self.perturbations_for(run))
        ] + [
            EvalSpec(run.run_id, f"step:{step}", "test", self.eval_episodes, "none", self.max_steps(run))
            for step in self.curve(run)
        ]

    def perturbations_for(self, run: RunSpec) -> list[str]:
        """The perturbations a run is evaluated under: none for the controls, which read no pixels (every
        perturbation changes only what the cameras see: their episodes would replay the nominal ones)."""
        return [] if run.obs_space in CONTROL_SPACES else list(self.perturbations)

    def validations(self, run: RunSpec, checkpoint_steps: list[int]) -> list[EvalSpec]:
        """The validation evaluations that select the run's best checkpoint."""
        if not self.validation_episodes:
            return []
        return [
            EvalSpec(run.run_id, f"step:{step}", "validation", self.validation_episodes, "none", self.max_steps(run))
            for step in checkpoint_steps
        ]


def task_overrides(task: str, obs_space: str) -> dict[str, object]:
    """`--policy.*` fields a task sets for a space: its point-cloud crop box (`Task.workspace`; RLBench's scene)."""
    workspace = RLBENCH_WORKSPACE if grid_task_name(task) else task_spec(task).workspace
    return {"workspace": list(workspace)} if workspace is not None and reads_points(obs_space) else {}


GRID_FIELDS = set(Grid.__dataclass_fields__)
PER_POLICY = ("batch_size", "checkpoints", *BUDGET_UNITS)


def _resolve_encoders(spec, spaces: list[str], preset: str, name: str) -> dict[str, list[str]]:
    """`encoders` may be omitted (the preset's choice per space), a list (each space takes the listed
    encoders that accept it; every listed encoder must fit some space) or a mapping space -> encoders (strict)."""
    from lerobot_obsbench.encoders import available_encoders, check_encoder, encoder_info

    if spec is None:
        return {s: [preset_encoder(preset, s)] for s in spaces}
    if isinstance(spec, dict):
        _check_spaces_listed(spec, spaces, "encoders", name)
        resolved = {}
        for space in spaces:
            names = _as_list(spec.get(space, preset_encoder(preset, space)), f"encoders.{space}")
            _check_listed_once(names, f"encoders.{space}", name)
            for name in names:
                try:
                    check_encoder(name, space)
                except ValueError as err:
                    raise GridError(str(err)) from None
            resolved[space] = names
        return resolved
    names = _as_list(spec, "encoders")
    _check_listed_once(names, "encoders", name)
    _choose(names, available_encoders(), "encoders")
    resolved = {s: [n for n in names if s in encoder_info(n).spaces] for s in spaces}
    for space, chosen in resolved.items():
        if not chosen and space in CONTROL_SPACES:
            resolved[space] = [preset_encoder(preset, space)]  # the controls need no encoder listed
        elif not chosen:
            raise GridError(
                f"no listed encoder accepts obs_space {space!r}; encoders for it: "
                f"{', '.join(available_encoders(space))}"
            )
    for name in names:
        if not any(name in resolved[s] for s in spaces):
            raise GridError(
                f"encoder {name!r} accepts none of the grid's obs_spaces {spaces} (it accepts "
                f"{', '.join(encoder_info(name).spaces)})"
            )
    return resolved


def _check_spaces_listed(mapping: dict, spaces: list[str], field_name: str, name: str) -> None:
    """A per-space mapping names only the grid's spaces."""
    extra = [s for s in mapping if s not in spaces]
    if extra:
        raise GridError(f"{name}: {field_name} names spaces {extra} that are not in obs_spaces {spaces}")


def _resolve_augmentations(spec, spaces: list[str], name: str) -> dict[str, list[str]]:
    """`augmentations`: a mapping space -> recipes (`--policy.augment` values, "" or null for none), each recipe
    checked against its space and normalised, so one recipe written two ways is refused as listed twice."""
    from lerobot_obsbench.augmentations import AugmentationError, normalised_recipe

    if spec is None:
        return {}
    if not isinstance(spec, dict):
        raise GridError(f"{name}: augmentations maps spaces to recipes, e.g. {{rgb: ['', random_shift]}}; got {spec!r}")
    _check_spaces_listed(spec, spaces, "augmentations", name)
    resolved = {}
    for space, written in spec.items():
        written = ["" if r is None else r for r in _as_list(written, f"augmentations.{space}")]
        recipes = []
        for recipe in written:
            if not isinstance(recipe, str):
                raise GridError(f"{name}: augmentations.{space} lists recipes as text; got {recipe!r}")
            try:
                recipes.append(normalised_recipe(recipe, space))
            except AugmentationError as err:
                raise GridError(f"{name}: augmentations.{space}: {err}") from None
        _check_listed_once(recipes, f"augmentations.{space}", name, written)
        resolved[space] = recipes
    return resolved


def _check_listed_once(values: list, field_name: str, name: str, written: list | None = None) -> None:
    """An axis lists each of its values once (`written`: the values as the file spells them, where the grid
    normalises them); a repeated value is one point of the grid given twice."""
    repeated = sorted({json.dumps(v) for v in values if values.count(v) > 1})
    if repeated:
        spelling = f" (written {written})" if written is not None and written != values else ""
        raise GridError(
            f"{name}: {field_name} lists {', '.join(repeated)} more than once{spelling}; each value is one point of "
            "the grid (listed twice, it would train the same runs twice): list it once"
        )


# Numeric grid fields and their bounds, as lerobot_obsbench.numeric.check_number (the project's one rule for
# numbers) takes them; lists and per-policy mappings are checked value by value. Booleans and strings are refused
# (YAML reads `steps: '5'` as a string).
NUMERIC_FIELDS = {
    "seeds": {"whole": True, "minimum": 0},
    "demos": {"whole": True, "minimum": 1},
    "learning_rates": {"above": 0},
    "steps": {"above": 0},
    "samples": {"above": 0},
    "demo_epochs": {"above": 0},
    "frame_epochs": {"above": 0},
    "task_budgets": {"above": 0},
    "batch_size": {"whole": True, "minimum": 1},
    "checkpoints": {"whole": True, "minimum": 1},
    "validation_episodes": {"whole": True, "minimum": 0},
    "image_size": {"whole": True, "minimum": MIN_IMAGE_SIZE},
    "eval_episodes": {"whole": True, "minimum": 1},
    "eval_batch_size": {"whole": True, "minimum": 1},
    "episode_length": {"whole": True, "minimum": 1},
    "held_out_demos": {"whole": True, "minimum": 0},
    "eval_checkpoints": {"whole": True, "minimum": 1},
}
TEXT_LIST_FIELDS = ("cameras", "perturbations")


def _checked_number(value, label: str, bounds: dict):
    """`value` of a numeric grid field (a number, a list or a per-policy or per-task mapping of them) as
    check_number gives it back: a whole number written 2.0 is 2, so it names the same runs as 2."""
    if isinstance(value, dict):
        return {key: check_number(f"{label} of {key}", v, error=GridError, **bounds) for key, v in value.items()}
    if isinstance(value, (list, tuple)):
        return list(check_numbers(label, value, error=GridError, **bounds))
    return check_number(label, value, error=GridError, **bounds)


def _check_values(values: dict, name: str) -> None:
    """Type and range of every numeric and text field, before anything is built or run; each number in `values` is
    replaced by its checked value."""
    for key, bounds in NUMERIC_FIELDS.items():
        if values.get(key) is not None:
            values[key] = _checked_number(values[key], f"{name}: {key}", bounds)
    for key in TEXT_LIST_FIELDS:
        value = values.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            raise GridError(f"{name}: {key} is a list of names, e.g. [base_camera]; got {value!r}")
    for key in ("name", "description", "preset", "control_mode", "checkpoints_from", "rlbench_data", "clip_weights"):
        if key in values and values[key] is not None and not isinstance(values[key], str):
            raise GridError(f"{name}: {key} is text; got {values[key]!r}")
    for key in ("tasks", "obs_spaces", "policies", *NUMERIC_FIELDS, *TEXT_LIST_FIELDS):
        if isinstance(values.get(key), list):
            _check_listed_once(values[key], key, name)
    if not isinstance(values.get("policy_overrides", {}), dict):
        raise GridError(f"{name}: policy_overrides is a mapping of --policy.* fields to values")
    per_space = values.get("space_overrides", {})
    if not isinstance(per_space, dict) or not all(isinstance(v, dict) for v in per_space.values()):
        raise GridError(
            f"{name}: space_overrides maps spaces to --policy.* fields, e.g. {{rgb: {{encoder_norm: batch}}}}"
        )
    _check_spaces_listed(per_space, values.get("obs_spaces", []), "space_overrides", name)


# the fields parse_grid turns into their values itself; every other grid field passes to Grid as written
PARSED_FIELDS = frozenset(
    "name tasks obs_spaces policies seeds learning_rates demos preset encoders augmentations".split()
)


def parse_grid(data: dict, name: str = "grid") -> Grid:
    _check_field_names(data, name)
    values = dict(data)
    values.setdefault("name", name)
    tasks = _as_list(values.get("tasks"), "tasks")
    rlbench = _check_tasks(values, tasks, name)
    spaces = _choose(_as_list(values.get("obs_spaces"), "obs_spaces"), list(OBS_SPACES), "obs_spaces")
    policies = _as_list(values.get("policies", ["obs_act"]), "policies")
    _named_policies_in_grid_terms(policies, name)
    _choose(policies, list(POLICY_TYPES), "policies")
    preset = values.get("preset", "cpu")
    _choose([preset], list(PRESETS), "preset")
    for key in PER_POLICY:
        if isinstance(values.get(key), dict):
            _choose(list(values[key]), list(policies), f"policies in {key}")
    task_budgets = values.get("task_budgets", {})
    if not isinstance(task_budgets, dict):
        raise GridError(
            f"{name}: task_budgets maps tasks to budgets, e.g. {{PickCube-v1: 30000}}; got {task_budgets!r}"
        )
    _choose(list(task_budgets), tasks, "tasks in task_budgets")
    _check_values(values, name)
    for task in [] if rlbench else tasks:
        try:
            check_cameras(task_spec(task), values.get("cameras", ["base_camera"]))
        except TaskError as err:
            raise GridError(f"{name}: {err}") from None
    grid = Grid(
        name=str(values["name"]),
        tasks=tasks,
        obs_spaces=spaces,
        policies=policies,
        seeds=_as_list(values.get("seeds", [1000]), "seeds"),
        learning_rates=[float(lr) for lr in _as_list(values.get("learning_rates", [1e-4]), "learning_rates")],
        demos=_as_list(values.get("demos", [100]), "demos"),
        preset=preset,
        encoders=_resolve_encoders(values.get("encoders"), spaces, preset, name),
        augmentations=_resolve_augmentations(values.get("augmentations"), spaces, name),
        **{k: values[k] for k in GRID_FIELDS - PARSED_FIELDS if k in values},
    )
    _check_grid(grid, bool(rlbench), name)
    return grid


def _check_field_names(data, name: str) -> None:
    """A grid file is a mapping of known fields, `epochs` refused as ambiguous."""
    if not isinstance(data, dict):
        raise GridError(f"{name}: a grid file is a YAML mapping of fields; got {type(data).__name__}")
    if "epochs" in data:
        raise GridError(
            f"{name}: `epochs` is ambiguous; write `demo_epochs` (the paper's: one sampled frame per demonstration "
            "per epoch) or `frame_epochs` (every frame of every demonstration), or `steps` / `samples`"
        )
    unknown = sorted(set(data) - GRID_FIELDS)
    if unknown:
        raise GridError(f"{name}: unknown grid fields {unknown}; valid fields: {', '.join(sorted(GRID_FIELDS))}")


def _check_tasks(values: dict, tasks: list, name: str) -> list[str]:
    """The grid's tasks: all RLBench tasks (returned) or all ManiSkill tasks (then no RLBench-only field)."""
    rlbench = [t for t in tasks if isinstance(t, str) and grid_task_name(t) is not None]
    if rlbench:
        _check_rlbench(values, tasks, rlbench, name)
        return rlbench
    _choose(tasks, list(TASKS), "tasks")
    for task in tasks:
        task_spec(task)
    given = [k for k in ("rlbench_data", "clip_weights") if values.get(k) is not None]
    if given:
        raise GridError(f"{name}: {', '.join(given)} only apply to RLBench tasks (rlbench/<task>); the grid has none")
    return rlbench


def _check_grid(grid: Grid, rlbench: bool, name: str) -> None:
    """What only the whole grid can tell: one budget unit per policy, valid and distinct perturbations (RLBench's
    among its camera views), the experts' control mode, variants as mappings, and no override of a grid axis."""
    for policy in grid.policies:
        grid.budget(policy)  # exactly one unit per policy
    for text in grid.perturbations:
        try:
            parse_perturbation(text)
        except ValueError as err:
            raise GridError(f"{name}: {err}") from None
    if len(set(grid.perturbations)) != len(grid.perturbations):
        raise GridError(f"{name}: perturbations are listed twice: {grid.perturbations}")
    if rlbench:
        for text in grid.perturbations:
            try:
                camera_view_for(text)
            except ValueError as err:
                raise GridError(f"{name}: {err}") from None
    if grid.control_mode != DEFAULT_CONTROL_MODE:
        raise GridError(
            f"{name}: the scripted experts record demos with control_mode {DEFAULT_CONTROL_MODE}; got "
            f"{grid.control_mode!r}"
        )
    if not grid.variants or not all(isinstance(v, dict) for v in grid.variants):
        raise GridError(f"{name}: variants is a list of mappings of --policy.* fields, e.g. [{{}}, {{sampling: pre}}]")
    _check_listed_once(grid.variants, "variants", name)
    _check_curve(grid, name)
    for where, fields in (
        ("policy_overrides", grid.policy_overrides),
        *((f"space_overrides.{space}", v) for space, v in grid.space_overrides.items()),
        *(("variants", v) for v in grid.variants),
    ):
        clash = sorted(set(fields) & set(AXIS_FIELDS))
        if clash:
            field_name = clash[0]
            raise GridError(
                f"{name}: {where} sets --policy.{field_name}, which the grid sets through {AXIS_FIELDS[field_name]}; "
                f"list the value there instead (the run would train one thing while its results say another)"
            )
    check_policy_configs(grid, name)


def _check_curve(grid: Grid, name: str) -> None:
    """Each of `eval_checkpoints` lies below some run's budget, which must be known before training (not
    frame_epochs)."""
    if not grid.eval_checkpoints:
        return
    runs = grid.expand()
    if any(run.budget_unit == "frame_epochs" for run in runs):
        raise GridError(
            f"{name}: eval_checkpoints are optimizer steps, and a frame_epochs budget's steps are known only "
            "once the demonstrations are recorded; give the budget as steps, samples or demo_epochs"
        )
    longest = max(run.steps() for run in runs)
    late = [step for step in grid.eval_checkpoints if step >= longest]
    if late:
        raise GridError(
            f"{name}: eval_checkpoints {late} are not below the {longest} steps of the grid's longest run (the "
            "last checkpoint ends every curve); list earlier steps"
        )


def _check_rlbench(values: dict, tasks: list, rlbench: list[str], name: str) -> None:
    """An RLBench grid: every task an RLBench task the importer knows, its data folder named, its cameras
    RLBench's, and no ManiSkill-only setting given (each would otherwise be ignored)."""
    others = [t for t in tasks if t not in rlbench]
    if others:
        raise GridError(
            f"{name}: RLBench and ManiSkill tasks in one grid ({rlbench[0]} and {others[0]}); they differ in cameras, "
            "image size and episode budget: put each simulator's tasks in a grid of its own"
        )
    for task in rlbench:
        try:
            rlbench_task(grid_task_name(task))
        except RLBenchTaskError as err:
            raise GridError(f"{name}: {err}") from None
    if not values.get("rlbench_data"):
        raise GridError(
            f"{name}: RLBench tasks need `rlbench_data: DIR`, PerAct's pre-generated data (DIR/train/<task> and "
            "DIR/test/<task>, plus DIR/val/<task> for validation_episodes)"
        )
    values.setdefault("cameras", ["front"])  # the paper's RLBench camera
    bad = [c for c in values["cameras"] if c not in RLBENCH_CAMERAS] if isinstance(values["cameras"], list) else []
    if bad:
        raise GridError(f"{name}: cameras {bad} are not RLBench's; choose from {', '.join(RLBENCH_CAMERAS)}")
    if values.get("image_size", RLBENCH_IMAGE_SIZE) != RLBENCH_IMAGE_SIZE:
        raise GridError(
            f"{name}: image_size {values['image_size']!r}: RLBench grids train on PerAct's data as rendered, "
            f"{RLBENCH_IMAGE_SIZE} x {RLBENCH_IMAGE_SIZE}; leave image_size out"
        )
    for key in ("control_mode", "held_out_demos", "eval_batch_size"):
        if values.get(key):
            raise GridError(
                f"{name}: {key} does not apply to RLBench tasks (they act by end-effector pose planning, are "
                "evaluated one episode at a time in CoppeliaSim, and the held-out diagnostics replay ManiSkill "
                "demonstrations); leave it out"
            )


def check_policy_configs(grid: Grid, name: str) -> None:
    """Build each distinct policy config of the grid now, so an unknown field or a value that does not fit the
    space / encoder (e.g. pre-sampling for rgb) fails before anything runs."""
    import draccus
    from lerobot.configs.policies import PreTrainedConfig

    seen = set()
    for run in grid.expand():
        key = json.dumps(
            [run.policy, run.obs_space, run.encoder, run.policy_overrides, run.augment, run.lr], default=str
        )
        if key in seen:
            continue
        seen.add(key)
        config_class = PreTrainedConfig.get_choice_class(run.policy)
        unknown = sorted(set(dict(run.policy_overrides)) - set(config_class.__dataclass_fields__))
        if unknown:
            raise GridError(
                f"{name}: {run.policy} has no fields {unknown} (policy_overrides / space_overrides / variants)"
            )
        args = [arg.replace("--policy.", "--", 1) for arg in run.policy_args()]
        try:  # lerobot-train's own parser, on the arguments it will get
            draccus.parse(config_class, args=[*args, "--device=cpu"])
        except (ValueError, TypeError, draccus.utils.DraccusException) as err:
            if "Couldn't instantiate" in str(err) and err.__context__ is not None:
                err = err.__context__  # the config's own check, which draccus wraps without its message
            raise GridError(f"{name}: {run.method} with {dict(run.policy_overrides)}: {err}") from None


def preset_grids() -> list[str]:
    """Preset grids ship inside the package (package data), so `obsbench run quick` works from any install."""
    return shipped(GRIDS, ".yaml")


def resolve_grid_path(path_or_preset: str | Path):
    """A grid file's path, or the packaged preset grid of that name."""
    found = path_or_shipped(path_or_preset, GRIDS, ".yaml")
    if found is not None:
        return found
    raise GridError(f"no grid file {str(path_or_preset)!r}; give a YAML path or a preset: {', '.join(preset_grids())}")


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a mapping that names a key twice (plain YAML keeps the last one silently)."""


def _unique_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    lines: dict = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        if key in lines:
            raise yaml.constructor.ConstructorError(
                None, None, f"{key!r} is given twice (lines {lines[key]} and {line}): keep one", key_node.start_mark
            )
        lines[key] = line
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def load_grid(path_or_preset: str | Path) -> Grid:
    path = resolve_grid_path(path_or_preset)
    try:
        data = yaml.load(path.read_text(), Loader=_UniqueKeyLoader)
    except yaml.YAMLError as err:
        raise GridError(f"{path}: not valid YAML: {err}") from None
    return parse_grid(data, name=path.name.removesuffix(".yaml"))
