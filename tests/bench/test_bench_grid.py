"""Grid files: presets expand and validate; bad grids fail before anything runs, naming the valid choices."""

from __future__ import annotations

import json
import math
import re
import shutil

import numpy as np
import pytest
import yaml

from lerobot_obsbench.bench.grid import GRID_FIELDS, load_grid, parse_grid, preset_grids
from lerobot_obsbench.bench.results import append_result
from lerobot_obsbench.bench.specs import AXIS_FIELDS, EvalSpec, GridError, RunSpec
from lerobot_obsbench.bench.units import demo_dir, kept_checkpoints, save_freq, train_command
from lerobot_obsbench.cli import main
from lerobot_obsbench.envs.perturbations import orbit_eye, parse_perturbation
from lerobot_obsbench.numeric import check_number
from lerobot_obsbench.presets import preset_overrides
from tests.commands.test_train_cli import policy_fields, preset_cases
from tests.support.paths import REPO_ROOT

BASE = {"tasks": ["PushCube-v1"], "obs_spaces": ["rgb", "pointcloud"], "steps": 10, "preset": "tiny"}


def test_every_preset_grid_says_what_it_is_in_a_header_of_eight_lines_or_fewer():
    """A grid file's header is its one-paragraph why; the details live in docs/ (a longer header is prose that
    belongs on a page)."""
    from lerobot_obsbench.bench.package_data import GRIDS, path_or_shipped

    for name in preset_grids():
        path = path_or_shipped(name, GRIDS, ".yaml")
        lines = path.read_text().splitlines()
        header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
        assert 1 <= header <= 8, f"{path.name}: a header of {header} lines"


def test_the_q3_and_q4_grids_keep_the_run_ids_of_the_published_runs_they_contain():
    """cpu-robustness-* train the published suites' runs (the same training fields): their unperturbed evaluations
    are those suites' runs again, which a re-run under the pinned kernels gives identical."""
    metaworld = {r.run_id for r in load_grid("cpu-metaworld").expand()}
    assert {r.run_id for r in load_grid("cpu-robustness-metaworld").expand()} <= metaworld
    maniskill = {r.run_id for g in ("quick", "cpu-ranking") for r in load_grid(g).expand()}
    assert {r.run_id for r in load_grid("cpu-robustness-maniskill").expand()} <= maniskill
    # the sample-efficiency grids' largest demonstration counts are the published suites' runs too
    most = [r for r in load_grid("cpu-sample-efficiency-metaworld").expand() if r.demos == 50]
    assert len(most) == 45 and {r.run_id for r in most} <= metaworld
    pushes = [r for r in load_grid("cpu-sample-efficiency-maniskill").expand() if r.demos == 200]
    quick = {r.run_id for r in load_grid("quick").expand()}
    assert {r.run_id for r in pushes if r.task == "PushCubeWide-v1"} == quick


def _own_box(task: str) -> list | None:
    """The crop box `task` sets for its point-cloud runs (None: it has none, and the policy's default crops)."""
    from lerobot_obsbench.envs.catalog import task_record

    box = task_record(task).workspace
    return None if box is None else list(box)


CPU_SUITE_HOURS = 6.0  # a CPU suite's limit: its dry run with two local workers on a 2-core machine


@pytest.mark.parametrize("name", [n for n in preset_grids() if n.startswith("cpu-")])
def test_every_cpu_suite_keeps_the_suites_rules(name, capsys):
    """What makes a CPU suite's answer worth reading, for every `cpu-*` grid (a new one included): three or more
    training seeds (its intervals cover training variance), the oracle beside the blind control wherever blind is
    listed, each point-cloud run cropped to its own task's box, a dry run priced within the suites' limit, and every
    task either measured by the cost model's rates or named by the dry run as priced at the defaults."""
    from lerobot_obsbench.bench.cost import EVAL_TASK_FACTOR, EXPERT_MEAN_STEPS
    from lerobot_obsbench.envs.metaworld.tasks import is_metaworld_name

    grid = load_grid(name)
    runs = grid.expand()
    assert len(set(grid.seeds)) >= 3
    spaces = {r.obs_space for r in runs}
    assert "none" not in spaces or "state" in spaces, "blind without the oracle"
    for run in runs:
        if run.obs_space == "pointcloud":
            assert dict(run.policy_overrides).get("workspace") == _own_box(run.task), run.task
    assert main(["run", name, "--dry-run", "--out", "/nonexistent/out", "--workers", "2"]) == 0
    text = capsys.readouterr().out
    assert _hours("with 2 local workers: ~HOURS h of wall time", text) <= CPU_SUITE_HOURS
    defaults = re.search(r"priced at the defaults, not measured: (.*)", text)
    for task in grid.tasks:
        measured = task in EXPERT_MEAN_STEPS and (is_metaworld_name(task) or task in EVAL_TASK_FACTOR["cpu"])
        assert measured or (defaults and f"{task} (" in defaults.group(1)), f"{task}: priced silently"


def test_presets_expand_and_validate():
    assert {"quick", "paper-main", "paper-sample-efficiency", "paper-generalization", "paper-design"} <= set(
        preset_grids()
    )
    sizes = {}
    for name in preset_grids():
        runs = load_grid(name).expand()
        assert runs, name
        assert len({r.run_id for r in runs}) == len(runs), f"{name}: two runs share an id"
        sizes[name] = runs
    # paper-main: 3 tasks x 7 (space, encoder) pairs of Table 2 x 2 policies x 3 lrs x 2 seeds (each lr twice)
    assert len(sizes["paper-main"]) == 3 * 7 * 2 * 3 * 2
    pairs = {(r.obs_space, r.encoder) for r in sizes["paper-main"]}
    assert pairs == {
        ("rgb", "resnet50"),
        ("rgb", "vit_b"),
        ("rgbd", "resnet50"),
        ("rgbd", "vit_b"),
        ("rgbd", "multivit_b"),
        ("pointcloud", "pointnet"),
        ("pointcloud", "spunet34"),
    }
    assert {r.demos for r in sizes["paper-sample-efficiency"]} == {10, 25, 100}
    main_grid = load_grid("paper-main")
    assert all(r.preset == "paper" and r.demos == 1000 for r in sizes["paper-main"])
    assert {len(main_grid.evaluations(r)) for r in sizes["paper-main"]} == {2}  # last and best-on-validation
    assert {s.episodes for r in sizes["paper-main"] for s in main_grid.evaluations(r)} == {400}
    generalization = load_grid("paper-generalization")
    assert len(generalization.perturbations) == 20 and generalization.checkpoints_from
    # an evaluation-only grid names runs of the training grid: the same training identities
    assert {r.run_id for r in sizes["paper-generalization"]} <= {r.run_id for r in sizes["paper-main"]}
    quick = sizes["quick"]
    # the two controls bracket two seeing spaces
    assert {"none", "state", "rgb", "pointcloud"} <= {r.obs_space for r in quick}
    quick_grid = load_grid("quick")
    moved = {"none", "camera_yaw:10", "camera_pitch:10"}
    for r in quick:  # the camera moves only for the spaces that read it
        expected = {"none"} if r.obs_space in ("none", "state") else moved
        assert {s.perturbation for s in quick_grid.evaluations(r)} == expected
    # the crop box of the task reaches its point-cloud runs, and only them
    workspaces = {r.obs_space: dict(r.policy_overrides).get("workspace") for r in quick}
    assert workspaces["pointcloud"] == [-0.2, 0.45, -0.35, 0.35, 0.005, 0.1] and workspaces["rgb"] is None
    assert quick_grid.held_out_demos > 0


def test_variants_are_an_axis_and_a_column_label():
    runs = parse_grid(
        {**BASE, "obs_spaces": ["pointcloud"], "variants": [{}, {"sampling": "pre"}, {"point_features": "xyz"}]}
    ).expand()
    assert [dict(r.policy_overrides) for r in runs] == [{}, {"sampling": "pre"}, {"point_features": "xyz"}]
    assert len({r.run_id for r in runs}) == 3


def test_augmentations_are_an_axis_per_space_whose_unaugmented_runs_keep_their_ids(tmp_path):
    plain = parse_grid(BASE).expand()
    grid = parse_grid({**BASE, "augmentations": {"rgb": ["", "random_shift+colour_jitter"]}})
    runs = grid.expand()
    assert [(r.obs_space, r.augment) for r in runs] == [
        ("rgb", ""),
        ("rgb", "random_shift+colour_jitter"),
        ("pointcloud", ""),
    ]
    assert {r.run_id for r in plain} == {r.run_id for r in runs if not r.augment}  # finished runs are reused
    augmented = runs[1]
    assert augmented.method == "obs_act/rgb/resnet18/random_shift+colour_jitter"
    assert "augment" not in runs[0].config() and RunSpec.from_config(augmented.config()) == augmented
    command = train_command(augmented, tmp_path / "demos", tmp_path / "run", 10, "cpu", 5)
    assert "--policy.augment=random_shift+colour_jitter" in command


@pytest.mark.parametrize(
    "space, recipes",
    [
        ("rgb", ["random_shift", " random_shift"]),
        ("rgb", ["random_shift+colour_jitter", "colour_jitter + random_shift"]),
        ("rgb", ["", "  "]),
        ("rgb+pointcloud", ["random_shift+point_jitter", "point_jitter+random_shift"]),
    ],
)
def test_one_recipe_written_two_ways_is_refused_like_a_seed_given_twice(space, recipes):
    """`[random_shift, " random_shift"]` used to make two methods that train the same thing."""
    grid = {**BASE, "obs_spaces": [space], "augmentations": {space: recipes}}
    with pytest.raises(GridError, match=rf"augmentations.{re.escape(space)} lists .* more than once"):
        parse_grid(grid)


def test_recipes_are_normalised_before_runs_are_made_keeping_the_order_that_trains():
    written = parse_grid({**BASE, "augmentations": {"rgb": [" colour_jitter + random_shift "]}}).expand()[0]
    canonical = parse_grid({**BASE, "augmentations": {"rgb": ["random_shift+colour_jitter"]}}).expand()[0]
    assert written.augment == "random_shift+colour_jitter" and written.run_id == canonical.run_id
    # within a kind the order is what trains (the transforms compose in it): two recipes, as written
    point_orders = ["point_jitter+point_dropout", "point_dropout+point_jitter"]
    runs = parse_grid({**BASE, "obs_spaces": ["pointcloud"], "augmentations": {"pointcloud": point_orders}}).expand()
    assert [r.augment for r in runs] == point_orders


def _adapter_output(synthetic_module, space: str, recipe: str) -> list:
    import torch

    from lerobot_obsbench.schema import PointCloud
    from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
    from tests.support.helpers import CAM, frame_batch

    config = AdapterConfig(space, [CAM], workspace=(-0.5, 0.5, -0.5, 0.5, 0.005, 0.5), augment=recipe)
    torch.manual_seed(0)
    out = ObservationAdapter(config)(frame_batch(synthetic_module, batch_size=2, size=32))
    parts = out if isinstance(out, tuple) else (out,)
    return [t for p in parts for t in ((p.xyz, p.features, p.mask) if isinstance(p, PointCloud) else (p,))]


@pytest.mark.parametrize(
    "space, recipe, reordered, same",
    [
        ("rgb", "random_shift+colour_jitter", "colour_jitter+random_shift", True),
        ("rgb+pointcloud", "random_shift+point_jitter", "point_jitter+random_shift", True),
        ("pointcloud", "point_translate+point_rotate", "point_rotate+point_translate", False),
        ("rgb", "random_shift+random_crop", "random_crop+random_shift", False),
    ],
)
def test_the_order_of_a_recipes_names_matters_within_a_kind_only(synthetic_module, space, recipe, reordered, same):
    """What the grid's normalisation rests on: the adapter applies each kind at its own point, in name order."""
    import torch

    first, second = (_adapter_output(synthetic_module, space, names) for names in (recipe, reordered))
    assert all(torch.equal(a, b) for a, b in zip(first, second, strict=True)) == same


def test_a_value_the_grid_sets_over_its_preset_is_what_trains_and_appears_once():
    """A grid's own value of a preset field (policy_overrides, its encoder and learning-rate axes) used to follow the
    preset's on lerobot-train's command line: each field twice, the later one winning."""
    for preset, policy, space, encoder in preset_cases():
        fields = preset_overrides(preset, policy, space, encoder)
        overrides = {name: f"user_{name}" for name in fields if name not in AXIS_FIELDS}
        run = RunSpec(
            task="PushCube-v1",
            obs_space=space,
            encoder=encoder,
            policy=policy,
            seed=0,
            lr=0.125,
            demos=1,
            preset=preset,
            batch_size=1,
            budget_unit="steps",
            budget=1,
            image_size=64,
            cameras=("base_camera",),
            control_mode="pd_ee_delta_pose",
            policy_overrides=tuple(sorted(overrides.items())),
        )
        given = policy_fields(run.policy_args())
        assert all(len(values) == 1 for values in given.values()), (preset, policy, space, encoder, given)
        assert {name: given[name][0] for name in overrides} == overrides
        assert given["encoder"] == [encoder] and given["optimizer_lr"] == ["0.125"]
    grid = {**BASE, "obs_spaces": ["pointcloud"], "encoders": ["dp3"], "preset": "real-one-arm"}
    (run,) = parse_grid({**grid, "learning_rates": [1e-3], "policy_overrides": {"workspace_jitter": 0.0}}).expand()
    given = policy_fields(train_command(run, "ds", "out", steps=10, device="cpu", save_every=5))
    assert given["optimizer_lr"] == ["0.001"] and given["workspace_jitter"] == ["0.0"]  # the preset's: 5e-5, 0.01


def test_space_overrides_set_fields_for_one_space_only():
    plain = {r.obs_space: r for r in parse_grid({**BASE, "obs_spaces": ["rgb", "pointcloud"]}).expand()}
    grid = {
        **BASE,
        "obs_spaces": ["rgb", "pointcloud"],
        "encoders": {"rgb": ["spatial_softmax"], "pointcloud": ["dp3"]},
        "space_overrides": {"rgb": {"encoder_norm": "batch"}},
    }
    runs = {r.obs_space: r for r in parse_grid(grid).expand()}
    assert dict(runs["rgb"].policy_overrides) == {"encoder_norm": "batch"}
    assert "encoder_norm" not in dict(runs["pointcloud"].policy_overrides)
    assert "--policy.encoder_norm=batch" in runs["rgb"].policy_args()
    no_override = {**grid, "space_overrides": {}}
    assert {r.obs_space: r.run_id for r in parse_grid(no_override).expand()}["pointcloud"] == runs["pointcloud"].run_id
    assert plain["rgb"].run_id != runs["rgb"].run_id


def test_run_id_is_a_hash_of_the_resolved_config():
    a, b = parse_grid({**BASE, "learning_rates": [1e-4, 1e-3]}).expand()[:2]
    assert a.run_id != b.run_id and a.lr != b.lr
    again = parse_grid({**BASE, "learning_rates": [1e-4, 1e-3]}).expand()[0]
    assert again.run_id == a.run_id
    assert RunSpec.from_config(a.config()) == a


@pytest.mark.parametrize(
    "change, words",
    [
        ({"tasks": ["PickCube-v9"]}, ["PickCube-v9", "PickCube-v1", "StackCube-v1"]),
        ({"obs_spaces": ["rgbdd"]}, ["rgbdd", "pointcloud", "pointmap"]),
        ({"encoders": ["resnet5"]}, ["resnet5", "pointnet", "resnet50"]),
        ({"encoders": {"rgb": ["pointnet"]}}, ["pointnet", "rgb", "resnet18"]),
        ({"encoders": ["resnet18"]}, ["pointcloud", "pointnet"]),
        ({"obs_spaces": ["pointcloud"], "encoders": ["pointnet", "resnet18"]}, ["resnet18", "accepts none"]),
        ({"policies": ["obs_vqbet"]}, ["obs_vqbet", "obs_act", "obs_diffusion"]),
        ({"preset": "huge"}, ["huge", "paper", "cpu", "tiny"]),
        ({"stepz": 3}, ["stepz", "steps", "demo_epochs"]),
        ({"epochs": 3}, ["`epochs` is ambiguous", "demo_epochs", "frame_epochs"]),
        ({"demo_epochs": 3}, ["exactly one", "steps", "samples", "demo_epochs", "one randomly sampled frame"]),
        ({"steps": {"obs_diffusion": 3}}, ["obs_diffusion", "valid choices: obs_act"]),
        ({"batch_size": {"obs_act": 0}}, ["batch_size of obs_act", ">= 1"]),
        ({"perturbations": ["lighting:0.3"]}, ["lighting:0.3", "camera_yaw:DEG", "light:I"]),
        ({"perturbations": ["background:2,0,0"]}, ["background:2,0,0", "[0, 1]"]),
        ({"variants": [{}, {"sampling": "pre"}]}, ["obs_act/rgb/resnet18", "sampling='pre'", "point-cloud design"]),
        ({"policy_overrides": {"chunk_sise": 5}}, ["no fields ['chunk_sise']"]),
        ({"seeds": []}, ["'seeds' is empty"]),
        ({"augmentations": {"rgb": ["point_jitter"]}}, ["augmentations.rgb", "does not apply", "random_shift"]),
        ({"augmentations": {"rgb": ["random_shfit"]}}, ["unknown augmentation 'random_shfit'", "colour_jitter"]),
        ({"augmentations": {"depth": ["random_shift"]}}, ["augmentations names spaces ['depth']"]),
        ({"augmentations": {"rgb": ["", None]}}, ['augmentations.rgb lists "" more than once']),
        # each used to train the same runs twice under one id
        ({"encoders": {"rgb": ["resnet18", "resnet18"]}}, ['encoders.rgb lists "resnet18" more than once']),
        ({"encoders": ["resnet18", "pointnet", "resnet18"]}, ['encoders lists "resnet18" more than once']),
        ({"variants": [{}, {}]}, ["variants lists {} more than once"]),
        ({"augmentations": ["random_shift"]}, ["maps spaces to recipes"]),
        ({"policy_overrides": {"augment": "random_shift"}}, ["sets --policy.augment", "augmentations"]),
        ({"space_overrides": {"depth": {"encoder_norm": "batch"}}}, ["space_overrides names spaces ['depth']"]),
        ({"space_overrides": {"rgb": {"encoder": "resnet50"}}}, ["space_overrides.rgb sets --policy.encoder"]),
        ({"space_overrides": {"rgb": ["batch"]}}, ["space_overrides maps spaces to --policy.* fields"]),
        (
            {"space_overrides": {"rgb": {"encoder_norm": "batch"}}},
            ["encoder_norm='batch' is not an option", "resnet18"],
        ),
    ],
)
def test_bad_grids_fail_with_the_valid_choices(change, words):
    with pytest.raises(GridError) as err:
        parse_grid({**BASE, **change})
    for word in words:
        assert word in str(err.value)


@pytest.mark.parametrize(
    "field, text, message",
    [
        ("steps", "-5", "steps must be a whole number >= 1; got -5"),
        ("steps", ".nan", "steps must be a whole number >= 1; got nan"),
        ("steps", "'x'", "steps must be a whole number >= 1; got 'x'"),
        ("image_size", "16", "image_size must be a whole number >= 32; got 16"),
        ("image_size", "'64'", "image_size must be a whole number >= 32; got '64'"),
        ("seeds", "a", "seeds must be a whole number >= 0; got 'a'"),
        ("seeds", "[1000, 1.5]", "seeds[1] must be a whole number >= 0; got 1.5"),
        ("demos", "[0]", "demos[0] must be a whole number >= 1; got 0"),
        ("learning_rates", "[.inf]", "learning_rates[0] must be a finite number > 0; got inf"),
        ("eval_episodes", "1.5", "eval_episodes must be a whole number >= 1; got 1.5"),
        ("episode_length", "0", "episode_length must be a whole number >= 1; got 0"),
        ("validation_episodes", "-1", "validation_episodes must be a whole number >= 0; got -1"),
        ("batch_size", "true", "batch_size must be a whole number >= 1; got True"),
        ("eval_batch_size", "0", "eval_batch_size must be a whole number >= 1; got 0"),
        ("cameras", "base_camera", "cameras is a list of names"),
        ("cameras", "null", "cameras is a list of names, e.g. [base_camera]; got None"),
        ("policy_overrides", "null", "policy_overrides maps --policy.* fields to values"),
        ("batch_size", "null", "batch_size must be a whole number >= 1; got None"),
    ],
)
def test_bad_grid_values_are_refused_by_the_dry_run(tmp_path, capsys, field, text, message):
    """Each value is refused before anything runs: no demos, no output directory."""
    lines = {"tasks": "[PushCube-v1]", "obs_spaces": "[rgb]", "steps": "5", field: text}
    grid = tmp_path / "bad.yaml"
    grid.write_text("".join(f"{key}: {value}\n" for key, value in lines.items()))
    assert main(["run", str(grid), "--out", str(tmp_path / "out"), "--dry-run"]) == 2
    assert f"obsbench run: error: bad: {message}" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_grid_numbers_are_refused_by_the_projects_one_rule_in_its_words():
    """Every grid number goes through lerobot_obsbench.numeric: what check_number refuses, the grid refuses with
    its words (NaN, infinities, out of range, a bool, text)."""
    numeric = [spec for spec in GRID_FIELDS if spec.metadata["number"] is not None]
    assert {"seeds", "steps", "task_budgets", "eval_checkpoints", "image_size"} <= {spec.name for spec in numeric}
    for spec in numeric:
        bounds, shape = spec.metadata["number"], spec.metadata["shape"]
        label = f"{spec.name} of PushCube-v1" if shape == "per_task" else spec.name
        for value in (float("nan"), float("inf"), -1, 0, 0.5, True, "3"):
            try:
                check_number(label, value, **bounds)
            except ValueError as refusal:
                written = {"per_task": {"PushCube-v1": value}, "axis": [value], "list": [value]}.get(shape, value)
                with pytest.raises(GridError) as err:
                    parse_grid({**BASE, spec.name: written})
                assert str(err.value).replace("[0]", "") == f"grid: {refusal}"


def test_a_whole_number_written_with_a_decimal_point_is_that_number():
    """`seeds: [1000.0]` used to be refused as not whole while numeric.check_number, the one rule, takes it; and
    1000 and 1000.0 are one seed listed twice, not two runs of the same training."""
    written = parse_grid({**BASE, "seeds": [1000.0], "demos": [50.0], "batch_size": 8.0}).expand()
    plain = parse_grid({**BASE, "seeds": [1000], "demos": [50], "batch_size": 8}).expand()
    assert [r.run_id for r in written] == [r.run_id for r in plain]
    with pytest.raises(GridError, match="seeds lists 1000 more than once"):
        parse_grid({**BASE, "seeds": [1000, 1000.0]})


def test_bad_grid_fails_before_anything_runs(tmp_path, capsys):
    grid = tmp_path / "bad.yaml"
    grid.write_text("tasks: [PushCube-v1]\nobs_spaces: [rgb]\nencoders: {rgb: [pointnet]}\nsteps: 5\n")
    assert main(["run", str(grid), "--out", str(tmp_path / "out")]) == 2
    assert "does not accept obs_space='rgb'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_dry_run_prints_the_plan_and_skips_finished_runs(tmp_path, capsys):
    grid = tmp_path / "g.yaml"
    grid.write_text(
        "tasks: [PushCube-v1]\nobs_spaces: [rgb, pointcloud]\nseeds: [1, 2]\nsteps: 5\npreset: tiny\neval_episodes: 3\n"
    )
    assert main(["run", str(grid), "--out", str(tmp_path), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "4 runs, 0 already trained, 4 to train; 0 of 4 test evaluations done" in text
    assert "one training seed" not in text
    runs = load_grid(grid).expand()
    train = {
        "kind": "train",
        "run_id": runs[0].run_id,
        "config": runs[0].config(),
        "method": runs[0].method,
        "task": runs[0].task,
        "checkpoint": "ckpt",
        "checkpoints": {"5": "ckpt"},
        "train_steps": 5,
    }
    append_result(tmp_path / "results.jsonl", train)
    (tmp_path / "ckpt").mkdir()
    (tmp_path / "ckpt" / "model.safetensors").write_bytes(b"")
    train["checkpoints"] = {"5": str(tmp_path / "ckpt")}
    (tmp_path / "results.jsonl").unlink()
    append_result(tmp_path / "results.jsonl", train)
    assert main(["run", str(grid), "--out", str(tmp_path), "--dry-run"]) == 0
    assert "4 runs, 1 already trained, 3 to train; 0 of 4 test evaluations done" in capsys.readouterr().out
    assert not (tmp_path / "demos").exists()
    # its checkpoint gone (a results file copied without the runs' folders): trained again, as its run id
    (tmp_path / "ckpt" / "model.safetensors").unlink()
    assert main(["run", str(grid), "--out", str(tmp_path), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "4 runs, 0 already trained, 4 to train" in text
    assert f"run {runs[0].run_id} has evaluations to do and its checkpoint {tmp_path / 'ckpt'} is gone" in text


def test_a_grid_runs_in_pieces_with_the_whole_grids_run_ids(tmp_path, capsys):
    whole = load_grid("cpu-ranking")
    piece = whole.piece(["LiftPegUpright-v1", "PickCube-v1"], ["rgb"])
    assert piece.tasks == ["PickCube-v1", "LiftPegUpright-v1"] and piece.obs_spaces == ["rgb"]
    expected = [run for run in whole.expand() if run.task in piece.tasks and run.obs_space == "rgb"]
    assert [run.run_id for run in piece.expand()] == [run.run_id for run in expected] and len(expected) == 6
    assert whole.piece(None, None).expand() == whole.expand()
    args = ["run", "cpu-ranking", "--out", str(tmp_path), "--dry-run", "--tasks", "PickCube-v1"]
    assert main([*args, "--obs-spaces", "rgb", "none"]) == 0
    text = capsys.readouterr().out
    assert "6 runs, 0 already trained, 6 to train" in text and "LiftPegUpright" not in text
    assert main([*args, "--obs-spaces", "rgbd"]) == 2
    err = capsys.readouterr().err
    assert "--obs-spaces rgbd: not in grid cpu-ranking's obs_spaces (none, state, rgb, pointcloud)" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "results.jsonl").exists()


def test_dry_run_counts_steps_and_samples_in_the_papers_units(capsys):
    """paper-main: one sampled frame per demonstration per epoch -> ACT 500 x 1000 / 16, DP 1800 x 1000 / 64."""
    assert main(["run", "paper-main", "--dry-run", "--out", "/nonexistent/out"]) == 0
    text = capsys.readouterr().out
    assert "batch 16  500 demo_epochs = 31250 steps, 500000 samples" in text
    assert "batch 64  1800 demo_epochs = 28125 steps, 1800000 samples" in text
    assert "total to do: 7481250 optimizer steps" in text
    assert "demo_epochs = the paper's epochs: one randomly sampled frame per demonstration per epoch" in text
    assert "h on a 2-core CPU" in text and "h on one H200 GPU" in text
    assert "one training seed" not in text  # paper-main trains two seeds per learning rate


def test_dry_run_warns_that_one_training_seed_cannot_show_training_variance(tmp_path, capsys):
    (tmp_path / "one_seed.yaml").write_text(yaml.safe_dump({**BASE, "seeds": [1000]}))
    assert main(["run", str(tmp_path / "one_seed.yaml"), "--dry-run", "--out", str(tmp_path / "out")]) == 0
    assert "note: one training seed (1000)" in capsys.readouterr().out
    assert main(["run", "quick", "--dry-run", "--out", "/nonexistent/out"]) == 0  # the main job trains three
    assert "note: one training seed" not in capsys.readouterr().out


def test_training_identity_leaves_out_evaluation_and_checkpointing():
    base = parse_grid(BASE)
    more = parse_grid(
        {
            **BASE,
            "eval_episodes": 99,
            "perturbations": ["light:0.03"],
            "episode_length": 20,
            "checkpoints": 7,
            "validation_episodes": 5,
        }
    )
    assert [r.run_id for r in base.expand()] == [r.run_id for r in more.expand()]
    run = base.expand()[0]
    assert [s.perturbation for s in more.evaluations(run)] == ["none", "light:0.03"] * 2
    assert {s.checkpoint for s in more.evaluations(run)} == {"last", "best"}
    assert {s.eval_id for s in base.evaluations(run)} < {s.eval_id for s in more.evaluations(run)} or all(
        s.episodes == 99 for s in more.evaluations(run)
    )
    assert EvalSpec(**base.evaluations(run)[0].config()).eval_id == base.evaluations(run)[0].eval_id
    assert base.evaluations(run)[0].max_steps == 50 and more.evaluations(run)[0].max_steps == 20


def test_train_command_is_stock_lerobot_train_with_the_run_fields(tmp_path):
    run = parse_grid(
        {**BASE, "encoders": {"rgb": ["resnet18"]}, "demos": [7], "seeds": [5], "policy_overrides": {"chunk_size": 3}}
    ).expand()[0]
    cmd = train_command(run, tmp_path / "ds", tmp_path / "out", steps=10, device="cpu", save_every=5)
    assert cmd[0].endswith("lerobot-train")
    for arg in (
        "--policy.type=obs_act",
        "--policy.obs_space=rgb",
        "--policy.encoder=resnet18",
        "--seed=5",
        "--steps=10",
        "--save_freq=5",
        "--dataset.episodes=[0,1,2,3,4,5,6]",
        "--policy.chunk_size=3",
        "--wandb.enable=false",
    ):
        assert arg in cmd
    assert [a for a in cmd if a.startswith("--policy.encoder=")] == ["--policy.encoder=resnet18"]


def test_orbit_keeps_distance_and_target():
    eye, target = np.array([0.3, 0.0, 0.6]), np.array([-0.1, 0.0, 0.1])
    yawed = orbit_eye(eye, target, yaw_deg=10)
    raised = orbit_eye(eye, target, pitch_deg=10)
    for moved in (yawed, raised):
        assert np.linalg.norm(moved - target) == pytest.approx(np.linalg.norm(eye - target))
    a, b = eye - target, yawed - target
    assert np.degrees(np.arccos(a[:2] @ b[:2] / np.linalg.norm(a[:2]) / np.linalg.norm(b[:2]))) == pytest.approx(10)
    assert yawed[2] == pytest.approx(eye[2])
    a, b = eye - target, raised - target
    assert np.degrees(np.arccos(a @ b / np.linalg.norm(a) / np.linalg.norm(b))) == pytest.approx(10)
    assert raised[2] > eye[2]


def test_perturbation_names_round_trip():
    for text in ("camera_yaw:5", "light:0.03", "background:1,0.2,0.2", "noise:16"):
        assert parse_perturbation(text).name == text
    assert parse_perturbation("none") is None


def test_training_progress_reads_the_total_loss_of_lerobot_061_logs(tmp_path):
    """LeRobot 0.6.1 logs the loss terms after the total (`loss:0.130 ... l1_loss:0.130 kld_loss:0.000`): the
    progress line shows the total."""
    from lerobot_obsbench.bench.units import training_progress

    run = tmp_path / "runs" / "r1"
    run.mkdir(parents=True)
    (run / "progress.json").write_text(json.dumps({"resumed_from": 0, "steps": 2000, "started": 0.0}))
    (run / "train.log").write_text(
        "Training:  96%|#########6| 1920/2000 [03:21<00:10,  7.60step/s]INFO ot_train.py:641 step:2K smpl:31K "
        "loss:0.130 grdn:0.511 lr:8.4e-06 l1_loss:0.129 kld_loss:0.000\n"
    )
    assert training_progress(tmp_path, "r1") == {"step": 1920, "steps": 2000, "loss": 0.13, "started": 0.0}


def test_loss_curve_numbers_lerobots_rounded_steps_from_the_log_frequency():
    """From 1,000 on lerobot-train prints steps rounded to thousands ("step:1K" for 1020 and 1080 alike): each
    such line is the next multiple of the log frequency, counted from where the run (re)started."""
    from lerobot_obsbench.bench.diagnostics import loss_curve

    def line(step: str, loss: float) -> str:
        return f"Training:  5%|5| 1/9 [00:01<00:08]INFO ot_train.py:641 step:{step} smpl:9K loss:{loss} l1_loss:0.1\r"

    log = "\n=== 2026-11-25T00:00:00+00:00 starting ===\n" + "".join(
        line(step, loss) for step, loss in (("960", 0.5), ("1K", 0.4), ("1K", 0.35), ("1K", 0.3))
    )
    log += "\n=== 2026-11-25T00:10:00+00:00 resuming at step 1500 ===\n" + line("2K", 0.2) + line("2K", 0.1)
    assert loss_curve(log, 60) == [[960, 0.5], [1020, 0.4], [1080, 0.35], [1140, 0.3], [1560, 0.2], [1620, 0.1]]


# ---- RLBench tasks ----------------------------------------------------------------------------------------------

RLBENCH = {"tasks": ["rlbench/open_drawer"], "obs_spaces": ["rgb", "pointcloud"], "steps": 10, "preset": "tiny"}


def test_an_rlbench_grid_trains_on_the_front_camera_and_evaluates_by_rlbenchs_protocol():
    grid = parse_grid({**RLBENCH, "rlbench_data": "data/rlbench", "clip_weights": "clip.pt"})
    runs = grid.expand()
    assert {r.cameras for r in runs} == {("front",)} and {r.image_size for r in runs} == {128}
    assert {r.control_mode for r in runs} == {"ee_pose_planning"} and {r.language_goal for r in runs} == {
        "clip_vit_b16"
    }
    assert {grid.max_steps(r) for r in runs} == {200}  # the paper's episode budget
    workspaces = {r.obs_space: dict(r.policy_overrides).get("workspace") for r in runs}
    assert workspaces == {"rgb": None, "pointcloud": [-0.3, 0.7, -0.5, 0.5, 0.76, 1.6]}
    assert "/" not in runs[0].demo_key and runs[0].demo_key.endswith("-clip_vit_b16")
    assert RunSpec.from_config(runs[0].config()) == runs[0]
    # without the language goal: another dataset and other runs
    plain = parse_grid({**RLBENCH, "rlbench_data": "data/rlbench"}).expand()
    assert plain[0].run_id != runs[0].run_id and plain[0].demo_key != runs[0].demo_key
    assert "language_goal" not in plain[0].config()  # left out at its default: ManiSkill runs keep their ids
    assert "language_goal" not in parse_grid(BASE).expand()[0].config()


@pytest.mark.parametrize(
    "change, words",
    [
        ({}, ["rlbench_data: DIR", "DIR/train/<task>"]),
        ({"tasks": ["rlbench/open_drawer", "PushCube-v1"]}, ["RLBench and ManiSkill tasks in one grid"]),
        ({"tasks": ["rlbench/stack_blockz"]}, ["unknown RLBench task 'stack_blockz'", "open_drawer"]),
        ({"cameras": ["base_camera"]}, ["cameras ['base_camera'] are not RLBench's", "front, left_shoulder"]),
        ({"image_size": 64}, ["image_size 64", "128 x 128"]),
        ({"control_mode": "pd_joint_pos"}, ["control_mode does not apply to RLBench tasks"]),
        ({"held_out_demos": 5}, ["held_out_demos does not apply to RLBench tasks"]),
        ({"eval_batch_size": 4}, ["eval_batch_size does not apply to RLBench tasks", "one episode at a time"]),
        ({"perturbations": ["light:0.3"]}, ["'light:0.3' has no RLBench counterpart", "camera_pitch:5"]),
    ],
)
def test_bad_rlbench_grids_are_refused(change, words):
    data = {} if change == {} else {"rlbench_data": "data/rlbench"}
    with pytest.raises(GridError) as err:
        parse_grid({**RLBENCH, **data, **change})
    for word in words:
        assert word in str(err.value)
    with pytest.raises(GridError, match="only apply to RLBench tasks"):
        parse_grid({**BASE, "rlbench_data": "data/rlbench"})


def test_rlbench_presets_are_the_papers_nine_tasks_and_plan_without_the_simulator(tmp_path, capsys):
    from lerobot_obsbench.rlbench.paper_tasks import PAPER_TASKS

    table2 = load_grid("paper-rlbench")
    assert [t.removeprefix("rlbench/") for t in table2.tasks] == list(PAPER_TASKS)
    runs = table2.expand()
    assert len(runs) == 9 * 7 * 2 * 3 * 2  # Table 2's (space, encoder) pairs x policies x lrs x seeds
    assert {s.episodes for r in runs for s in table2.evaluations(r)} == {25}
    efficiency = load_grid("paper-sample-efficiency-rlbench")
    assert {r.demos for r in efficiency.expand()} == {10, 25, 100}
    code = main(["run", "paper-rlbench", "--out", str(tmp_path / "out"), "--dry-run", "--rlbench-data", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 0 and "756 runs" in out and "rlbench/open_drawer" in out
    # what is missing here is said before the plan, not refused: a plan needs no simulator
    assert out.startswith("note: this machine cannot run paper-rlbench as it is: rlbench_data lacks 27 task folder")
    assert "COPPELIASIM_ROOT" in out and not (tmp_path / "out").exists()
    code = main(["run", "paper-rlbench", "--out", str(tmp_path / "out"), "--rlbench-data", str(tmp_path)])
    assert code == 2 and "rlbench_data lacks 27 task folder" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_an_rlbench_grid_asking_for_more_episodes_than_the_data_holds_stops_before_anything_runs(
    tmp_path, capsys, synthetic_module
):
    from tests.support import rlbench_fixtures

    for split in ("train", "test"):
        rlbench_fixtures.write_task(tmp_path / "data" / split / "open_drawer", synthetic_module, "variations", 2, 2)
    (tmp_path / "g.yaml").write_text(
        "tasks: [rlbench/open_drawer]\nobs_spaces: [rgb]\nsteps: 5\npreset: tiny\ndemos: [5]\neval_episodes: 3\n"
        f"rlbench_data: {tmp_path / 'data'}\n"
    )
    assert main(["run", str(tmp_path / "g.yaml"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "test/open_drawer holds 2 episodes; the grid's eval_episodes needs 3" in err
    assert "train/open_drawer holds 2 episodes; the grid's demos needs 5" in err
    assert "COPPELIASIM_ROOT" in err and not (tmp_path / "out").exists()


def test_evaluations_run_in_lockstep_up_to_the_cores_a_unit_gets():
    """The grid's eval_batch_size wins; else the device's measured default, on CPU no more envs than the cores the
    local engine gives each unit (make main: two units on two cores, one env each)."""
    from lerobot_obsbench.bench.runner import eval_batch_size
    from lerobot_obsbench.envs.vector import DEFAULT_BATCH_SIZE

    grid = parse_grid(BASE)
    assert eval_batch_size(grid, "cpu") == DEFAULT_BATCH_SIZE["cpu"]
    assert eval_batch_size(grid, "cpu", cores=1) == 1
    assert eval_batch_size(grid, "cuda:0", cores=1) == DEFAULT_BATCH_SIZE["cuda"]
    assert eval_batch_size(parse_grid({**BASE, "eval_batch_size": 4}), "cpu", cores=1) == 4
    run = grid.expand()[0]
    assert run.config() == parse_grid({**BASE, "eval_batch_size": 4}).expand()[0].config()  # not in the identity


def test_the_cost_models_measured_rates_are_the_benchmarks_results():
    """Every measured rate in the package's rates file is what the benchmarks' results under benchmarks/results give
    (benchmarks/refresh_rates.py derives them): a benchmark rerun with other numbers fails here until
    `python -m benchmarks.refresh_rates` writes them. The default lockstep batch sizes are the fastest measured."""
    from benchmarks.refresh_rates import cpu_eval_totals, cuda_evaluations, measured_rates, merged
    from lerobot_obsbench.bench.cost import RATES
    from lerobot_obsbench.envs.vector import DEFAULT_BATCH_SIZE

    assert merged(RATES, measured_rates()) == RATES
    totals = cpu_eval_totals()
    assert DEFAULT_BATCH_SIZE["cpu"] == min(totals, key=lambda n: totals[n][1])
    fastest = min(cuda_evaluations(), key=lambda r: r["wall_s"] / r["episodes"])
    assert DEFAULT_BATCH_SIZE["cuda"] == fastest["batch_size"]


def test_refreshing_the_rates_follows_a_new_measurement_and_refuses_a_result_it_cannot_use(tmp_path):
    """A benchmark result that changed moves its rate (named by `differences`) and no other; an evaluation whose
    batch sizes disagreed on the episodes' outcomes gives no rate."""
    from benchmarks.refresh_rates import RatesError, differences, measured_rates, merged
    from lerobot_obsbench.bench.cost import RATES

    results = tmp_path / "results"
    shutil.copytree(REPO_ROOT / "benchmarks" / "results", results)
    measured = json.loads((results / "eval_cpu.json").read_text())
    for rows in measured["with_policy"].values():
        for row in rows:
            row["seconds"] *= 2 if row["batch_size"] == 1 else 1
    (results / "eval_cpu.json").write_text(json.dumps(measured))
    refreshed = merged(RATES, measured_rates(results))
    changed = [line for line in differences(RATES, refreshed) if not line.startswith("sources.")]
    before = RATES["eval_steps_per_second"]["cpu"]["1"]
    assert len(changed) == 1 and changed[0].startswith(f"eval_steps_per_second.cpu.1: {before} -> ")
    assert float(changed[0].split("-> ")[1]) == pytest.approx(round(before / 2, 1), abs=0.1)
    source = refreshed["sources"]["eval_cpu.json"]  # the new content is named, on the machine it names
    assert source["sha256"] != RATES["sources"]["eval_cpu.json"]["sha256"] and source["machine"] == "2-core CPU"
    next(iter(measured["with_policy"].values()))[0]["same_results_as_first"] = False
    (results / "eval_cpu.json").write_text(json.dumps(measured))
    with pytest.raises(RatesError, match="changed the episodes' outcomes"):
        measured_rates(results)


def test_per_task_evaluation_factors_price_a_tasks_evaluations_on_the_cpu_only():
    from lerobot_obsbench.bench.cost import EVAL_TASK_FACTOR, episode_seconds

    for task, factor in EVAL_TASK_FACTOR["cpu"].items():
        plain = episode_seconds(25, 100, "cpu", image_size=64) - 10  # the fixed start-up is not scaled
        assert episode_seconds(25, 100, "cpu", image_size=64, task=task) - 10 == pytest.approx(factor * plain)
        assert episode_seconds(25, 100, "cuda", task=task) == episode_seconds(25, 100, "cuda")
    assert episode_seconds(25, 100, "cpu", task="PushCube-v1") == episode_seconds(25, 100, "cpu")  # not measured


def _hours(pattern: str, text: str) -> float:
    """The hours a dry run's cost line gives: `pattern` with `HOURS` where the number stands."""
    return float(re.search(re.escape(pattern).replace("HOURS", r"([0-9.]+)"), text).group(1))


def test_a_task_added_to_a_suite_in_its_grid_file_alone_follows_the_suites_rules(tmp_path, capsys):
    """docs/architecture.md's extension row "a task in a suite": a registered task written into cpu-ranking's
    `tasks` and nothing else leaves the other runs' ids as they were, gets every space with both controls and its
    own crop box, and is priced, the dry run naming the rates it lacks."""
    from lerobot_obsbench.bench.package_data import GRIDS, path_or_shipped

    fields = yaml.safe_load(path_or_shipped("cpu-ranking", GRIDS, ".yaml").read_text())
    path = tmp_path / "more.yaml"
    path.write_text(yaml.safe_dump({**fields, "tasks": [*fields["tasks"], "PushCube-v1"]}))
    runs = load_grid(path).expand()
    added = [r for r in runs if r.task == "PushCube-v1"]
    assert {r.run_id for r in runs} - {r.run_id for r in added} == {r.run_id for r in load_grid("cpu-ranking").expand()}
    assert sorted((r.obs_space, r.seed) for r in added) == sorted(
        (s, seed) for s in ("none", "state", "rgb", "pointcloud") for seed in fields["seeds"]
    )
    clouds = [r for r in added if r.obs_space == "pointcloud"]
    assert clouds and all(dict(r.policy_overrides).get("workspace") == _own_box("PushCube-v1") for r in clouds)
    assert main(["run", str(path), "--dry-run", "--out", str(tmp_path / "out"), "--workers", "2"]) == 0
    text = capsys.readouterr().out
    assert "PushCube-v1 (evaluation factor, expert's episode length)" in text
    assert _hours("with 2 local workers: ~HOURS h of wall time", text) > 0


PUBLISHED = sorted(p.parent.name for p in (REPO_ROOT / "docs" / "results").glob("*/results.jsonl"))


@pytest.mark.parametrize("suite", [name for name in PUBLISHED if name in preset_grids()])
def test_a_published_suites_grid_still_names_the_runs_it_published(suite):
    """A change that moved a run id would orphan a published suite's results and retrain what its page describes:
    each published grid expands to exactly the runs its results.jsonl holds (cpu-suite's include the main job's, the
    quick grid's, which the test below pins to them)."""
    path = REPO_ROOT / "docs" / "results" / suite / "results.jsonl"
    trained = {json.loads(line)["run_id"] for line in path.read_text().splitlines() if '"kind": "train"' in line}
    assert {r.run_id for r in load_grid(suite).expand()} == trained


def test_cpu_suite_reuses_the_quick_grids_runs_and_fits_three_hours(capsys):
    """cpu-suite's PushCubeWide-v1 is the quick grid's setting, run for run (a copy of its outputs is reused), and
    the suite fits the three hours its page promises (the CPU suites' other rules: the test above)."""
    grid = load_grid("cpu-suite")
    pushes = {r.run_id for r in grid.expand() if r.task == "PushCubeWide-v1"}
    assert pushes == {r.run_id for r in load_grid("quick").expand()}
    assert main(["run", "cpu-suite", "--dry-run", "--out", "/nonexistent/out", "--workers", "2"]) == 0
    assert _hours("with 2 local workers: ~HOURS h of wall time", capsys.readouterr().out) <= 3.0


def test_cpu_ranking_draws_every_runs_learning_curve_to_its_budget():
    """Every cpu-ranking run is evaluated at 1,000 and 3,000 steps, and a task given a longer budget (its oracle
    needs more steps) also at 10,000, before its last checkpoint."""
    grid = load_grid("cpu-ranking")
    for run in grid.expand():
        assert run.budget_unit == "steps"
        expected = (1000, 3000, 10000) if run.budget > 10000 else (1000, 3000)
        assert grid.curve(run) == expected and max(expected) < run.budget, (run.task, run.budget)


def test_gpu_day_fits_one_gpu_day_with_the_papers_encoders(capsys):
    runs = load_grid("gpu-day").expand()
    assert {r.preset for r in runs} == {"paper"}
    assert {(r.obs_space, r.encoder) for r in runs} == {
        ("none", "blind"),
        ("state", "oracle"),
        ("rgb", "resnet50"),
        ("rgbd", "resnet50"),
        ("pointcloud", "pointnet"),
    }
    assert {r.task for r in runs} == {"StackCube-v1", "PegInsertionSide-v1"}  # what the CPU's budget cannot learn
    assert main(["run", "gpu-day", "--dry-run", "--out", "/nonexistent/out", "--device", "cuda"]) == 0
    text = capsys.readouterr().out
    assert 0 < _hours("HOURS h on one H200 GPU", text) <= 24.0


def test_dry_run_prices_only_the_demonstrations_still_to_record(tmp_path, capsys):
    grid = tmp_path / "g.yaml"
    grid.write_text("tasks: [PushCube-v1, PickCube-v1]\nobs_spaces: [none]\nsteps: 5\npreset: tiny\ndemos: 2000\n")
    assert main(["run", str(grid), "--out", str(tmp_path), "--dry-run"]) == 0
    first = capsys.readouterr().out
    assert "demonstrations to record: 4000 episodes of PushCube-v1 (2000), PickCube-v1 (2000)" in first
    run = next(r for r in load_grid(grid).expand() if r.task == "PushCube-v1")
    recorded = demo_dir(tmp_path, run, 2000) / "meta"
    recorded.mkdir(parents=True)
    (recorded / "info.json").write_text("{}")
    assert main(["run", str(grid), "--out", str(tmp_path), "--dry-run"]) == 0
    second = capsys.readouterr().out
    assert "demonstrations to record: 2000 episodes of PickCube-v1 (2000)" in second
    assert _hours("HOURS h on a 2-core CPU", second) < _hours("HOURS h on a 2-core CPU", first)


def test_a_learning_curve_evaluates_the_listed_checkpoints_on_the_test_seeds_and_keeps_the_run_ids():
    """`eval_checkpoints` adds nominal test evaluations of those steps' checkpoints; what a run trains, and so its
    id, does not change (how often it saves is not part of it)."""
    plain = parse_grid({**BASE, "steps": 3000, "perturbations": ["light:0.05"]})
    curve = parse_grid({**BASE, "steps": 3000, "perturbations": ["light:0.05"], "eval_checkpoints": [2000, 1000]})
    assert [r.run_id for r in curve.expand()] == [r.run_id for r in plain.expand()]
    run = curve.expand()[0]
    added = [s for s in curve.evaluations(run) if s not in plain.evaluations(run)]
    assert [(s.checkpoint, s.split, s.perturbation) for s in added] == [
        ("step:1000", "test", "none"),
        ("step:2000", "test", "none"),
    ]
    assert all(s.episodes == curve.eval_episodes for s in added)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"eval_checkpoints": [10]}, r"eval_checkpoints \[10\] are not below the 10 steps of the grid's longest run"),
        ({"eval_checkpoints": [5, 5]}, "eval_checkpoints lists 5 more than once"),
        ({"eval_checkpoints": [0]}, r"eval_checkpoints\[0\] must be a whole number >= 1; got 0"),
        ({"eval_checkpoints": [2.5]}, r"eval_checkpoints\[0\] must be a whole number >= 1; got 2.5"),
        ({"steps": None, "frame_epochs": 2, "eval_checkpoints": [5]}, "a frame_epochs budget's steps are known only"),
    ],
)
def test_a_learning_curve_it_cannot_give_is_refused_when_the_grid_loads(changes, message):
    with pytest.raises(GridError, match=message):
        parse_grid({k: v for k, v in {**BASE, **changes}.items() if v is not None})


def test_a_task_budget_changes_that_tasks_runs_alone_and_their_curve_goes_further():
    """`task_budgets` gives a task its own budget for every space; the other tasks' runs keep their ids, and each
    run's curve has the eval_checkpoints below its own budget."""
    two_tasks = {**BASE, "tasks": ["PushCube-v1", "PickCube-v1"], "steps": 3000}
    plain = parse_grid(two_tasks)
    longer = parse_grid({**two_tasks, "task_budgets": {"PickCube-v1": 9000}, "eval_checkpoints": [1000, 5000]})
    before = {r.run_id: r for r in plain.expand()}
    after = longer.expand()
    assert [r.run_id in before for r in after] == [r.task == "PushCube-v1" for r in after]
    assert {r.task: (r.steps(), longer.curve(r)) for r in after} == {
        "PushCube-v1": (3000, (1000,)),
        "PickCube-v1": (9000, (1000, 5000)),
    }
    push = next(r for r in after if r.task == "PushCube-v1")
    assert [s.checkpoint for s in longer.evaluations(push)] == ["last", "step:1000"]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"task_budgets": {"StackCube-v1": 9000}}, r"unknown tasks in task_budgets \['StackCube-v1'\]"),
        ({"task_budgets": {"PushCube-v1": 0}}, "task_budgets of PushCube-v1 must be a finite number > 0; got 0"),
        ({"task_budgets": [9000]}, r"task_budgets maps tasks to budgets, e.g. \{PickCube-v1: 30000\}"),
    ],
)
def test_a_task_budget_for_no_task_of_the_grid_or_not_a_budget_is_refused(changes, message):
    with pytest.raises(GridError, match=message):
        parse_grid({**BASE, **changes})


@pytest.mark.parametrize(
    ("steps", "checkpoints", "curve", "kept", "freq"),
    [
        (3000, 4, (), [750, 1500, 2250, 3000], 750),  # as before learning curves: one spacing
        (3000, 1, (1000, 2000), [1000, 2000, 3000], 1000),
        (3000, 4, (1000,), [750, 1000, 1500, 2250, 3000], 250),
        (100, 3, (), [34, 68, 100], 34),  # lerobot-train saves the last step whatever the spacing
        (10, 1, (), [10], 10),
    ],
)
def test_checkpoints_kept_and_the_spacing_that_saves_them(steps, checkpoints, curve, kept, freq):
    assert kept_checkpoints(steps, checkpoints, curve) == kept
    assert save_freq(kept) == freq
    assert all(s % freq == 0 for s in kept[:-1])


def test_a_metaworld_grid_records_with_corner2_acts_by_mocap_and_crops_the_tasks_box():
    """A grid of Meta-World tasks: LeRobot's camera unless named, its own control mode in the runs (so their demos
    are never a ManiSkill task's), the task's measured crop box (inside the table's) for point clouds, Meta-World's
    budget; other simulators' tasks and unknown names refused."""
    from lerobot_obsbench.envs.metaworld.tasks import MAX_STEPS, TABLE_WORKSPACE, metaworld_task

    grid = parse_grid({"tasks": ["drawer-open-v3"], "obs_spaces": ["state", "pointcloud"], "steps": 10})
    runs = {run.obs_space: run for run in grid.expand()}
    assert grid.cameras == ["corner2"]
    assert {run.control_mode for run in runs.values()} == {"mocap_delta_pos"}  # its task record's
    box = dict(runs["pointcloud"].policy_overrides)["workspace"]
    assert box == list(metaworld_task("drawer-open-v3").workspace) != list(TABLE_WORKSPACE)
    assert "workspace" not in dict(runs["state"].policy_overrides)
    assert grid.max_steps(runs["state"]) == MAX_STEPS
    with pytest.raises(GridError, match="Meta-World and ManiSkill tasks in one grid"):
        parse_grid({**BASE, "tasks": ["drawer-open-v3", "PushCube-v1"]})
    with pytest.raises(GridError, match="did you mean drawer-open-v3"):
        parse_grid({**BASE, "tasks": ["drawer-opn-v3"]})
    with pytest.raises(GridError, match=r"cameras \['base_camera'\]: drawer-open-v3 has no such camera"):
        parse_grid({**BASE, "tasks": ["drawer-open-v3"], "cameras": ["base_camera"]})


def test_metaworld_evaluations_and_recordings_are_priced_by_what_mujoco_renders(tmp_path):
    """A Meta-World evaluation is priced at the measured rate of what its env renders for the policy (nothing for the
    controls, depth, colour, or both), a recording at colour and depth over its expert's measured episode length,
    which also estimates a frame_epochs budget's frames; a ManiSkill run's price is unchanged."""
    from lerobot_obsbench.bench.cost import (
        EXPERT_MEAN_STEPS,
        METAWORLD_EVAL_STEPS_PER_SECOND,
        demo_seconds,
        episode_seconds,
        eval_seconds,
        planned_steps,
        rendered_for,
    )

    assert {space: rendered_for(space) for space in ("none", "state", "depth", "rgb", "rgbd", "pointcloud")} == {
        "none": "none",
        "state": "none",
        "depth": "depth",
        "rgb": "colour",
        "rgbd": "colour+depth",
        "pointcloud": "colour+depth",
    }
    assert rendered_for("pointcloud", "xyz") == "depth"  # points without colour: no colour frame
    assert set(METAWORLD_EVAL_STEPS_PER_SECOND) == {"none", "depth", "colour", "colour+depth"}
    grid = parse_grid({"tasks": ["drawer-open-v3"], "obs_spaces": ["none", "depth", "rgb", "pointcloud"], "steps": 10})
    for run in grid.expand():
        spec = grid.evaluations(run)[0]
        rate = METAWORLD_EVAL_STEPS_PER_SECOND[rendered_for(run.obs_space, run.point_features)]
        expected = spec.episodes * spec.max_steps * 0.6 / rate + 10
        assert eval_seconds(spec, run, "cpu") == pytest.approx(expected), run.obs_space
        assert eval_seconds(spec, run, "cuda") == pytest.approx(expected)  # not measured on a GPU: the cpu rate
    # a run's point features are its override's, else its preset's (the cpu preset's DP3: xyz), else the default
    clouds = {"tasks": ["drawer-open-v3"], "obs_spaces": ["pointcloud"], "steps": 10, "preset": "cpu"}
    for encoder, overrides, features in (("dp3", {}, "xyz"), ("dp3", {"point_features": "rgb+xyz"}, "rgb+xyz")):
        run = parse_grid({**clouds, "encoders": {"pointcloud": [encoder]}, "policy_overrides": overrides}).expand()[0]
        assert run.point_features == features
        rate = METAWORLD_EVAL_STEPS_PER_SECOND["depth" if features == "xyz" else "colour+depth"]
        spec = EvalSpec(run.run_id, "last", "test", 4, "none", 100)
        assert eval_seconds(spec, run, "cpu") == pytest.approx(4 * 100 * 0.6 / rate + 10)
    run = grid.expand()[0]
    # a recording: the expert's measured mean length, each step rendering colour and depth
    episode = EXPERT_MEAN_STEPS["drawer-open-v3"] / METAWORLD_EVAL_STEPS_PER_SECOND["colour+depth"]
    assert demo_seconds(grid, run, 10, "cpu") == pytest.approx(10 * episode + 10 + 10)  # no failed attempts
    blind = parse_grid({"tasks": ["drawer-open-v3"], "obs_spaces": ["none"], "steps": 10, "cameras": []})
    episode = EXPERT_MEAN_STEPS["drawer-open-v3"] / METAWORLD_EVAL_STEPS_PER_SECOND["none"]  # physics alone
    assert demo_seconds(blind, blind.expand()[0], 10, "cpu") == pytest.approx(10 * episode + 10 + 10)
    epochs = parse_grid({"tasks": ["drawer-open-v3"], "obs_spaces": ["none"], "frame_epochs": 3, "batch_size": 10})
    run = epochs.expand()[0]
    frames = round(run.demos * EXPERT_MEAN_STEPS["drawer-open-v3"])  # before the demonstrations exist: an estimate
    assert planned_steps(run, tmp_path) == (math.ceil(3 * frames / 10), False)
    maniskill = parse_grid(BASE)
    run = maniskill.expand()[0]
    spec = maniskill.evaluations(run)[0]
    assert eval_seconds(spec, run, "cpu") == episode_seconds(
        spec.episodes, spec.max_steps, "cpu", image_size=run.image_size, task=run.task
    )


def test_cpu_metaworld_ranks_every_space_on_probed_easy_and_medium_tasks():
    """The `cpu-metaworld` grid: tasks of DP3's easy and medium groups, each one the oracle probe tried, every
    space; its point clouds are DP3's xyz, so their env renders depth alone."""
    import yaml

    from lerobot_obsbench.bench.cost import rendered_for
    from lerobot_obsbench.envs.catalog import task_record
    from lerobot_obsbench.envs.metaworld.tasks import tasks_of

    grid = load_grid("cpu-metaworld")
    runs = grid.expand()
    probe = yaml.safe_load((REPO_ROOT / "docs/results/metaworld/oracle-probe.yaml").read_text())
    assert set(grid.tasks) <= set(probe["tasks"])
    assert {group for group in ("easy", "medium") if set(grid.tasks) & set(tasks_of(group))} == {"easy", "medium"}
    assert set(grid.tasks) <= {*tasks_of("easy"), *tasks_of("medium")}
    assert {r.obs_space for r in runs} == {"none", "state", "rgb", "depth", "pointcloud"}
    clouds = [r for r in runs if r.obs_space == "pointcloud"]
    assert {(r.encoder, r.point_features, rendered_for(r.obs_space, r.point_features)) for r in clouds} == {
        ("dp3", "xyz", "depth")
    }
    # each task's cloud is cropped to its own measured box
    assert all(dict(r.policy_overrides)["workspace"] == list(task_record(r.task).workspace) for r in clouds)
    assert len({tuple(dict(r.policy_overrides)["workspace"]) for r in clouds}) == len(grid.tasks)


def test_dp3_metaworld_is_dp3s_protocol_on_its_fifty_tasks_and_is_priced(capsys):
    """The `dp3-metaworld` preset grid: DP3's 50 Meta-World tasks by difficulty group, 10 demonstrations, Diffusion
    Policy with DP3's settings (3 of the predicted actions executed, DDIM with 10 steps predicting the sample, DP3's
    encoder on 512 xyz points) against images, depth and both controls, 3,000 epochs at batch 128, three seeds, and
    a dry run that prices it."""
    from lerobot_obsbench.envs.metaworld.tasks import DIFFICULTIES, tasks_of

    grid = load_grid("dp3-metaworld")
    runs = grid.expand()
    assert grid.tasks == [task for group in DIFFICULTIES for task in tasks_of(group)] and len(grid.tasks) == 50
    assert {(r.obs_space, r.encoder) for r in runs} >= {("pointcloud", "dp3"), ("rgb", "resnet18")}
    assert {r.obs_space for r in runs} == {"none", "state", "rgb", "depth", "pointcloud"}
    assert {(r.policy, r.preset, r.demos, r.batch_size, r.budget_unit, r.budget) for r in runs} == {
        ("obs_diffusion", "dp3", 10, 128, "frame_epochs", 3000)
    }
    assert sorted({r.seed for r in runs}) == [0, 1, 2]
    fields = preset_overrides("dp3", "obs_diffusion", "pointcloud", "dp3")
    assert {k: fields[k] for k in ("n_action_steps", "noise_scheduler_type", "prediction_type")} == {
        "n_action_steps": 3,
        "noise_scheduler_type": "DDIM",
        "prediction_type": "sample",
    }
    assert (fields["num_inference_steps"], fields["num_tokens"], fields["point_features"]) == (10, 512, "xyz")
    from lerobot_obsbench.envs.metaworld.tasks import TABLE_WORKSPACE

    clouds = [r for r in runs if r.obs_space == "pointcloud"]  # DP3's one box for every task
    assert {tuple(dict(r.policy_overrides)["workspace"]) for r in clouds} == {TABLE_WORKSPACE}
    assert {s.episodes for r in runs[:5] for s in grid.evaluations(r)} == {20}
    assert {grid.max_steps(r) for r in runs} == {200}
    assert main(["run", "dp3-metaworld", "--dry-run", "--out", "/nonexistent/out"]) == 0
    text = capsys.readouterr().out
    assert "750 runs, 0 already trained, 750 to train" in text
    assert _hours("on a 2-core CPU, HOURS h on one H200 GPU", text) > 0
