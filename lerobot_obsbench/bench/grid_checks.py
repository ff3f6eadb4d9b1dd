"""The checks a grid file passes before anything runs: each field's type and range (the project's one rule for
numbers, lerobot_obsbench.numeric), the names it lists against the registries (tasks, spaces, encoders, recipes,
policies), and what only the whole grid can tell (one budget per policy, curves, overrides of an axis). Each
refusal is a `GridError` naming the field and the valid choices."""

from __future__ import annotations

import copy
import dataclasses
import json
from dataclasses import MISSING, field

from lerobot_obsbench.bench.specs import GridError
from lerobot_obsbench.envs.base_task import TASKS, task_spec
from lerobot_obsbench.envs.catalog import task_record
from lerobot_obsbench.envs.metaworld.tasks import DEFAULT_CAMERA as METAWORLD_CAMERA
from lerobot_obsbench.envs.metaworld.tasks import is_metaworld_name
from lerobot_obsbench.numeric import check_number, check_numbers
from lerobot_obsbench.presets import preset_encoder
from lerobot_obsbench.rlbench.paper_tasks import CAMERAS as RLBENCH_CAMERAS
from lerobot_obsbench.rlbench.paper_tasks import IMAGE_SIZE as RLBENCH_IMAGE_SIZE
from lerobot_obsbench.rlbench.paper_tasks import RLBenchTaskError, grid_task_name, rlbench_task
from lerobot_obsbench.schema import is_control


def as_list(value, name: str) -> list:
    if value is None:
        raise GridError(f"grid field {name!r} is required")
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if not values:
        raise GridError(f"grid field {name!r} is empty: it needs at least one value")
    return values


def refuse_named_policies(policies: list, name: str) -> None:
    """A named type (act_pcd, ...) is one policy type, space and encoder; a grid lists those on their own axes."""
    from lerobot_obsbench.policies.named import NAMED_POLICIES

    named = next((p for p in policies if p in NAMED_POLICIES), None)
    if named is not None:
        policy, space, encoder = NAMED_POLICIES[named]
        raise GridError(
            f"{name}: policies lists {named}, a named type; a grid sets its parts on their own axes: "
            f"policies: [{policy}], obs_spaces: [{space}], encoders: {{{space}: [{encoder}]}}"
        )


def choose(values: list, valid, name: str) -> list:
    bad = [v for v in values if v not in valid]
    if bad:
        raise GridError(f"unknown {name} {bad}; valid choices: {', '.join(valid)}")
    return values


def resolve_encoders(spec, spaces: list[str], preset: str, name: str) -> dict[str, list[str]]:
    """`encoders` may be omitted (the preset's choice per space), a list (each space takes the listed
    encoders that accept it; every listed encoder must fit some space) or a mapping space -> encoders (strict)."""
    from lerobot_obsbench.encoders import available_encoders, check_encoder, encoder_info

    if spec is None:
        return {s: [preset_encoder(preset, s)] for s in spaces}
    if isinstance(spec, dict):
        _check_spaces_listed(spec, spaces, "encoders", name)
        resolved = {}
        for space in spaces:
            names = as_list(spec.get(space, preset_encoder(preset, space)), f"encoders.{space}")
            check_listed_once(names, f"encoders.{space}", name)
            for name in names:
                try:
                    check_encoder(name, space)
                except ValueError as err:
                    raise GridError(str(err)) from None
            resolved[space] = names
        return resolved
    names = as_list(spec, "encoders")
    check_listed_once(names, "encoders", name)
    choose(names, available_encoders(), "encoders")
    resolved = {s: [n for n in names if s in encoder_info(n).spaces] for s in spaces}
    for space, chosen in resolved.items():
        if not chosen and is_control(space):
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


def resolve_augmentations(spec, spaces: list[str], name: str) -> dict[str, list[str]]:
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
        written = ["" if r is None else r for r in as_list(written, f"augmentations.{space}")]
        recipes = []
        for recipe in written:
            if not isinstance(recipe, str):
                raise GridError(f"{name}: augmentations.{space} lists recipes as text; got {recipe!r}")
            try:
                recipes.append(normalised_recipe(recipe, space))
            except AugmentationError as err:
                raise GridError(f"{name}: augmentations.{space}: {err}") from None
        check_listed_once(recipes, f"augmentations.{space}", name, written)
        resolved[space] = recipes
    return resolved


def check_listed_once(values: list, field_name: str, name: str, written: list | None = None) -> None:
    """An axis lists each of its values once (`written`: the values as the file spells them, where the grid
    normalises them); a repeated value is one point of the grid given twice."""
    repeated = sorted({json.dumps(v) for v in values if values.count(v) > 1})
    if repeated:
        spelling = f" (written {written})" if written is not None and written != values else ""
        raise GridError(
            f"{name}: {field_name} lists {', '.join(repeated)} more than once{spelling}; each value is one point of "
            "the grid (listed twice, it would train the same runs twice): list it once"
        )


def grid_field(
    default=MISSING,
    *,
    number: dict | None = None,
    shape: str = "one",
    text: bool = False,
    names: bool = False,
    mapping: str | None = None,
    resolved: bool = False,
):
    """A `Grid` field with its check written beside its type and default, for `check_values`: `number`, the bounds
    lerobot_obsbench.numeric.check_number takes (the project's one rule for numbers), applied by `shape` ("one"
    number; a "list" of them; an "axis", one value or a list of them; "per_policy", a number or a mapping policy ->
    number; "per_task", a mapping task -> number); `text` (a string), `names` (a list of non-empty strings),
    `mapping` (a mapping, described in the refusal); `resolved` (parse_grid resolves it against a registry). A list
    or mapping default is copied for each grid."""
    meta = {"number": number, "shape": shape, "text": text, "names": names, "mapping": mapping, "resolved": resolved}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: copy.deepcopy(default), metadata=meta)
    return field(default=default, metadata=meta)


def _checked_number(value, spec: dataclasses.Field, label: str, keys: dict[str, list]):
    """`value` of a numeric grid field, by its shape, as check_number gives it back: a whole number written 2.0 is
    2, so it names the same runs as 2."""
    bounds, shape = spec.metadata["number"], spec.metadata["shape"]
    if shape == "per_task" and not isinstance(value, dict):
        raise GridError(f"{label} maps tasks to budgets, e.g. {{PickCube-v1: 30000}}; got {value!r}")
    if isinstance(value, dict) and shape in ("per_policy", "per_task"):
        owners = "policies" if shape == "per_policy" else "tasks"
        choose(list(value), keys[owners], f"{owners} in {spec.name}")
        return {key: check_number(f"{label} of {key}", v, error=GridError, **bounds) for key, v in value.items()}
    if shape == "axis" and not isinstance(value, (list, tuple)):
        return [check_number(label, value, error=GridError, **bounds)]
    if shape == "axis":
        as_list(value, spec.name)  # an empty axis is refused
    if shape in ("axis", "list"):
        return list(check_numbers(label, value, error=GridError, **bounds))
    return check_number(label, value, error=GridError, **bounds)


def check_values(values: dict, fields: tuple[dataclasses.Field, ...], keys: dict[str, list], name: str) -> None:
    """Type and range of every field given, by the check written beside it (`grid_field`), before anything is
    built or run; each number in `values` is replaced by its checked value. `keys`: the grid's policies and tasks,
    which per-policy and per-task mappings name. `null` is a value only where it is the field's default."""
    for spec in fields:
        if spec.name not in values or (values[spec.name] is None and spec.default is None):
            continue
        value = values[spec.name]
        label = f"{name}: {spec.name}"
        if spec.metadata["number"] is not None:
            values[spec.name] = value = _checked_number(value, spec, label, keys)
        if spec.metadata["names"] and not (isinstance(value, list) and all(isinstance(v, str) and v for v in value)):
            raise GridError(f"{label} is a list of names, e.g. [base_camera]; got {value!r}")
        if spec.metadata["text"] and not isinstance(value, str):
            raise GridError(f"{label} is text; got {value!r}")
        if spec.metadata["mapping"] and not isinstance(value, dict):
            raise GridError(f"{label} maps {spec.metadata['mapping']}; got {value!r}")
        if isinstance(value, list):
            check_listed_once(value, spec.name, name)
    per_space = values.get("space_overrides") or {}
    if not all(isinstance(v, dict) for v in per_space.values()):
        raise GridError(
            f"{name}: space_overrides maps spaces to --policy.* fields, e.g. {{rgb: {{encoder_norm: batch}}}}"
        )
    _check_spaces_listed(per_space, values.get("obs_spaces", []), "space_overrides", name)


def check_tasks(values: dict, tasks: list, name: str) -> list[str]:
    """The grid's tasks: all RLBench tasks (returned), or all ManiSkill or all Meta-World tasks (then no RLBench-only
    field)."""
    rlbench = [t for t in tasks if isinstance(t, str) and grid_task_name(t) is not None]
    if rlbench:
        _check_rlbench(values, tasks, rlbench, name)
        return rlbench
    metaworld = [t for t in tasks if isinstance(t, str) and is_metaworld_name(t)]
    if metaworld:
        _check_metaworld(values, tasks, metaworld, name)
    else:
        choose(tasks, list(TASKS), "tasks")
        for task in tasks:
            task_spec(task)
    given = [k for k in ("rlbench_data", "clip_weights") if values.get(k) is not None]
    if given:
        raise GridError(f"{name}: {', '.join(given)} only apply to RLBench tasks (rlbench/<task>); the grid has none")
    return rlbench


def _refuse_other_simulators(tasks: list, own: list[str], simulator: str, name: str) -> None:
    """A grid of `simulator`'s tasks (`own`) holds no other simulator's."""
    others = [t for t in tasks if t not in own]
    if others:
        raise GridError(
            f"{name}: {simulator} and ManiSkill tasks in one grid ({own[0]} and {others[0]}); simulators differ in "
            "robot, cameras, image size and episode budget: put each simulator's tasks in a grid of its own"
        )


def _check_metaworld(values: dict, tasks: list, metaworld: list[str], name: str) -> None:
    """A Meta-World grid: every task one LeRobot lists, no task of another simulator, and `corner2` (LeRobot's
    camera) unless the grid names its cameras."""
    _refuse_other_simulators(tasks, metaworld, "Meta-World", name)
    for task in metaworld:
        try:
            task_record(task)  # (a ManiSkill name written in lower case reads as Meta-World's: named as ManiSkill's)
        except ValueError as err:
            raise GridError(f"{name}: {err}") from None
    values.setdefault("cameras", [METAWORLD_CAMERA])


def _check_rlbench(values: dict, tasks: list, rlbench: list[str], name: str) -> None:
    """An RLBench grid: every task an RLBench task the importer knows, its data folder named, its cameras
    RLBench's, and no ManiSkill-only setting given (each would otherwise be ignored)."""
    _refuse_other_simulators(tasks, rlbench, "RLBench", name)
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
