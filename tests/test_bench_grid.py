"""Grid files: presets expand and validate; bad grids fail before anything runs, naming the valid choices."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_obsbench.bench.grid import GridError, RunSpec, load_grid, parse_grid, preset_grids
from lerobot_obsbench.bench.runner import plan, train_command
from lerobot_obsbench.cli import main
from lerobot_obsbench.envs.perturbations import orbit_eye, parse_perturbation

BASE = {"tasks": ["PushCube-v1"], "obs_spaces": ["rgb", "pointcloud"], "steps": 10, "preset": "tiny"}


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
    # paper-main: 3 tasks x 7 (space, encoder) pairs of Table 2 x 2 policies x 3 lrs x 3 seeds
    assert len(sizes["paper-main"]) == 3 * 7 * 2 * 3 * 3
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
    assert all(r.preset == "paper" and r.eval_episodes == 400 for r in sizes["paper-main"])
    assert len(sizes["paper-generalization"][0].perturbations) == 20
    quick = sizes["quick"]
    assert {"rgb", "rgbd", "pointcloud"} <= {r.obs_space for r in quick}


def test_variants_are_an_axis_and_a_column_label():
    runs = parse_grid(
        {**BASE, "obs_spaces": ["pointcloud"], "variants": [{}, {"sampling": "pre"}, {"point_features": "xyz"}]}
    ).expand()
    assert [dict(r.policy_overrides) for r in runs] == [{}, {"sampling": "pre"}, {"point_features": "xyz"}]
    assert len({r.run_id for r in runs}) == 3


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
        ({"stepz": 3}, ["stepz", "steps", "epochs"]),
        ({"epochs": 3}, ["exactly one", "steps", "epochs"]),
        ({"perturbations": ["lighting:0.3"]}, ["lighting:0.3", "camera_yaw:DEG", "light:I"]),
        ({"perturbations": ["background:2,0,0"]}, ["background:2,0,0", "[0, 1]"]),
        ({"variants": [{}, {"sampling": "pre"}]}, ["obs_act/rgb/resnet18", "sampling='pre'", "point-cloud design"]),
        ({"policy_overrides": {"chunk_sise": 5}}, ["no fields ['chunk_sise']"]),
        ({"seeds": []}, ["'seeds' is empty"]),
    ],
)
def test_bad_grids_fail_with_the_valid_choices(change, words):
    with pytest.raises(GridError) as err:
        parse_grid({**BASE, **change})
    for word in words:
        assert word in str(err.value)


def test_bad_grid_fails_before_anything_runs(tmp_path, capsys):
    grid = tmp_path / "bad.yaml"
    grid.write_text("tasks: [PushCube-v1]\nobs_spaces: [rgb]\nencoders: {rgb: [pointnet]}\nsteps: 5\n")
    assert main(["run", str(grid), "--out", str(tmp_path / "out")]) == 2
    assert "does not accept obs_space='rgb'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_dry_run_prints_the_plan_and_skips_finished_runs(tmp_path, capsys):
    grid = tmp_path / "g.yaml"
    grid.write_text("tasks: [PushCube-v1]\nobs_spaces: [rgb, pointcloud]\nseeds: [1, 2]\nsteps: 5\npreset: tiny\n")
    assert main(["run", str(grid), "--out", str(tmp_path), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "4 runs, 0 already finished, 4 to run" in text
    runs, todo = plan(load_grid(grid), tmp_path)
    (tmp_path / "results.jsonl").write_text(
        '{"run_id": "' + runs[0].run_id + '", "config": {}, "method": "m", "evaluations": {}}\n'
    )
    assert main(["run", str(grid), "--out", str(tmp_path), "--dry-run"]) == 0
    assert "4 runs, 1 already finished, 3 to run" in capsys.readouterr().out
    assert not (tmp_path / "demos").exists()


def test_train_command_is_stock_lerobot_train_with_the_run_fields(tmp_path):
    run = parse_grid(
        {**BASE, "encoders": {"rgb": ["resnet18"]}, "demos": [7], "seeds": [5], "policy_overrides": {"chunk_size": 3}}
    ).expand()[0]
    cmd = train_command(run, tmp_path / "ds", tmp_path / "out", steps=10, device="cpu")
    assert cmd[0].endswith("lerobot-train")
    for arg in (
        "--policy.type=obs_act",
        "--policy.obs_space=rgb",
        "--policy.encoder=resnet18",
        "--seed=5",
        "--steps=10",
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
