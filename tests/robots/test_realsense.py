"""The RealSense RGB-D camera on real librealsense: frames injected into a software device with chosen intrinsics,
depth units and depth -> colour extrinsics, recorded to a .bag, played back through the camera's pipeline."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("pyrealsense2", reason="pyrealsense2 is in the test extra: pip install -e '.[test]'")

from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig
from lerobot_obsbench.robots.realsense.realsense_rgbd import RealSenseRGBDCamera, RecordingEndedError
from tests.support.realsense_synthetic import StreamSpec, SyntheticRGBD, aligned_by_librealsense, write_bag

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
    """The camera playing `path` as fast as it is read: every frameset once, whatever the machine's load."""
    fields = {"width": W, "height": H, "fps": 30, "downsample": 1, "warmup_s": 0, "playback_real_time": False}
    fields.update(overrides)
    config = RealSenseRGBDCameraConfig(playback_file=str(path), **fields)
    camera = RealSenseRGBDCamera(config)
    camera.connect(warmup=False)
    return camera


def read_all(camera) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """Every frameset of a recording, up to its end (told by the camera, not guessed from a pause)."""
    frames = []
    try:
        while True:
            colour, depth = camera.async_read_rgbd(timeout_ms=60_000)
            frames.append((colour, depth, camera.read_frame_number))
    except RecordingEndedError:
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
    assert [number for _, _, number in frames] == list(range(6))  # the first frameset too
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
    # (over the pixels given a depth: the registration leaves the box's occlusion edges unknown)
    red = (colour[..., 0] > 200) & (colour[..., 1] < 60) & (got > 0)
    near = (got > 0) & (got < truth.max() - 50)
    assert (near & red).sum() / (near | red).sum() > 0.95
    raw_near = (raw_depth_mm(synthetic_module) > 0) & (raw_depth_mm(synthetic_module) < truth.max() - 50)
    assert (raw_near & red).sum() / (raw_near | red).sum() < 0.75


def test_colour_and_depth_come_from_the_same_frameset(tmp_path, synthetic_module):
    record(tmp_path / "pairs.bag", synthetic_module, 0.0001, frames=30)
    camera = playback(tmp_path / "pairs.bag")
    try:
        frames = read_all(camera)
    finally:
        camera.disconnect()
    assert [number for _, _, number in frames] == list(range(30))
    first_colour, first_depth, first = frames[0]
    valid = first_depth[..., 0] > 0
    for colour, depth, number in frames:
        index = int(colour[0, 0, 0])
        assert colour[0, 0, 1] == 255 - index and index == number
        # this frameset's depth (index mm further than frame `first`), not another frameset's
        shift = depth[..., 0][valid].astype(float) - first_depth[..., 0][valid]
        assert np.median(shift) == pytest.approx(index - first, abs=0.5)


def test_a_short_recording_plays_whole_however_late_its_second_sensor_starts(tmp_path, synthetic_module, monkeypatch):
    """The player reads its first item when the first sensor starts. On a loaded machine the second sensor may
    start after that read: made certain here by waiting for the player to start in between. Both framesets of a
    two-frameset recording still come back, then the end is reported (before the fix: no depth at all, and the
    reader timed out)."""
    import pyrealsense2 as rs

    record(tmp_path / "two.bag", synthetic_module, 0.001, frames=2)
    start = RealSenseRGBDCamera._start_sensor

    def start_then_let_the_player_read(camera, sensor):
        start(camera, sensor)
        while camera._playback.current_status() == rs.playback_status.stopped:
            time.sleep(0.01)  # polls the player's state, set by its own thread

    monkeypatch.setattr(RealSenseRGBDCamera, "_start_sensor", start_then_let_the_player_read)
    camera = playback(tmp_path / "two.bag")
    try:
        frames = read_all(camera)
        with pytest.raises(EOFError, match="has ended; all 2 of its framesets"):
            camera.async_read_rgbd(timeout_ms=60_000)
    finally:
        camera.disconnect()
    assert [number for _, _, number in frames] == [0, 1]


def test_downsampled_frames_keep_K_consistent(tmp_path, synthetic_module):
    record(tmp_path / "scene.bag", synthetic_module, 0.001, frames=4)
    camera = playback(tmp_path / "scene.bag", downsample=2)
    try:
        colour, depth = camera.async_read_rgbd(timeout_ms=60_000)
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


# A D400-like depth -> colour extrinsic: a fraction of a degree of rotation and millimetres of offset besides the
# baseline; with it, the depth camera's z is not the colour camera's
ROTATED = np.eye(4)
ROTATED[:3, :3] = Rotation.from_euler("xyz", [0.5, -1.0, 0.3], degrees=True).as_matrix()
ROTATED[:3, 3] = [0.015, 0.001, 0.002]
SLANTED = [(np.array([0.0, 0.0, 0.025]), 0.025, (220, 30, 30)), (np.array([0.1, 0.05, 0.04]), 0.04, (30, 30, 220))]


def true_z(synthetic, spec: StreamSpec, cam2world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Colour and exact z (metres, 0 = no return) along the camera's axis of the slanted two-box scene."""
    rgb, _, points = synthetic.render(spec.K(), cam2world, (spec.height, spec.width), SLANTED)
    world_to_cam = np.linalg.inv(cam2world)
    return rgb, np.nan_to_num((points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3])[..., 2], nan=0.0)


@pytest.mark.parametrize("downsample", [1, 2])
def test_depth_is_registered_into_the_colour_camera_exactly_with_a_rotated_extrinsic(
    tmp_path, synthetic_module, downsample
):
    """The colour camera's z at each colour pixel, within 1 mm (median < 0.5 mm) at >= 99% of the pixels given,
    from a depth camera with another lens, rotated and offset; librealsense's rs.align on the same recording keeps
    the depth camera's z (the control: this test tells the two apart)."""
    # 320 x 240: fine enough that the oblique table's depth changes little between neighbouring pixels
    colour_spec = StreamSpec(320, 240, 260.0, 260.0, 159.5, 119.5)
    depth_spec = StreamSpec(320, 240, 240.0, 242.0, 161.4, 117.8)
    colour2world = synthetic_module.look_at(eye=(0.35, -0.25, 0.45), target=(0.0, 0.0, 0.0))
    rgb, _ = true_z(synthetic_module, colour_spec, colour2world)
    _, depth_z = true_z(synthetic_module, depth_spec, colour2world @ ROTATED)
    units = 0.0001  # 0.1 mm: the camera's own quantisation stays below what is measured
    raw = np.rint(depth_z / units).astype(np.uint16)
    write_bag(tmp_path / "rotated.bag", SyntheticRGBD(colour_spec, depth_spec, units, ROTATED), [(rgb, raw)] * 2)
    camera = playback(tmp_path / "rotated.bag", width=320, height=240, downsample=downsample)
    try:
        _, depth = camera.async_read_rgbd(timeout_ms=60_000)
        K = camera.K
    finally:
        camera.disconnect()
    h, w = 240 // downsample, 320 // downsample
    _, truth = true_z(synthetic_module, StreamSpec(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2]), colour2world)
    got = depth[..., 0].astype(float) / 1000
    given = (got > 0) & (truth > 0)
    error_mm = np.abs(got - truth)[given] * 1000
    assert given.sum() >= 0.95 * (truth > 0).sum()  # the rest: occlusion edges, left unknown
    assert (error_mm <= 1.0).mean() >= 0.99 and np.median(error_mm) < 0.5, np.percentile(error_mm, [50, 99])
    if downsample == 1:  # the control
        aligned = aligned_by_librealsense(tmp_path / "rotated.bag").astype(float) * units
        both = (aligned > 0) & (truth > 0)
        assert (np.abs(aligned - truth)[both] * 1000 <= 1.0).mean() < 0.5


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
        ({"serial_number": "1", "downsample": 0}, "downsample must be a whole number >= 1; got 0"),
        ({"serial_number": "1", "fps": -30}, "fps must be a whole number >= 1; got -30"),
        ({"serial_number": "1", "warmup_s": float("nan")}, "warmup_s must be a finite number >= 0; got nan"),
        ({"serial_number": "1", "max_distortion": float("inf")}, "max_distortion must be a finite number >= 0"),
    ],
)
def test_config_refuses_bad_values(fields, message):
    with pytest.raises(ValueError, match=message):
        RealSenseRGBDCameraConfig(**fields)


def test_disconnecting_before_the_end_of_a_recording_played_as_fast_as_read(tmp_path, synthetic_module):
    """The lossless playback waits for its reader; disconnecting with framesets left must not wait forever."""
    import threading

    record(tmp_path / "long.bag", synthetic_module, 0.001, frames=12)
    camera = playback(tmp_path / "long.bag")
    camera.async_read_rgbd(timeout_ms=60_000)
    closing = threading.Thread(target=camera.disconnect, daemon=True)
    closing.start()
    closing.join(timeout=300)  # bounds a hang; a healthy disconnect takes well under a second
    assert not closing.is_alive() and not camera.is_connected
