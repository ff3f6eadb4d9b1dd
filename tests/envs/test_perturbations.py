"""The perturbation vocabulary shared by the task families (envs/perturbations.py): every bad perturbation is one
clear line before anything slow starts — an unknown kind, a level outside its range, depth noise on a space with no
depth, light on a space that reads no colour, a kind a family's env does not apply — in a grid, an env and an
evaluation; and the depth noise of an episode repeats with its seed."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from lerobot_obsbench.bench.grid import parse_grid
from lerobot_obsbench.bench.specs import GridError
from lerobot_obsbench.envs.perturbations import (
    MANISKILL_KINDS,
    METAWORLD_KINDS,
    DepthNoiser,
    PerturbationError,
    applies_to,
    check_changes,
    check_supported,
    orbit_eye,
    orbit_rotation,
    parse_perturbation,
)
from lerobot_obsbench.schema import depth_key, intrinsics_key


@pytest.mark.parametrize(
    ("text", "refusal"),
    [
        ("fog:3", "unknown perturbation 'fog:3'; write one of camera_yaw:DEG, camera_pitch:DEG, light:I, background"),
        ("depth_noise:5", r"depth_noise takes a level in \(0, 4\] \(1: a D415 by its datasheet\)"),
        ("depth_noise:0", r"depth_noise takes a level in \(0, 4\]"),
        ("depth_noise:1,2", "depth_noise takes 1 number"),
        ("camera_yaw:90", "camera angles must be within"),
        ("background:1,2,0", r"colours must be in \[0, 1\]"),
    ],
)
def test_a_perturbation_written_wrongly_is_refused_naming_the_forms(text, refusal):
    with pytest.raises(PerturbationError, match=refusal):
        parse_perturbation(text)


def test_what_a_perturbation_can_change_follows_what_the_space_reads():
    assert applies_to("depth_noise:1", "pointcloud") and applies_to("depth_noise:1", "rgbd")
    assert not applies_to("depth_noise:1", "rgb") and not applies_to("depth_noise:1", "none")
    assert applies_to("light:0.1", "rgb") and applies_to("light:0.1", "pointcloud", "rgb+xyz")
    assert not applies_to("light:0.1", "pointcloud", "xyz") and not applies_to("background:1,0,0", "depth")
    assert applies_to("camera_yaw:5", "depth") and not applies_to("camera_yaw:5", "state")
    with pytest.raises(PerturbationError, match=r"depth_noise:1 changes only what policies reading depth see, and "):
        check_changes(parse_perturbation("depth_noise:1"), "rgb")
    with pytest.raises(PerturbationError, match=r"point_features xyz\) reads depth: its episodes would replay"):
        check_changes(parse_perturbation("light:3"), "pointcloud", "xyz")
    check_changes(parse_perturbation("depth_noise:2"), "pointmap")


def test_each_family_applies_its_kinds_and_refuses_the_others():
    assert set(METAWORLD_KINDS) == set(MANISKILL_KINDS) - {"noise"}
    with pytest.raises(PerturbationError, match="noise:2: Meta-World tasks do not support noise perturbations"):
        check_supported(parse_perturbation("noise:2"), METAWORLD_KINDS, "Meta-World")
    check_supported(parse_perturbation("depth_noise:1"), METAWORLD_KINDS, "Meta-World")


GRID = {"obs_spaces": ["rgb", "pointcloud"], "steps": 5, "preset": "tiny"}


@pytest.mark.parametrize(
    ("tasks", "spaces", "perturbation", "refusal"),
    [
        (["reach-v3"], ["rgb"], "noise:16", "Meta-World tasks do not support noise perturbations; they take camera_"),
        (["PushCube-v1"], ["rgb", "none"], "depth_noise:1", "changes only what spaces reading depth see, and none of"),
        (["PushCube-v1"], ["rgb"], "depth_noise:9", r"depth_noise takes a level in \(0, 4\]"),
        (["PushCube-v1"], ["rgb"], "dusk:1", "unknown perturbation 'dusk:1'"),
    ],
)
def test_a_grid_refuses_a_perturbation_it_cannot_use_in_one_line(tasks, spaces, perturbation, refusal):
    started = time.perf_counter()
    with pytest.raises(GridError, match=refusal):
        parse_grid({**GRID, "tasks": tasks, "obs_spaces": spaces, "perturbations": [perturbation]})
    assert time.perf_counter() - started < 5


def test_each_run_is_evaluated_under_the_perturbations_that_can_change_what_it_reads():
    grid = parse_grid(
        {
            "tasks": ["reach-v3"],
            "obs_spaces": ["none", "rgb", "depth", "pointcloud"],
            "encoders": {"rgb": ["spatial_softmax"], "depth": ["spatial_softmax"], "pointcloud": ["dp3"]},
            "steps": 5,
            "perturbations": ["camera_yaw:5", "light:0.1", "background:1,0.2,0.2", "depth_noise:1"],
        }
    )
    found = {run.obs_space: grid.perturbations_for(run) for run in grid.expand()}
    assert found["none"] == []
    assert found["rgb"] == ["camera_yaw:5", "light:0.1", "background:1,0.2,0.2"]
    assert found["depth"] == found["pointcloud"] == ["camera_yaw:5", "depth_noise:1"]  # DP3's cloud is xyz


def test_an_episodes_depth_noise_repeats_with_its_seed_and_differs_with_another():
    depth = torch.full((2, 24, 24, 1), 800, dtype=torch.int32)
    depth[:, 8:16, 8:16] = 500  # a near block: holes beside its edge
    frames = {depth_key("cam"): depth.numpy(), intrinsics_key("cam"): np.tile(np.diag([30.0, 30.0, 1.0]), (2, 1, 1))}
    noiser = DepthNoiser(parse_perturbation("depth_noise:1"), num_envs=2)
    outs = []
    for seeds in ([3, 4], [3, 4], [4, 3]):
        noiser.reset(seeds)
        outs.append(noiser.apply(dict(frames), ["cam"])[depth_key("cam")])
    assert outs[0].dtype == depth.numpy().dtype and outs[0].shape == depth.shape
    assert np.array_equal(outs[0], outs[1]) and not np.array_equal(outs[0], frames[depth_key("cam")])
    assert np.array_equal(outs[2][0], outs[0][1]) and np.array_equal(outs[2][1], outs[0][0])  # each slot its seed's


def test_orbiting_keeps_the_distance_and_the_target():
    eye, target = np.array([0.5, 0.2, 0.6]), np.array([0.0, 0.1, 0.0])
    for yaw, pitch in ((10, 0), (0, 10), (-5, 5)):
        moved = orbit_eye(eye, target, yaw, pitch)
        assert np.linalg.norm(moved - target) == pytest.approx(np.linalg.norm(eye - target))
        turn = orbit_rotation(eye, target, yaw, pitch)
        assert np.allclose(turn @ turn.T, np.eye(3)) and np.linalg.det(turn) == pytest.approx(1.0)
    assert orbit_eye(eye, target, 0, 10)[2] > eye[2]  # pitching up raises the camera
