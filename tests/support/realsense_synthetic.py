"""Write RealSense recordings (.bag) of chosen colour + depth frames with librealsense's own software device.

No camera is needed: a `software_device` with a depth and a colour sensor receives the frames with the given
intrinsics, depth units and depth -> colour extrinsics, and `rs.recorder` writes them to a .bag that
`RealSenseRGBDCameraConfig(playback_file=...)` plays back through a normal pipeline. The tests and the recording
benchmark drive the camera this way; it also turns frames from elsewhere into a file the camera can replay.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lerobot_obsbench.robots.realsense.realsense_rgbd import import_realsense


@dataclass
class StreamSpec:
    """One synthetic stream: pinhole intrinsics (fx, fy, cx, cy) at width x height."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)


@dataclass
class SyntheticRGBD:
    """A synthetic RealSense: its streams, depth units and the depth -> colour rigid transform."""

    colour: StreamSpec
    depth: StreamSpec
    depth_units: float = 0.001  # metres per z16 unit (D400: 0.001 by default, 0.0001 in high-accuracy modes)
    depth_to_colour: np.ndarray = field(default_factory=lambda: np.eye(4))  # (4, 4), depth frame -> colour frame
    fps: int = 30
    serial_number: str = "000000000001"
    name: str = "Intel RealSense D415 (synthetic)"
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)  # colour stream Brown-Conrady coefficients


def _intrinsics(rs, spec: StreamSpec, coeffs=(0.0,) * 5):
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = spec.width, spec.height
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = spec.fx, spec.fy, spec.cx, spec.cy
    intrinsics.model = rs.distortion.brown_conrady
    intrinsics.coeffs = list(coeffs)
    return intrinsics


def _stream(rs, kind, uid: int, fmt, bpp: int, spec: StreamSpec, fps: int, coeffs=(0.0,) * 5):
    stream = rs.video_stream()
    stream.type, stream.index, stream.uid = kind, 0, uid
    stream.width, stream.height, stream.fps, stream.bpp, stream.fmt = spec.width, spec.height, fps, bpp, fmt
    stream.intrinsics = _intrinsics(rs, spec, coeffs)
    return stream


def write_bag(path: str | Path, camera: SyntheticRGBD, frames: Iterable[tuple[np.ndarray, np.ndarray]]) -> int:
    """Record (colour (H, W, 3) uint8, depth (h, w) uint16 in `depth_units`) pairs to `path`; returns the count.

    Both frames of a pair get the same frame number and timestamp (1/fps apart), as one hardware frameset. Frames
    are injected at the camera's rate (writing takes count/fps seconds): the recorder stamps each frame with its
    arrival time, which is what real-time playback follows and what pairs colour with depth on playback."""
    rs = import_realsense()
    device = rs.software_device()
    device.register_info(rs.camera_info.name, camera.name)
    device.register_info(rs.camera_info.serial_number, camera.serial_number)
    depth_sensor = device.add_sensor("Stereo Module")
    colour_sensor = device.add_sensor("RGB Camera")
    depth_sensor.add_read_only_option(rs.option.depth_units, camera.depth_units)
    depth_profile = depth_sensor.add_video_stream(
        _stream(rs, rs.stream.depth, 0, rs.format.z16, 2, camera.depth, camera.fps)
    ).as_video_stream_profile()
    colour_profile = colour_sensor.add_video_stream(
        _stream(rs, rs.stream.color, 1, rs.format.rgb8, 3, camera.colour, camera.fps, camera.distortion)
    ).as_video_stream_profile()
    extrinsics = rs.extrinsics()
    extrinsics.rotation = [float(v) for v in np.asarray(camera.depth_to_colour)[:3, :3].T.ravel()]  # column-major
    extrinsics.translation = [float(v) for v in np.asarray(camera.depth_to_colour)[:3, 3]]
    depth_profile.register_extrinsics_to(colour_profile, extrinsics)

    recorder = rs.recorder(str(path), device)
    depth_sensor.open(depth_profile)
    colour_sensor.open(colour_profile)
    syncer = rs.syncer()
    depth_sensor.start(syncer)
    colour_sensor.start(syncer)
    count, alive = 0, []  # librealsense reads the pixel buffers after on_video_frame returns: keep them alive
    start = time.perf_counter()
    for count, (colour, depth) in enumerate(frames, start=1):
        time.sleep(max(0.0, start + (count - 1) / camera.fps - time.perf_counter()))
        colour = np.ascontiguousarray(colour, dtype=np.uint8)
        depth = np.ascontiguousarray(np.asarray(depth).reshape(camera.depth.height, camera.depth.width), np.uint16)
        alive.append((colour, depth))
        for sensor, profile, pixels, bpp, width in (
            (depth_sensor, depth_profile, depth, 2, camera.depth.width),
            (colour_sensor, colour_profile, colour, 3, camera.colour.width),
        ):
            frame = rs.software_video_frame()
            frame.pixels, frame.bpp, frame.stride = pixels, bpp, width * bpp
            frame.timestamp = (count - 1) * 1000.0 / camera.fps
            frame.domain = rs.timestamp_domain.hardware_clock
            frame.frame_number = count - 1
            frame.profile = profile
            sensor.on_video_frame(frame)
    for sensor in (depth_sensor, colour_sensor):
        sensor.stop()
        sensor.close()
    del recorder  # flushes and closes the file
    return count


def aligned_by_librealsense(path: str | Path) -> np.ndarray:
    """librealsense's own `rs.align` to colour of the first full frameset of a recording: the depth (h, w) in the
    recording's depth units. The recording is played as fast as it is read, every sensor opened before any starts
    (as the camera plays it), so its first framesets are not lost to a loaded machine's schedule."""
    rs = import_realsense()
    device = rs.context().load_device(str(path))
    player = device.as_playback()
    player.set_real_time(False)
    player.pause()
    sensors, syncer = device.query_sensors(), rs.syncer()
    for sensor in sensors:
        sensor.open(sensor.get_stream_profiles()[0])
    for sensor in sensors:
        sensor.start(syncer)
    player.resume()
    try:
        while True:
            frames = syncer.wait_for_frames(60_000)
            if frames.get_color_frame() and frames.get_depth_frame():
                return np.asanyarray(rs.align(rs.stream.color).process(frames).get_depth_frame().get_data()).copy()
    finally:
        player.pause()
        while syncer.poll_for_frames():
            pass
        for sensor in sensors:
            sensor.stop()
            sensor.close()
