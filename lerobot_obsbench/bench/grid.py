"""Benchmark grid files: YAML naming tasks x observation spaces x encoders x policies x seeds x learning rates x
demo counts, the training budget, and the evaluations (episodes, episode budget, zero-shot perturbations,
checkpoint selection).

`load_grid(path_or_preset)` validates everything before anything runs (unknown task, space, encoder, policy,
perturbation or field: a `GridError` listing the valid choices). `Grid.expand()` gives one `RunSpec` per
training run and `Grid.evaluations(run)` the `EvalSpec`s of its test evaluations.

What a run and an evaluation are, and their ids: bench/specs.py; the checks: bench/grid_checks.py.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import MISSING, dataclass, fields, replace
from pathlib import Path

import yaml

from lerobot_obsbench.bench.grid_checks import (
    as_list,
    check_tasks,
    check_values,
    choose,
    grid_field,
    refuse_named_policies,
    resolve_augmentations,
    resolve_encoders,
)
from lerobot_obsbench.bench.package_data import GRIDS, path_or_shipped, shipped
from lerobot_obsbench.bench.specs import (
    AXIS_FIELDS,
    BUDGET_UNITS,
    CLIP_GOAL,
    RLBENCH_CONTROL_MODE,
    EvalSpec,
    GridError,
    RunSpec,
)
from lerobot_obsbench.envs.base_task import TaskError, check_cameras
from lerobot_obsbench.envs.catalog import is_metaworld, task_record
from lerobot_obsbench.envs.maniskill import DEFAULT_CONTROL_MODE
from lerobot_obsbench.envs.perturbations import (
    KINDS,
    MANISKILL_KINDS,
    METAWORLD_KINDS,
    PerturbationError,
    applies_to,
    check_supported,
    parse_perturbation,
)
from lerobot_obsbench.presets import PRESETS
from lerobot_obsbench.rlbench.evaluate import MAX_STEPS as RLBENCH_MAX_STEPS
from lerobot_obsbench.rlbench.evaluate import camera_view_for
from lerobot_obsbench.rlbench.paper_tasks import WORKSPACE as RLBENCH_WORKSPACE
from lerobot_obsbench.rlbench.paper_tasks import grid_task_name
from lerobot_obsbench.schema import MIN_IMAGE_SIZE, POLICY_TYPES, available_spaces, is_control, reads_points

COUNT = {"whole": True, "minimum": 1}  # a count of one or more
SOME = {"whole": True, "minimum": 0}  # a count, none allowed
POSITIVE = {"above": 0}


@dataclass
class Grid:
    """A parsed, validated grid file (fields: docs/benchmark.md); each field's check is written beside it
    (`grid_field`, bench/grid_checks.py)."""

    name: str = grid_field(text=True)
    tasks: list[str] = grid_field(resolved=True)
    obs_spaces: list[str] = grid_field(resolved=True)
    policies: list[str] = grid_field(["obs_act"], resolved=True)
    seeds: list[int] = grid_field([1000], number=SOME, shape="axis")
    learning_rates: list[float] = grid_field([1e-4], number=POSITIVE, shape="axis")
    demos: list[int] = grid_field([100], number=COUNT, shape="axis")
    preset: str = grid_field("cpu", text=True, resolved=True)
    encoders: dict[str, list[str]] = grid_field({}, resolved=True)  # obs_space -> encoders
    # obs_space -> training augmentation recipes (`--policy.augment`; "" = none), each a method of its own in the
    # report; a space not listed trains without augmentation
    augmentations: dict[str, list[str]] = grid_field({}, resolved=True)
    # training budget: exactly one unit per policy (module docstring); a number or a mapping policy -> number
    steps: int | dict[str, int] | None = grid_field(None, number=COUNT, shape="per_policy")
    samples: float | dict[str, float] | None = grid_field(None, number=POSITIVE, shape="per_policy")
    demo_epochs: float | dict[str, float] | None = grid_field(None, number=POSITIVE, shape="per_policy")
    frame_epochs: float | dict[str, float] | None = grid_field(None, number=POSITIVE, shape="per_policy")
    # task -> its own budget in the unit its policies are given (e.g. {PickCube-v1: 30000}), for every space alike:
    # a task that needs more steps than the others before its oracle clears blind
    task_budgets: dict[str, float] = grid_field({}, number=POSITIVE, shape="per_task")
    batch_size: int | dict[str, int] = grid_field(32, number=COUNT, shape="per_policy")
    # evenly spaced checkpoints saved during training (for resuming and for checkpoint selection)
    checkpoints: int | dict[str, int] = grid_field(4, number=COUNT, shape="per_policy")
    # > 0: every checkpoint is evaluated on this many validation episodes and the best one is also evaluated
    # on the test seeds (the report shows it by default); 0: the last checkpoint only
    validation_episodes: int = grid_field(0, number=SOME)
    # optimizer steps whose checkpoints the test seeds also evaluate (the nominal scene): each run's learning curve,
    # ending at its last checkpoint; a run's curve has the steps below its budget (each step must lie below some
    # run's). The checkpoints are saved besides `checkpoints`' and kept
    eval_checkpoints: list[int] = grid_field([], number=COUNT, shape="list")
    # demonstrations recorded beyond the most any run trains on, never trained on: each trained run's diagnostics
    # (open-loop action error, objects' pixel size and point-token share; bench/diagnostics.py) are computed on
    # them. 0: no diagnostics but the loss curve
    held_out_demos: int = grid_field(0, number=SOME)
    image_size: int = grid_field(128, number={"whole": True, "minimum": MIN_IMAGE_SIZE})
    cameras: list[str] = grid_field(["base_camera"], names=True)
    control_mode: str = grid_field(DEFAULT_CONTROL_MODE, text=True)
    eval_episodes: int = grid_field(50, number=COUNT)
    # episodes of each perturbed test evaluation (the first of the nominal's test seeds); None: eval_episodes. Fewer
    # buy more perturbations for the same time: a perturbation's effect is read over training seeds and tasks
    perturbed_episodes: int | None = grid_field(None, number=COUNT)
    # ManiSkill evaluations: episodes run in lockstep, each env in a process of its own, one batched policy call
    # per step (envs/evaluate.py); None: the measured default for the device. Not part of a run's identity.
    eval_batch_size: int | None = grid_field(None, number=COUNT)
    # steps per evaluation episode; None: each task's own budget
    episode_length: int | None = grid_field(None, number=COUNT)
    perturbations: list[str] = grid_field([], names=True)
    policy_overrides: dict[str, object] = grid_field({}, mapping="--policy.* fields to values, e.g. {use_vae: false}")
    # obs_space -> `--policy.*` fields for that space's runs only (e.g. {rgb: {encoder_norm: batch}}), applied over
    # policy_overrides
    space_overrides: dict[str, dict[str, object]] = grid_field(
        {}, mapping="spaces to --policy.* fields, e.g. {rgb: {encoder_norm: batch}}"
    )
    variants: list[dict[str, object]] = grid_field([{}])  # extra --policy.* sets, one axis
    # evaluate the checkpoints another grid trained (its output directory) instead of training
    checkpoints_from: str | None = grid_field(None, text=True)
    # RLBench tasks (`rlbench/<task>`): PerAct-format data, DIR/train/<task> imported as the demonstrations,
    # DIR/test/<task> (and DIR/val/<task> for validation_episodes) replayed by the evaluation protocol
    rlbench_data: str | None = grid_field(None, text=True)
    # RLBench: CLIP ViT-B/16 weights (a local file) for the language goal; None: no language goal
    clip_weights: str | None = grid_field(None, text=True)
    description: str = grid_field("", text=True)

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
            control_mode = RLBENCH_CONTROL_MODE if rlbench else task_record(task).control_mode or self.control_mode
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
                        control_mode=control_mode,
                        policy_overrides=tuple(sorted(overrides.items())),
                        language_goal=CLIP_GOAL if rlbench and self.clip_weights else "",
                        augment=augment,
                    )
                )
        return runs

    def piece(self, tasks: list[str] | None = None, obs_spaces: list[str] | None = None) -> Grid:
        """This grid on some of its `tasks` and `obs_spaces` (None: all of them): the same runs with the same ids,
        so pieces run one after another into one output folder add up to the whole grid."""
        chosen = {}
        for field_name, names, flag in (("tasks", tasks, "--tasks"), ("obs_spaces", obs_spaces, "--obs-spaces")):
            own = getattr(self, field_name)
            unknown = [name for name in names or [] if name not in own]
            if unknown:
                raise GridError(
                    f"{flag} {' '.join(unknown)}: not in grid {self.name}'s {field_name} ({', '.join(own)})"
                )
            chosen[field_name] = [name for name in own if names is None or name in names]
        return replace(self, **chosen)

    def max_steps(self, run: RunSpec) -> int:
        return int(self.episode_length or (RLBENCH_MAX_STEPS if run.rlbench_task else task_record(run.task).max_steps))

    def test_checkpoints(self) -> tuple[str, ...]:
        return ("last", "best") if self.validation_episodes else ("last",)

    def curve(self, run: RunSpec) -> tuple[int, ...]:
        """The steps of `run`'s learning curve before its last checkpoint: the eval_checkpoints below its budget."""
        return tuple(step for step in sorted(self.eval_checkpoints) if step < run.steps())

    def evaluations(self, run: RunSpec) -> list[EvalSpec]:
        """The run's test evaluations: each tested checkpoint, nominally and under every perturbation, then its
        learning curve's earlier checkpoints (nominally)."""
        return [
            EvalSpec(
                run.run_id, checkpoint, "test", self.episodes_under(perturbation), perturbation, self.max_steps(run)
            )
            for checkpoint in self.test_checkpoints()
            for perturbation in ("none", *self.perturbations_for(run))
        ] + [
            EvalSpec(run.run_id, f"step:{step}", "test", self.eval_episodes, "none", self.max_steps(run))
            for step in self.curve(run)
        ]

    def episodes_under(self, perturbation: str) -> int:
        """Test episodes of an evaluation under `perturbation` ("none": the nominal one)."""
        return self.perturbed_episodes if perturbation != "none" and self.perturbed_episodes else self.eval_episodes

    def perturbations_for(self, run: RunSpec) -> list[str]:
        """The perturbations a run is evaluated under: those that can change what it reads (none for the controls;
        `depth_noise` for spaces built from depth, light and background for those that read colour): under the
        others its episodes would replay the nominal ones."""
        return [p for p in self.perturbations if applies_to(p, run.obs_space, run.point_features)]

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
    workspace = RLBENCH_WORKSPACE if grid_task_name(task) else task_record(task).workspace
    return {"workspace": list(workspace)} if workspace is not None and reads_points(obs_space) else {}


GRID_FIELDS = fields(Grid)
GRID_FIELD_NAMES = frozenset(spec.name for spec in GRID_FIELDS)
# the fields parse_grid resolves against the registries itself; every other field passes to Grid as checked
RESOLVED_FIELDS = frozenset(spec.name for spec in GRID_FIELDS if spec.metadata["resolved"])


def parse_grid(data: dict, name: str = "grid") -> Grid:
    _check_field_names(data, name)
    values = dict(data)
    values.setdefault("name", name)
    tasks = as_list(values.get("tasks"), "tasks")
    rlbench = check_tasks(values, tasks, name)
    spaces = choose(as_list(values.get("obs_spaces"), "obs_spaces"), list(available_spaces()), "obs_spaces")
    policies = as_list(values.get("policies", _default("policies")), "policies")
    refuse_named_policies(policies, name)
    choose(policies, list(POLICY_TYPES), "policies")
    preset = values.get("preset", _default("preset"))
    choose([preset], list(PRESETS), "preset")
    check_values(values, GRID_FIELDS, {"policies": policies, "tasks": tasks}, name)
    if "learning_rates" in values:
        values["learning_rates"] = [float(lr) for lr in values["learning_rates"]]
    cameras = values.get("cameras", _default("cameras"))
    seeing = [space for space in spaces if not is_control(space)]
    if cameras == [] and seeing:
        raise GridError(
            f"{name}: cameras is empty, and obs_spaces {seeing} read a camera; name one (e.g. [base_camera]) or "
            "leave cameras out for the task's own"
        )
    for task in [] if rlbench else tasks:
        try:
            check_cameras(task_record(task), cameras)
        except TaskError as err:
            raise GridError(f"{name}: {err}") from None
    grid = Grid(
        tasks=tasks,
        obs_spaces=spaces,
        policies=policies,
        preset=preset,
        encoders=resolve_encoders(values.get("encoders"), spaces, preset, name),
        augmentations=resolve_augmentations(values.get("augmentations"), spaces, name),
        **{key: value for key, value in values.items() if key not in RESOLVED_FIELDS},
    )
    _check_grid(grid, bool(rlbench), name)
    return grid


def _default(field_name: str):
    """The default of a Grid field (a fresh copy of a list or mapping)."""
    spec = Grid.__dataclass_fields__[field_name]
    return spec.default if spec.default_factory is MISSING else spec.default_factory()


def _check_field_names(data, name: str) -> None:
    """A grid file is a mapping of known fields, `epochs` refused as ambiguous."""
    if not isinstance(data, dict):
        raise GridError(f"{name}: a grid file is a YAML mapping of fields; got {type(data).__name__}")
    if "epochs" in data:
        raise GridError(
            f"{name}: `epochs` is ambiguous; write `demo_epochs` (the paper's: one sampled frame per demonstration "
            "per epoch) or `frame_epochs` (every frame of every demonstration), or `steps` / `samples`"
        )
    unknown = sorted(set(data) - GRID_FIELD_NAMES)
    if unknown:
        raise GridError(f"{name}: unknown grid fields {unknown}; valid fields: {', '.join(sorted(GRID_FIELD_NAMES))}")


def _check_grid(grid: Grid, rlbench: bool, name: str) -> None:
    """What only the whole grid can tell: one budget unit per policy, valid and distinct perturbations (RLBench's
    among its camera views), the experts' control mode, variants as mappings, and no override of a grid axis."""
    for policy in grid.policies:
        grid.budget(policy)  # exactly one unit per policy
    for text in grid.perturbations:
        try:
            _check_perturbation(grid, text)
        except ValueError as err:
            raise GridError(f"{name}: {err}") from None
    if grid.perturbed_episodes is not None and not grid.perturbations:
        raise GridError(
            f"{name}: perturbed_episodes is set but perturbations is empty; list perturbations or leave it out"
        )
    if (grid.perturbed_episodes or 0) > grid.eval_episodes:
        raise GridError(
            f"{name}: perturbed_episodes ({grid.perturbed_episodes}) is more than eval_episodes "
            f"({grid.eval_episodes}): a perturbed evaluation runs the first of the nominal's test seeds"
        )
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
    _check_curve(grid, name)
    for where, overrides in (
        ("policy_overrides", grid.policy_overrides),
        *((f"space_overrides.{space}", v) for space, v in grid.space_overrides.items()),
        *(("variants", v) for v in grid.variants),
    ):
        clash = sorted(set(overrides) & set(AXIS_FIELDS))
        if clash:
            field_name = clash[0]
            raise GridError(
                f"{name}: {where} sets --policy.{field_name}, which the grid sets through {AXIS_FIELDS[field_name]}; "
                f"list the value there instead (the run would train one thing while its results say another)"
            )
    check_policy_configs(grid, name)


def _check_perturbation(grid: Grid, text: str) -> None:
    """A perturbation of the grid: written rightly, applied by the env of every task's family (RLBench's camera
    views: `camera_view_for`), and able to change what some space of the grid sees."""
    perturbation = parse_perturbation(text)
    for task in grid.tasks:
        if grid_task_name(task) is None:
            metaworld = is_metaworld(task_record(task))
            kinds, family = (METAWORLD_KINDS, "Meta-World") if metaworld else (MANISKILL_KINDS, "ManiSkill")
            check_supported(perturbation, kinds, family)
    if not any(applies_to(text, run.obs_space, run.point_features) for run in grid.expand()):
        raise PerturbationError(
            f"perturbations: {text} changes only what spaces reading {KINDS[perturbation.kind].changes_text} see, "
            f"and none of obs_spaces {grid.obs_spaces} does; add such a space or leave it out"
        )


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
