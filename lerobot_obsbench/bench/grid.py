"""Benchmark grid files: YAML naming tasks x observation spaces x encoders x policies x seeds x learning rates x
demo counts, the training budget and the evaluation (episodes, zero-shot perturbations).

`load_grid(path_or_preset)` validates everything before anything runs (unknown task, space, encoder, policy,
perturbation or field: a `GridError` listing the valid choices) and `Grid.expand()` gives one `RunSpec` per
training run. A run's identity is the SHA-256 of its resolved config (`RunSpec.run_id`): the results store
skips runs whose id it already holds, so editing a grid only adds the runs that changed.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path

import yaml

from lerobot_obsbench.envs.maniskill import DEFAULT_CONTROL_MODE
from lerobot_obsbench.envs.perturbations import parse_perturbation
from lerobot_obsbench.envs.task import TASKS, task_spec
from lerobot_obsbench.presets import PRESETS, preset_encoder, preset_overrides
from lerobot_obsbench.schema import OBS_SPACES, POLICY_TYPES

# Preset grids ship inside the package (package data), so `obsbench run quick` works from any install.
PRESET_GRIDS = resources.files("lerobot_obsbench.bench") / "grids"


class GridError(ValueError):
    """A grid file names something that does not exist or does not fit together."""


@dataclass(frozen=True)
class RunSpec:
    """One training run (then its evaluations): everything that determines its result."""

    task: str
    obs_space: str
    encoder: str
    policy: str
    seed: int
    lr: float
    demos: int
    preset: str
    batch_size: int
    steps: int | None  # optimizer steps; None = derived from `epochs` and the demo frames at run time
    epochs: float | None
    image_size: int
    cameras: tuple[str, ...]
    control_mode: str
    eval_episodes: int
    perturbations: tuple[str, ...]
    policy_overrides: tuple[tuple[str, object], ...] = ()

    def config(self) -> dict:
        data = asdict(self)
        data["cameras"] = list(self.cameras)
        data["perturbations"] = list(self.perturbations)
        data["policy_overrides"] = dict(self.policy_overrides)
        return data

    @property
    def run_id(self) -> str:
        canonical = json.dumps(self.config(), sort_keys=True, separators=(",", ":"), default=str)
        return hashlib.sha256(canonical.encode()).hexdigest()[:16]

    @property
    def method(self) -> str:
        """Column label in reports: what differs between the compared methods."""
        return f"{self.policy}/{self.obs_space}/{self.encoder}"

    @property
    def demo_key(self) -> str:
        """Runs sharing this key train on (a prefix of) the same demonstration dataset."""
        return f"{self.task}-{self.image_size}px-{'+'.join(self.cameras)}-{self.control_mode}"

    @classmethod
    def from_config(cls, config: dict) -> RunSpec:
        data = dict(config)
        data["cameras"] = tuple(data["cameras"])
        data["perturbations"] = tuple(data["perturbations"])
        data["policy_overrides"] = tuple(sorted(data.get("policy_overrides", {}).items()))
        return cls(**data)


def _as_list(value, name: str) -> list:
    if value is None:
        raise GridError(f"grid field {name!r} is required")
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if not values:
        raise GridError(f"grid field {name!r} is empty: it needs at least one value")
    return values


def _choose(values: list, valid, name: str) -> list:
    bad = [v for v in values if v not in valid]
    if bad:
        raise GridError(f"unknown {name} {bad}; valid choices: {', '.join(valid)}")
    return values


@dataclass
class Grid:
    """A parsed, validated grid file (fields: README, "The benchmark")."""

    name: str
    tasks: list[str]
    obs_spaces: list[str]
    policies: list[str]
    seeds: list[int]
    learning_rates: list[float]
    demos: list[int]
    preset: str = "cpu"
    encoders: dict[str, list[str]] = field(default_factory=dict)  # obs_space -> encoders
    batch_size: int = 32
    steps: int | dict[str, int] | None = None
    epochs: float | dict[str, float] | None = None
    image_size: int = 128
    cameras: list[str] = field(default_factory=lambda: ["base_camera"])
    control_mode: str = DEFAULT_CONTROL_MODE
    eval_episodes: int = 50
    perturbations: list[str] = field(default_factory=list)
    policy_overrides: dict[str, object] = field(default_factory=dict)
    variants: list[dict[str, object]] = field(default_factory=lambda: [{}])  # extra --policy.* sets, one axis
    description: str = ""

    def budget(self, policy: str) -> tuple[int | None, float | None]:
        def pick(value):
            return value.get(policy) if isinstance(value, dict) else value

        return pick(self.steps), pick(self.epochs)

    def expand(self) -> list[RunSpec]:
        runs = []
        for task, space, policy, variant, demos, lr, seed in itertools.product(
            self.tasks, self.obs_spaces, self.policies, self.variants, self.demos, self.learning_rates, self.seeds
        ):
            steps, epochs = self.budget(policy)
            overrides = {**self.policy_overrides, **variant}
            for encoder in self.encoders[space]:
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
                        batch_size=self.batch_size,
                        steps=steps,
                        epochs=epochs,
                        image_size=self.image_size,
                        cameras=tuple(self.cameras),
                        control_mode=self.control_mode,
                        eval_episodes=self.eval_episodes,
                        perturbations=tuple(self.perturbations),
                        policy_overrides=tuple(sorted(overrides.items())),
                    )
                )
        return runs


GRID_FIELDS = {f for f in Grid.__dataclass_fields__}


def _resolve_encoders(spec, spaces: list[str], preset: str) -> dict[str, list[str]]:
    """`encoders` may be omitted (the preset's choice per space), a list (each space takes the listed
    encoders that accept it; every listed encoder must fit some space) or a mapping space -> encoders (strict)."""
    from lerobot_obsbench.encoders import available_encoders, check_encoder

    if spec is None:
        return {s: [preset_encoder(preset, s)] for s in spaces}
    if isinstance(spec, dict):
        extra = [s for s in spec if s not in spaces]
        if extra:
            raise GridError(f"encoders names spaces {extra} that are not in obs_spaces {spaces}")
        resolved = {}
        for space in spaces:
            names = _as_list(spec.get(space, preset_encoder(preset, space)), f"encoders.{space}")
            for name in names:
                try:
                    check_encoder(name, space)
                except ValueError as err:
                    raise GridError(str(err)) from None
            resolved[space] = names
        return resolved
    names = _as_list(spec, "encoders")
    _choose(names, available_encoders(), "encoders")
    resolved = {s: [n for n in names if s in _accepts(n)] for s in spaces}
    for name in names:
        if not any(name in resolved[s] for s in spaces):
            raise GridError(
                f"encoder {name!r} accepts none of the grid's obs_spaces {spaces} (it accepts "
                f"{', '.join(_accepts(name))})"
            )
    for space, chosen in resolved.items():
        if not chosen:
            raise GridError(
                f"no listed encoder accepts obs_space {space!r}; encoders for it: "
                f"{', '.join(available_encoders(space))}"
            )
    return resolved


def _accepts(name: str) -> tuple[str, ...]:
    from lerobot_obsbench.encoders import encoder_info

    return encoder_info(name).spaces


def parse_grid(data: dict, name: str = "grid") -> Grid:
    if not isinstance(data, dict):
        raise GridError(f"{name}: a grid file is a YAML mapping of fields; got {type(data).__name__}")
    unknown = sorted(set(data) - GRID_FIELDS)
    if unknown:
        raise GridError(f"{name}: unknown grid fields {unknown}; valid fields: {', '.join(sorted(GRID_FIELDS))}")
    values = dict(data)
    values.setdefault("name", name)
    tasks = _choose(_as_list(values.get("tasks"), "tasks"), list(TASKS), "tasks")
    for task in tasks:
        task_spec(task)
    spaces = _choose(_as_list(values.get("obs_spaces"), "obs_spaces"), list(OBS_SPACES), "obs_spaces")
    policies = _choose(_as_list(values.get("policies", ["obs_act"]), "policies"), list(POLICY_TYPES), "policies")
    preset = values.get("preset", "cpu")
    _choose([preset], list(PRESETS), "preset")
    grid = Grid(
        name=str(values["name"]),
        tasks=tasks,
        obs_spaces=spaces,
        policies=policies,
        seeds=[int(s) for s in _as_list(values.get("seeds", [1000]), "seeds")],
        learning_rates=[float(lr) for lr in _as_list(values.get("learning_rates", [1e-4]), "learning_rates")],
        demos=[int(n) for n in _as_list(values.get("demos", [100]), "demos")],
        preset=preset,
        encoders=_resolve_encoders(values.get("encoders"), spaces, preset),
        **{
            k: values[k]
            for k in (
                "batch_size",
                "steps",
                "epochs",
                "image_size",
                "cameras",
                "control_mode",
                "eval_episodes",
                "perturbations",
                "policy_overrides",
                "variants",
                "description",
            )
            if k in values
        },
    )
    for policy in policies:
        steps, epochs = grid.budget(policy)
        if (steps is None) == (epochs is None):
            raise GridError(
                f"{name}: give exactly one training budget for {policy}: `steps` (optimizer steps) or "
                "`epochs` (passes over the demos), as a number or a mapping policy -> number"
            )
    if min(grid.demos) < 1 or grid.eval_episodes < 1 or grid.batch_size < 1:
        raise GridError(f"{name}: demos, eval_episodes and batch_size must be >= 1")
    for text in grid.perturbations:
        try:
            parse_perturbation(text)
        except ValueError as err:
            raise GridError(f"{name}: {err}") from None
    if len(set(grid.perturbations)) != len(grid.perturbations):
        raise GridError(f"{name}: perturbations are listed twice: {grid.perturbations}")
    if grid.control_mode != DEFAULT_CONTROL_MODE:
        raise GridError(
            f"{name}: the scripted experts record demos with control_mode {DEFAULT_CONTROL_MODE}; got "
            f"{grid.control_mode!r}"
        )
    if not grid.variants or not all(isinstance(v, dict) for v in grid.variants):
        raise GridError(f"{name}: variants is a list of mappings of --policy.* fields, e.g. [{{}}, {{sampling: pre}}]")
    check_policy_configs(grid, name)
    return grid


def check_policy_configs(grid: Grid, name: str) -> None:
    """Build each distinct policy config of the grid now, so an unknown field or a value that does not fit the
    space / encoder (e.g. pre-sampling for rgb) fails before anything runs."""
    from lerobot.configs.policies import PreTrainedConfig

    seen = set()
    for run in grid.expand():
        key = json.dumps([run.policy, run.obs_space, run.encoder, run.policy_overrides], default=str)
        if key in seen:
            continue
        seen.add(key)
        config_class = PreTrainedConfig.get_choice_class(run.policy)
        fields = {
            **preset_overrides(run.preset, run.policy, run.obs_space),
            "encoder": run.encoder,
            **dict(run.policy_overrides),
        }
        unknown = sorted(set(fields) - set(config_class.__dataclass_fields__))
        if unknown:
            raise GridError(f"{name}: {run.policy} has no fields {unknown} (policy_overrides / variants)")
        try:
            config_class(obs_space=run.obs_space, device="cpu", **fields)
        except (ValueError, TypeError) as err:
            raise GridError(f"{name}: {run.method} with {dict(run.policy_overrides)}: {err}") from None


def preset_grids() -> list[str]:
    return sorted(p.name.removesuffix(".yaml") for p in PRESET_GRIDS.iterdir() if p.name.endswith(".yaml"))


def resolve_grid_path(path_or_preset: str | Path):
    """A grid file's path, or the packaged preset grid of that name."""
    path = Path(path_or_preset)
    if path.is_file():
        return path
    preset = PRESET_GRIDS / f"{path_or_preset}.yaml"
    if preset.is_file():
        return preset
    raise GridError(f"no grid file {str(path_or_preset)!r}; give a YAML path or a preset: {', '.join(preset_grids())}")


def load_grid(path_or_preset: str | Path) -> Grid:
    path = resolve_grid_path(path_or_preset)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise GridError(f"{path}: not valid YAML: {err}") from None
    return parse_grid(data, name=path.name.removesuffix(".yaml"))


# Rough 2-core CPU costs per training sample (cpu: measured on the quick grid at 64 px, ~0.25 s per batch of 16)
# for `--dry-run` estimates only.
SECONDS_PER_SAMPLE = {"tiny": 0.01, "cpu": 0.017, "paper": 0.4}
DEMO_FRAMES_PER_EPISODE = 30
ENV_STEPS_PER_SECOND = 15.0


def estimate_seconds(run: RunSpec) -> float:
    """Order-of-magnitude wall time of one run on a 2-core CPU (training + every evaluation)."""
    steps = run.steps or math.ceil(run.epochs * run.demos * DEMO_FRAMES_PER_EPISODE / run.batch_size)
    train = steps * run.batch_size * SECONDS_PER_SAMPLE[run.preset] * max(run.image_size / 64, 1) ** 2 + 20
    evaluations = 1 + len(run.perturbations)
    episode = task_spec(run.task).max_steps * 0.6 / ENV_STEPS_PER_SECOND
    return train + evaluations * (run.eval_episodes * episode + 5)
