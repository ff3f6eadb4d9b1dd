"""`obsbench validate` reads the sensor values: each corruption a real recording can have is caught, with the
episodes named and a non-zero exit for the spaces it breaks; a few empty frames are reported, not failed."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_obsbench.cli import main

CAM = "base_camera"
DEPTH, K, POSE = f"observation.depth.{CAM}", f"observation.intrinsics.{CAM}", f"observation.cam2world.{CAM}"
POINT_SPACES = ("depth", "rgbd", "pointmap", "pointcloud")


def _write(synthetic, tmp_path_factory, name, hook=None, **kwargs):
    root = tmp_path_factory.mktemp("validate") / name
    return synthetic.write_dataset(
        root, episodes=3, frames=6, size=32, seed=3, use_video=False, frame_hook=hook, **kwargs
    )


def _in_episode(episode, change, frames=None):
    """A frame hook applying `change` to the frames of one episode (all, or the listed indices)."""

    def hook(ep, index, frame):
        if ep == episode and (frames is None or index in frames):
            frame = {**frame, **change(frame)}
        return frame

    return hook


def _validate(root, capsys, *args):
    code = main(["validate", "--root", str(root), *args])
    return code, capsys.readouterr().out


def _verdicts(out: str) -> dict[str, bool]:
    return {line.split()[1]: line.startswith("ok") for line in out.splitlines() if line.startswith(("ok", "FAILED"))}


def test_one_empty_depth_frame_is_a_note_not_a_failure(synthetic_module, tmp_path_factory, capsys):
    root = _write(
        synthetic_module, tmp_path_factory, "one_empty", _in_episode(1, lambda f: {DEPTH: f[DEPTH] * 0}, frames={4})
    )
    code, out = _validate(root, capsys)
    assert code == 0 and all(_verdicts(out).values())
    assert "1 of 18 frames have no valid depth pixel, in episode 1 (1 of 3)" in out
    assert "empty-cloud point" in out


def test_mostly_empty_episode_fails_the_depth_spaces(synthetic_module, tmp_path_factory, capsys):
    root = _write(
        synthetic_module, tmp_path_factory, "empty_ep", _in_episode(2, lambda f: {DEPTH: f[DEPTH] * 0}, {0, 1, 2, 3})
    )
    code, out = _validate(root, capsys)
    verdicts = _verdicts(out)
    assert code == 1 and verdicts["rgb"] and verdicts["none"]
    assert not any(verdicts[s] for s in POINT_SPACES)
    assert "worst: episode 2, 67% of its frames" in out and "episodes [2]" in out
    assert _validate(root, capsys, "--obs-space", "pointcloud")[0] == 1
    assert _validate(root, capsys, "--obs-space", "rgb")[0] == 0


@pytest.mark.parametrize(
    "name,change,message",
    [
        ("nan_K", lambda f: {K: np.full((3, 3), np.nan, np.float32)}, "cannot belong to the 32x32 frames"),
        ("zero_focal", lambda f: {K: f[K] * np.diag([0, 1, 1]).astype(np.float32)}, "(e.g. fx 0, fy"),
        # a per-frame K scaled x4 (the frames were downsampled, K was not)
        ("scaled_K", lambda f: {K: np.diag([4, 4, 1]).astype(np.float32) @ f[K]}, "scale fx, fy, cx, cy with the"),
        # a 640x480 camera's K stored beside 32x32 frames
        (
            "other_resolution",
            lambda f: {K: np.array([[600, 0, 320], [0, 600, 240], [0, 0, 1]], np.float32)},
            "principal point (320, 240)",
        ),
        (
            "scaled_pose",
            lambda f: {POSE: f[POSE] @ np.diag([1.05, 1.05, 1.05, 1]).astype(np.float32)},
            "not rigid camera -> world transforms (largest deviation 0.158",
        ),
    ],
)
def test_bad_camera_geometry_fails_the_point_spaces(synthetic_module, tmp_path_factory, capsys, name, change, message):
    root = _write(synthetic_module, tmp_path_factory, name, _in_episode(1, change, frames={2}))
    code, out = _validate(root, capsys)
    verdicts = _verdicts(out)
    assert code == 1 and message in out and "in episode 1 (1 of 3)" in out
    assert verdicts["rgb"] and verdicts["depth"] and verdicts["rgbd"]
    assert not verdicts["pointmap"] and not verdicts["pointcloud"]
    # the metadata alone cannot see it
    assert _validate(root, capsys, "--quick")[0] == 0


def test_depth_in_metres_is_caught(synthetic_module, tmp_path_factory, capsys):
    root = _write(synthetic_module, tmp_path_factory, "metres", lambda e, i, f: {**f, DEPTH: f[DEPTH] // 1000})
    code, out = _validate(root, capsys, "--obs-space", "depth")
    assert code == 1 and "expected millimetres" in out


def test_colour_and_depth_at_different_resolutions(synthetic_module, tmp_path_factory, capsys):
    root = _write(synthetic_module, tmp_path_factory, "half_depth", depth_size=16)
    code, out = _validate(root, capsys)
    verdicts = _verdicts(out)
    assert code == 1 and "is 32x32 but observation.depth.base_camera is 16x16" in out
    assert verdicts["rgb"] and verdicts["depth"]
    assert not verdicts["rgbd"] and not verdicts["pointmap"] and not verdicts["pointcloud"]


def test_not_a_dataset_is_one_line(tmp_path, capsys):
    assert main(["validate", "--root", str(tmp_path / "nothing")]) == 2
    assert "is not a LeRobot dataset (no meta/info.json)" in capsys.readouterr().err


def test_constant_depth_everywhere_fails_the_depth_spaces_and_a_few_flat_frames_are_a_note(
    synthetic_module, tmp_path_factory, capsys
):
    """What a 1-channel depth image read as RLBench's packed depth leaves: one value over the whole view."""
    flat = lambda f: {DEPTH: np.full_like(f[DEPTH], 4500)}
    root = _write(synthetic_module, tmp_path_factory, "flat", lambda ep, index, frame: {**frame, **flat(frame)})
    code, out = _validate(root, capsys)
    verdicts = _verdicts(out)
    assert code == 1 and verdicts["rgb"] and not any(verdicts[s] for s in POINT_SPACES)
    assert "18 of 18 frames hold one depth value over the whole view: this is not depth" in out
    root = _write(synthetic_module, tmp_path_factory, "two_flat", _in_episode(0, flat, frames={1, 2}))
    code, out = _validate(root, capsys)
    assert code == 0 and "2 of 18 frames hold one depth value over the whole view (in episode 0" in out
