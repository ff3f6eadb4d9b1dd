"""Intel RealSense as one RGB-D sensor for LeRobot robots (README: Real robot).

LeRobot 0.4.4's `intelrealsense` camera reads colour and depth without aligning them, exposes no intrinsics and
assumes millimetre depth units. Here one librealsense pipeline streams both at the same fps; a background thread
takes each frameset, aligns depth to colour (`rs.align`), filters it (optional), converts it to uint16
millimetres through the device's own depth scale, and keeps colour and depth of that frameset together, so a
read returns a matching pair. K is the colour stream's pinhole intrinsics (scaled with `downsample`).

Needs `pyrealsense2` (`pip install 'lerobot_policy_obsbench[realsense]'`; on Linux also Debian's `libusb-1.0-0`).
"""

from __future__ import annotations

import logging
import time
from threading import Event, Lock, Thread
from typing import Any

import cv2
import numpy as np
from lerobot.cameras.camera import Camera
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_obsbench.robots.realsense.config_realsense_rgbd import SYNC_MODES, RealSenseRGBDCameraConfig

logger = logging.getLogger(__name__)

INSTALL_HINT = (
    "pyrealsense2 is needed for RealSense cameras: pip install 'lerobot_policy_obsbench[realsense]' "
    "(and on Debian/Ubuntu: apt-get install libusb-1.0-0)."
)


def import_realsense():
    try:
        import pyrealsense2 as rs
    except ImportError as error:
        raise ImportError(f"{INSTALL_HINT} ({error})") from error
    return rs


def pinhole_K(intrinsics, downsample: int = 1) -> np.ndarray:
    """OpenCV K (3, 3) of librealsense intrinsics, for frames downsampled by an integer factor (pixel centres
    kept aligned: u' = (u + 0.5) / d - 0.5)."""
    d = float(downsample)
    return np.array(
        [
            [intrinsics.fx / d, 0.0, (intrinsics.ppx + 0.5) / d - 0.5],
            [0.0, intrinsics.fy / d, (intrinsics.ppy + 0.5) / d - 0.5],
            [0.0, 0.0, 1.0],
        ],
        dtype=np.float32,
    )


def depth_to_millimetres(raw: np.ndarray, depth_scale: float) -> np.ndarray:
    """librealsense z16 (device units of `depth_scale` metres) -> uint16 millimetres, 0 = invalid."""
    if abs(depth_scale - 0.001) < 1e-9:
        return raw.astype(np.uint16, copy=True)
    mm = np.rint(raw.astype(np.float64) * (depth_scale * 1000.0))
    return np.clip(mm, 0, np.iinfo(np.uint16).max).astype(np.uint16)


def downsample_rgbd(colour: np.ndarray, depth: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """Colour by area averaging, depth by nearest sampling (averaging depth would invent surfaces at edges)."""
    if factor == 1:
        return colour, depth
    h, w = colour.shape[0] // factor, colour.shape[1] // factor
    colour = cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA)
    offset = factor // 2  # the sample nearest each block's centre
    return colour, np.ascontiguousarray(depth[offset::factor, offset::factor][:h, :w])


class RealSenseRGBDCamera(Camera):
    """See the module docstring. `read()` / `async_read()` / `read_latest()` return colour (H, W, 3) uint8 like any
    LeRobot camera; `read_rgbd()` / `async_read_rgbd()` return (colour, depth (H, W, 1) uint16 mm) of one frameset.
    """

    def __init__(self, config: RealSenseRGBDCameraConfig):
        super().__init__(config)
        self.config = config
        self.height, self.width = config.stored_size
        self._pipeline = None
        self._thread: Thread | None = None
        self._stop = Event()
        self._new_frame = Event()
        self._lock = Lock()
        # (colour, depth, colour frame number, host time of arrival) of the newest frameset
        self._latest: tuple[np.ndarray, np.ndarray, int, float] | None = None
        self._error: BaseException | None = None
        self.depth_scale: float | None = None  # metres per device depth unit, read from the device
        self.K: np.ndarray | None = None  # (3, 3) float32 of the returned frames
        self.serial_number: str = config.serial_number
        self.frames_dropped = 0  # framesets the reader replaced before anyone read them
        self.read_frame_number: int | None = None  # colour frame number of the frameset last returned

    def __str__(self) -> str:
        return f"{self.__class__.__name__}({self.serial_number or self.config.playback_file})"

    @property
    def is_connected(self) -> bool:
        return self._pipeline is not None

    @staticmethod
    def find_cameras() -> list[dict[str, Any]]:
        """Connected RealSense devices: name, serial (`id`), firmware, USB type."""
        rs = import_realsense()
        found = []
        for device in rs.context().query_devices():
            info = {"type": "RealSense", "name": device.get_info(rs.camera_info.name)}
            info["id"] = device.get_info(rs.camera_info.serial_number)
            for key, field in (("firmware_version", "firmware_version"), ("usb_type", "usb_type_descriptor")):
                if device.supports(getattr(rs.camera_info, field)):
                    info[key] = device.get_info(getattr(rs.camera_info, field))
            found.append(info)
        return found

    @check_if_already_connected
    def connect(self, warmup: bool = True) -> None:
        rs = import_realsense()
        cfg = self.config
        rs_config = rs.config()
        if cfg.playback_file:
            rs_config.enable_device_from_file(cfg.playback_file, repeat_playback=False)
        else:
            serials = [c["id"] for c in self.find_cameras()]
            if cfg.serial_number not in serials:
                raise ConnectionError(
                    f"No RealSense camera with serial {cfg.serial_number!r}; connected: {serials or 'none'}. "
                    "Check the USB 3 cable, or run `obsbench find-cameras`."
                )
            rs_config.enable_device(cfg.serial_number)
        rs_config.enable_stream(rs.stream.color, cfg.width, cfg.height, rs.format.rgb8, cfg.fps)
        rs_config.enable_stream(rs.stream.depth, cfg.width, cfg.height, rs.format.z16, cfg.fps)
        pipeline = rs.pipeline()
        try:
            profile = pipeline.start(rs_config)
        except RuntimeError as error:
            raise ConnectionError(
                f"{self}: could not start colour + depth at {cfg.width}x{cfg.height} @ {cfg.fps} fps ({error}). "
                "Pick a mode the camera supports (D415/D435: 640x480 or 1280x720 at 30 fps)."
            ) from error
        try:
            self._configure(rs, profile)
        except Exception:
            pipeline.stop()
            raise
        self._pipeline = pipeline
        self._stop.clear()
        self._thread = Thread(target=self._read_loop, args=(rs,), name=f"{self}_reader", daemon=True)
        self._thread.start()
        if warmup:
            deadline = time.perf_counter() + max(cfg.warmup_s, 0.0)
            self.async_read_rgbd(timeout_ms=5000)
            while time.perf_counter() < deadline:
                self.async_read_rgbd(timeout_ms=5000)
        logger.info(f"{self} connected: depth scale {self.depth_scale} m, K\n{self.K}")

    def _configure(self, rs, profile) -> None:
        cfg = self.config
        device = profile.get_device()
        self.serial_number = device.get_info(rs.camera_info.serial_number)
        depth_sensor = device.first_depth_sensor()
        self.depth_scale = float(depth_sensor.get_depth_scale())
        if cfg.playback_file:
            device.as_playback().set_real_time(cfg.playback_real_time)
        elif cfg.sync_mode != "off":
            if not depth_sensor.supports(rs.option.inter_cam_sync_mode):
                raise ConnectionError(f"{self} does not support hardware sync; set sync_mode: off.")
            depth_sensor.set_option(rs.option.inter_cam_sync_mode, SYNC_MODES[cfg.sync_mode])
        intrinsics = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        worst = max((abs(c) for c in intrinsics.coeffs), default=0.0)
        if worst > cfg.max_distortion:
            raise ValueError(
                f"{self}: the colour stream's lens distortion ({intrinsics.model}, coefficients "
                f"{[round(c, 4) for c in intrinsics.coeffs]}) exceeds max_distortion={cfg.max_distortion}; the "
                "dataset schema stores a pinhole K. Use a camera/mode with rectified colour, or raise "
                "max_distortion if you accept the error."
            )
        self.K = pinhole_K(intrinsics, cfg.downsample)
        filters = {"spatial": rs.spatial_filter, "temporal": rs.temporal_filter, "hole_filling": rs.hole_filling_filter}
        self._filters = [filters[name]() for name in cfg.depth_filters]
        self._align = rs.align(rs.stream.color)

    def _read_loop(self, rs) -> None:
        while not self._stop.is_set():
            try:
                ok, frames = self._pipeline.try_wait_for_frames(1000)
                if not ok:
                    continue
                frames = self._align.process(frames)
                colour_frame, depth_frame = frames.get_color_frame(), frames.get_depth_frame()
                if not colour_frame or not depth_frame:
                    continue
                for block in self._filters:  # on the aligned depth, so the filters also close alignment holes
                    depth_frame = block.process(depth_frame)
                colour = np.asanyarray(colour_frame.get_data())
                depth = depth_to_millimetres(np.asanyarray(depth_frame.get_data()), self.depth_scale)
                colour, depth = downsample_rgbd(colour, depth, self.config.downsample)
                item = (
                    np.ascontiguousarray(colour),
                    depth[..., None],
                    colour_frame.get_frame_number(),
                    time.perf_counter(),
                )
            except Exception as error:  # surfaced to the reader, never swallowed
                self._error = error
                self._new_frame.set()
                return
            with self._lock:
                if self._new_frame.is_set():
                    self.frames_dropped += 1
                self._latest = item
            self._new_frame.set()

    def _take(self, timeout_ms: float, wait: bool) -> tuple[np.ndarray, np.ndarray, int, float]:
        """The newest frameset; `wait`: block for an unread one and mark it read (a peek otherwise)."""
        if wait and not self._new_frame.wait(timeout_ms / 1000):
            raise TimeoutError(f"{self}: no new frame within {timeout_ms} ms.")
        if self._error is not None:
            raise RuntimeError(f"{self}: the reader thread failed: {self._error!r}") from self._error
        with self._lock:
            if self._latest is None:
                raise RuntimeError(f"{self} has not captured a frame yet.")
            if wait:
                self._new_frame.clear()
            return self._latest

    @check_if_not_connected
    def async_read_rgbd(self, timeout_ms: float = 200) -> tuple[np.ndarray, np.ndarray]:
        """The next unread (colour (H, W, 3) uint8, depth (H, W, 1) uint16 mm) pair of one frameset."""
        colour, depth, self.read_frame_number, _ = self._take(timeout_ms, wait=True)
        return colour, depth

    @check_if_not_connected
    def read_rgbd(self) -> tuple[np.ndarray, np.ndarray]:
        """Wait for a frameset newer than this call, then return its (colour, depth)."""
        self._new_frame.clear()
        return self.async_read_rgbd(timeout_ms=10_000)

    @check_if_not_connected
    def read_latest_rgbd(self, max_age_ms: int = 500) -> tuple[np.ndarray, np.ndarray]:
        """The newest (colour, depth) without waiting; refuses one older than `max_age_ms`."""
        colour, depth, _, arrived = self._take(0, wait=False)
        age_ms = (time.perf_counter() - arrived) * 1000
        if age_ms > max_age_ms:
            raise TimeoutError(f"{self}: the newest frameset is {age_ms:.0f} ms old (max_age_ms={max_age_ms}).")
        return colour, depth

    def read(self) -> np.ndarray:
        return self.read_rgbd()[0]

    def async_read(self, timeout_ms: float = 200) -> np.ndarray:
        return self.async_read_rgbd(timeout_ms)[0]

    def read_latest(self, max_age_ms: int = 500) -> np.ndarray:
        return self.read_latest_rgbd(max_age_ms)[0]

    @check_if_not_connected
    def disconnect(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
        self._pipeline.stop()
        self._pipeline = None
        self._thread = None
        logger.info(f"{self} disconnected.")
