"""The RealSense RGB-D camera on real librealsense: frames injected into a software device with chosen intrinsics,
depth units and depth -> colour extrinsics, recorded to a .bag, played back through the camera's pipeline."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pyrealsense2", reason="pyrealsense2 is in the test extra: pip install -e '.[test]'")

from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig
from lerobot_obsbench.robots.realsense.realsense_rgbd import RealSenseRGBDCamera
from lerobot_obsbench.robots.realsense.synthetic import StreamSpec, SyntheticRGBD, write_bag

W, H = 96, 72
COLOUR = StreamSpec(W, H, 80.0, 80.0, 47.5, 35.5)
DEPTH = StreamSpec(W, H, 70.0, 72.0, 48.2, 36.1)  # another lens: alignment must resample
DEPTH_TO_COLOUR = np.array([[1, 0, 0, -0.03], [0, 1, 0, 0.0], [0, 0, 1, 0.0], [0, 0, 0, 1]], dtype=float)
BOX = (np.array([0.0, 0.0, 0.06]), 0.06, (220, 30, 30))  # a 12 cm red box on the table


def scene(synthetic, spec: StreamSpec, cam2world: np.ndarray):
    """Colour and depth (mm) of the analytic table + box scene through a pinhole camera."""
    return synthetic.render(spec.K(), cam2world, (spec.height, spec.width), [BOX])[:2]


def depth_cam2world(synthetic) -> np.ndarray:
    """Looking straight down from 45 cm: table and box top at constant depths, so a misregistered pixel shows."""
    return synthetic.look_at(eye=(0.03, -0.02, 0.45), target=(0.03, -0.02, 0.0), up=(0.0, 1.0, 0.0))


def raw_depth_mm(synthetic) -> np.ndarray:
    """The depth camera's own image (what reading depth without alignment gives)."""
    return scene(synthetic, DEPTH, depth_cam2world(synthetic))[1][..., 0]


def record(path, synthetic, units: float, frames: int = 12, distortion=(0.0,) * 5) -> SyntheticRGBD:
    """The scene seen by a depth camera and, 3 cm to its right, a colour camera with another lens; colour pixel
    (0, 0) carries the frame index, depth moves 1 mm away per frame."""
    camera = SyntheticRGBD(COLOUR, DEPTH, units, DEPTH_TO_COLOUR, serial_number="123456789012", distortion=distortion)
    d2w = depth_cam2world(synthetic)
    colour, _ = scene(synthetic, COLOUR, d2w @ np.linalg.inv(DEPTH_TO_COLOUR))
    _, depth_mm = scene(synthetic, DEPTH, d2w)

    def pairs():
        for i in range(frames):
            tagged = colour.copy()
            tagged[0, 0] = (i, 255 - i, 7)
            shifted = np.where(depth_mm > 0, depth_mm.astype(float) + i, 0)[..., 0]
            yield tagged, np.rint(shifted * 0.001 / units).astype(np.uint16)

    write_bag(path, camera, pairs())
    return camera


def playback(path, **overrides) -> RealSenseRGBDCamera:
    fields = {"width": W, "height": H, "fps": 30, "downsample": 1, "warmup_s": 0, **overrides}
    config = RealSenseRGBDCameraConfig(playback_file=str(path), **fields)
    camera = RealSenseRGBDCamera(config)
    camera.connect(warmup=False)
    return camera


def read_all(camera) -> list[tuple[np.ndarray, np.ndarray, int]]:
    frames = []
    try:
        while True:
            colour, depth = camera.async_read_rgbd(timeout_ms=600)
            frames.append((colour, depth, camera.read_frame_number))
    except TimeoutError:
        return frames


@pytest.mark.parametrize("units", [0.001, 0.0001, 0.00025])
def test_depth_is_aligned_to_colour_in_millimetres_through_the_device_scale(tmp_path, synthetic_module, units):
    record(tmp_path / "scene.bag", synthetic_module, units, frames=6)
    camera = playback(tmp_path / "scene.bag")
    try:
        assert camera.depth_scale == pytest.approx(units, rel=1e-6)
        np.testing.assert_allclose(camera.K, COLOUR.K(), atol=1e-6)  # the colour stream's K, not depth's
        frames = read_all(camera)
    finally:
        camera.disconnect()
    assert len(frames) >= 4
    colour, depth, number = frames[0]
    assert depth.dtype == np.uint16 and depth.shape == (H, W, 1) and colour.shape == (H, W, 3)
    # truth: the scene's depth seen from the colour camera (no rotation, no z offset: depth along the same axis)
    _, truth = scene(synthetic_module, COLOUR, depth_cam2world(synthetic_module) @ np.linalg.inv(DEPTH_TO_COLOUR))
    truth = truth[..., 0].astype(float) + number
    got = depth[..., 0].astype(float)
    both = (got > 0) & (truth > 0)
    assert both.mean() > 0.85  # the rest: the image border and the box's side seen by one camera only
    assert np.mean(np.abs(got - truth)[both] <= 1) > 0.9  # millimetres through the device's depth scale
    # the box's depth lands on the box's colour pixels (unaligned, parallax and the other lens move it ~9 px)
    red = (colour[..., 0] > 200) & (colour[..., 1] < 60)
    near = (got > 0) & (got < truth.max() - 50)
    assert (near & red).sum() / (near | red).sum() > 0.9
    raw_near = (raw_depth_mm(synthetic_module) > 0) & (raw_depth_mm(synthetic_module) < truth.max() - 50)
    assert (raw_near & red).sum() / (raw_near | red).sum() < 0.75


def test_colour_and_depth_come_from_the_same_frameset(tmp_path, synthetic_module):
    record(tmp_path / "pairs.bag", synthetic_module, 0.0001, frames=30)
    camera = playback(tmp_path / "pairs.bag")
    try:
        frames = read_all(camera)
    finally:
        camera.disconnect()
    assert len(frames) >= 25  # real-time playback may skip the first frameset
    first_colour, first_depth, first = frames[0]
    valid = first_depth[..., 0] > 0
    for colour, depth, number in frames:
        index = int(colour[0, 0, 0])
        assert colour[0, 0, 1] == 255 - index and index == number
        # this frameset's depth (index mm further than frame `first`), not another frameset's
        shift = depth[..., 0][valid].astype(float) - first_depth[..., 0][valid]
        assert np.median(shift) == pytest.approx(index - first, abs=0.5)
    numbers = [n for _, _, n in frames]
    assert numbers == sorted(numbers)


def test_downsampled_frames_keep_K_consistent(tmp_path, synthetic_module):
    record(tmp_path / "scene.bag", synthetic_module, 0.001, frames=4)
    camera = playback(tmp_path / "scene.bag", downsample=2)
    try:
        colour, depth = camera.async_read_rgbd(timeout_ms=2000)
        number = camera.read_frame_number
    finally:
        camera.disconnect()
    assert colour.shape == (H // 2, W // 2, 3) and depth.shape == (H // 2, W // 2, 1)
    np.testing.assert_allclose(camera.K[[0, 1], [0, 1]], [COLOUR.fx / 2, COLOUR.fy / 2])
    # the scene rendered through the scaled K at the halved size is what the camera returns
    K = camera.K
    half = StreamSpec(W // 2, H // 2, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    _, truth = scene(synthetic_module, half, depth_cam2world(synthetic_module) @ np.linalg.inv(DEPTH_TO_COLOUR))
    got, truth = depth[..., 0].astype(float), truth[..., 0].astype(float) + number
    both = (got > 0) & (truth > 0)
    assert np.mean(np.abs(got - truth)[both] <= 1) > 0.85


def test_distorted_colour_stream_is_refused(tmp_path, synthetic_module):
    record(tmp_path / "distorted.bag", synthetic_module, 0.001, frames=3, distortion=(0.12, -0.05, 0.0, 0.0, 0.0))
    config = RealSenseRGBDCameraConfig(playback_file=str(tmp_path / "distorted.bag"), width=W, height=H, downsample=1)
    with pytest.raises(ValueError, match="lens distortion.*max_distortion"):
        RealSenseRGBDCamera(config).connect(warmup=False)


def test_unknown_serial_names_the_cameras_found(monkeypatch):
    monkeypatch.setattr(RealSenseRGBDCamera, "find_cameras", staticmethod(lambda: [{"id": "111"}, {"id": "222"}]))
    camera = RealSenseRGBDCamera(RealSenseRGBDCameraConfig(serial_number="999", width=W, height=H, downsample=1))
    with pytest.raises(ConnectionError, match=r"999.*connected: \['111', '222'\]"):
        camera.connect()


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({}, "serial_number"),
        ({"serial_number": "1", "downsample": 7}, "downsample"),
        ({"serial_number": "1", "depth_filters": ["median"]}, "depth_filters"),
        ({"serial_number": "1", "sync_mode": "leader"}, "sync_mode"),
    ],
)
def test_config_refuses_bad_values(fields, message):
    with pytest.raises(ValueError, match=message):
        RealSenseRGBDCameraConfig(**fields)
