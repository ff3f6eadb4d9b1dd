"""Intel RealSense as one RGB-D sensor for LeRobot robots (docs/real-robot.md).

LeRobot's `intelrealsense` camera reads colour and depth without registering them and exposes no intrinsics. Here
the colour and depth sensors stream at the same fps into one librealsense syncer (librealsense's pipeline would drop
a recording's first frameset); a background thread takes each frameset, filters the depth (optional), registers it
into the colour camera (`geometry.register_depth`: z along the colour camera's axis at each colour pixel centre)
through the device's own depth scale, intrinsics and depth -> colour extrinsics, stores it as uint16 millimetres,
and keeps colour and depth of that frameset together, so a read returns a matching pair.
K is the colour stream's pinhole intrinsics (scaled with `downsample`).

Why not librealsense's `rs.align`: it writes each depth pixel's own z (the depth camera's) into the colour pixels it
covers, which is the colour camera's z only when the depth -> colour extrinsic is a pure x-baseline. With a
D400's real extrinsic (a fraction of a degree of rotation, millimetres of offset) it is off by millimetres on a
slanted surface, and its nearest-pixel splat stays off even with its z corrected for the rotation; the
registration here is within 1 mm (docs/real-robot.md, asserted by tests/robots/test_realsense.py).

Needs `pyrealsense2` (`pip install 'lerobot_policy_obsbench[realsense]'`; on Linux also Debian's `libusb-1.0-0`).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from threading import Condition, Event, Thread
from typing import Any

import cv2
import numpy as np
import torch
from lerobot.cameras.camera import Camera
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_obsbench.errors import ConfigError, MissingDependencyError, ObsBenchError
from lerobot_obsbench.geometry import register_depth
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
        raise MissingDependencyError(f"{INSTALL_HINT} ({error})") from error
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


def metres_to_millimetres(z: np.ndarray) -> np.ndarray:
    """Depth in metres -> the schema's uint16 millimetres (0 stays 0: unknown)."""
    return np.clip(np.rint(z * 1000.0), 0, np.iinfo(np.uint16).max).astype(np.uint16)


def downsample_colour(colour: np.ndarray, factor: int) -> np.ndarray:
    """Colour by area averaging: output pixel i covers input pixels factor*i .. factor*i + factor - 1, so its
    centre is at (i + 0.5) * factor - 0.5 in input pixels, as `pinhole_K` scales K."""
    if factor == 1:
        return colour
    h, w = colour.shape[0] // factor, colour.shape[1] // factor
    return cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA)


def subsampled_K(K: np.ndarray, factor: int, offset: int) -> np.ndarray:
    """K of an image keeping every `factor`-th pixel from `offset` (new pixel i = old pixel factor*i + offset): exact,
    since kept pixels are not resampled."""
    out = np.array(K, dtype=np.float64)
    out[:2, :2] /= factor
    out[:2, 2] = (out[:2, 2] - offset) / factor
    return out


def extrinsic_matrix(extrinsics) -> np.ndarray:
    """4 x 4 rigid transform of librealsense extrinsics (its rotation is stored column-major)."""
    matrix = np.eye(4)
    matrix[:3, :3] = np.asarray(extrinsics.rotation, dtype=np.float64).reshape(3, 3).T
    matrix[:3, 3] = extrinsics.translation
    return matrix


# Fixed-point refinement steps of the registration: the splat starts within half a pixel's footprint, so one step
# converges on the surfaces a table scene holds (docs/real-robot.md)
REGISTRATION_STEPS = 1


class CameraNotFoundError(ObsBenchError, ConnectionError):
    """The camera named by serial number, or the recording named by path, is not there."""


class CameraStartError(ObsBenchError, ConnectionError):
    """The camera is there but would not stream as configured (resolution, rate, hardware sync)."""


class CameraTimeoutError(ObsBenchError, TimeoutError):
    """No frame, or no fresh enough frame, arrived in time."""


class CameraReadError(ObsBenchError, RuntimeError):
    """A frame was asked for before the camera delivered one, or after its reader thread failed."""


class RecordingEndedError(ObsBenchError, EOFError):
    """A played-back recording has ended and every frameset it held was returned."""


class RealSenseRGBDCamera(Camera):
    """See the module docstring. `read()` / `async_read()` / `read_latest()` return colour (H, W, 3) uint8 like any
    LeRobot camera; `read_rgbd()` / `async_read_rgbd()` return (colour, depth (H, W, 1) uint16 mm) of one frameset.
    """

    def __init__(self, config: RealSenseRGBDCameraConfig):
        super().__init__(config)
        self.config = config
        self.height, self.width = config.stored_size
        self._sensors: list | None = None  # the started librealsense sensors (colour, depth)
        self._syncer = None
        self._playback = None  # the device of a played-back recording
        self._thread: Thread | None = None
        self._flush_thread: Thread | None = None  # closes a played-back recording's sensors at its end
        self._stop = Event()
        self._consumed = Event()  # lossless playback: the newest frameset was returned
        # guards what the reader thread hands over; notified when a frameset arrives, the reader fails or a
        # recording ends
        self._changed = Condition()
        # (colour, depth, colour frame number, host time of arrival) of the newest frameset
        self._latest: tuple[np.ndarray, np.ndarray, int, float] | None = None
        self._unread = False  # the newest frameset has not been returned yet
        self._ended = False  # the played-back recording has ended (no frameset will follow the newest)
        self._error: BaseException | None = None
        self.framesets_received = 0  # framesets the reader registered since connecting
        self.depth_scale: float | None = None  # metres per device depth unit, read from the device
        self.K: np.ndarray | None = None  # (3, 3) float32 of the returned frames
        self.serial_number: str = config.serial_number
        self.frames_dropped = 0  # framesets the reader replaced before anyone read them
        self.read_frame_number: int | None = None  # colour frame number of the frameset last returned

    def __str__(self) -> str:
        return f"{self.__class__.__name__}({self.serial_number or self.config.playback_file})"

    @property
    def is_connected(self) -> bool:
        return self._sensors is not None

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
        if cfg.playback_file:
            if not Path(cfg.playback_file).expanduser().is_file():
                raise CameraNotFoundError(
                    f"RealSense recording {cfg.playback_file} not found (record one with the RealSense Viewer or "
                    "rs-record; .bag)"
                )
            device = rs.context().load_device(str(Path(cfg.playback_file).expanduser()))
            playback = device.as_playback()
            playback.set_real_time(cfg.playback_real_time)
            playback.pause()  # until both streams feed the syncer, so the first frameset is paired like the rest
        else:
            serials = [c["id"] for c in self.find_cameras()]
            if cfg.serial_number not in serials:
                raise CameraNotFoundError(
                    f"No RealSense camera with serial {cfg.serial_number!r}; connected: {serials or 'none'}. "
                    "Check the USB 3 cable, or run `obsbench find-cameras`."
                )
            device = next(
                d for d in rs.context().query_devices() if d.get_info(rs.camera_info.serial_number) == cfg.serial_number
            )
        colour = self._stream_profile(rs, device, rs.stream.color, rs.format.rgb8)
        depth = self._stream_profile(rs, device, rs.stream.depth, rs.format.z16)
        self._configure(rs, device, colour, depth)
        # each sensor streams into one syncer, which pairs colour and depth of a frameset
        self._syncer = rs.syncer()
        by_sensor: dict[str, tuple[Any, list]] = {}  # one sensor may carry both (the D405's colour is its depth's)
        for sensor, stream in (colour, depth):
            by_sensor.setdefault(sensor.get_info(rs.camera_info.name), (sensor, []))[1].append(stream)
        self._playback = playback if cfg.playback_file else None
        self._sensors = self._open_and_start(by_sensor)
        self._consumed.set()
        self._stop.clear()
        self._latest, self._unread, self._ended, self._error, self.framesets_received = None, False, False, None, 0
        if self._playback is not None:
            # before the reader starts: until then the player reports "stopped", which the reader takes for the end
            self._playback.resume()
        self._thread = Thread(target=self._read_loop, name=f"{self}_reader", daemon=True)
        self._thread.start()
        if warmup:
            deadline = time.perf_counter() + max(cfg.warmup_s, 0.0)
            self.async_read_rgbd(timeout_ms=5000)
            while time.perf_counter() < deadline:
                self.async_read_rgbd(timeout_ms=5000)
        logger.info(f"{self} connected: depth scale {self.depth_scale} m, K\n{self.K}")

    def _open_and_start(self, by_sensor: dict[str, tuple[Any, list]]) -> list:
        """Open every sensor, then start them into the syncer. All opened first: a recording's player reads its
        first item when the first sensor starts, from the streams opened by then, so a stream opened later loses
        the frames read before it (a two-frameset recording: all its depth)."""
        opened, started = [], []
        try:
            for sensor, streams in by_sensor.values():
                sensor.open(streams if len(streams) > 1 else streams[0])
                opened.append(sensor)
            for sensor in opened:
                self._start_sensor(sensor)
                started.append(sensor)
        except RuntimeError as error:
            self._stop_sensors(started, opened)
            raise CameraStartError(f"{self}: could not start colour + depth ({error}).") from error
        return opened

    def _start_sensor(self, sensor) -> None:
        sensor.start(self._syncer)

    def _stream_profile(self, rs, device, kind, fmt) -> tuple[Any, Any]:
        """(sensor, stream profile) of `kind` in the configured size, fps and format; ConnectionError naming the
        modes the camera offers otherwise."""
        cfg = self.config
        offered = []
        for sensor in device.query_sensors():
            for stream in sensor.get_stream_profiles():
                if stream.stream_type() != kind or stream.format() != fmt:
                    continue
                video = stream.as_video_stream_profile()
                if (video.width(), video.height(), stream.fps()) == (cfg.width, cfg.height, cfg.fps):
                    return sensor, stream
                offered.append(f"{video.width()}x{video.height()}@{stream.fps()}")
        raise CameraStartError(
            f"{self}: no {kind} stream at {cfg.width}x{cfg.height} @ {cfg.fps} fps in {fmt}; the camera offers "
            f"{', '.join(sorted(set(offered))) or 'none'}. Pick one of those (D415/D435: 640x480 or 1280x720 at "
            "30 fps)."
        )

    def _configure(self, rs, device, colour, depth) -> None:
        cfg = self.config
        self.serial_number = device.get_info(rs.camera_info.serial_number)
        depth_sensor = depth[0].as_depth_sensor()
        self.depth_scale = float(depth_sensor.get_depth_scale())
        if not cfg.playback_file and cfg.sync_mode != "off":
            if not depth_sensor.supports(rs.option.inter_cam_sync_mode):
                raise CameraStartError(f"{self} does not support hardware sync; set sync_mode: off.")
            depth_sensor.set_option(rs.option.inter_cam_sync_mode, SYNC_MODES[cfg.sync_mode])
        colour_profile, depth_profile = colour[1].as_video_stream_profile(), depth[1].as_video_stream_profile()
        intrinsics = colour_profile.get_intrinsics()
        worst = max((abs(c) for c in intrinsics.coeffs), default=0.0)
        if worst > cfg.max_distortion:
            raise ConfigError(
                f"{self}: the colour stream's lens distortion ({intrinsics.model}, coefficients "
                f"{[round(c, 4) for c in intrinsics.coeffs]}) exceeds max_distortion={cfg.max_distortion}; the "
                "dataset schema stores a pinhole K. Use a camera/mode with rectified colour, or raise "
                "max_distortion if you accept the error."
            )
        self.K = pinhole_K(intrinsics, cfg.downsample)
        filters = {"spatial": rs.spatial_filter, "temporal": rs.temporal_filter, "hole_filling": rs.hole_filling_filter}
        self._filters = [filters[name]() for name in cfg.depth_filters]
        # registration: depth keeps every `downsample`-th pixel (the output's resolution; its K follows exactly),
        # is unprojected, moved into the colour camera and resampled at the colour output's pixel centres
        self.depth_to_colour = extrinsic_matrix(depth_profile.get_extrinsics_to(colour_profile))
        self._depth_offset = cfg.downsample // 2
        self.K_depth = subsampled_K(pinhole_K(depth_profile.get_intrinsics()), cfg.downsample, self._depth_offset)
        as_batch = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)[None]
        self._registration = (as_batch(self.K_depth), as_batch(self.depth_to_colour), as_batch(self.K))

    def _syncer_output(self):
        """What the syncer gives, until the camera stops or a played-back recording has ended: the player stops at
        the end of its file with frames still queued in its sensors; closing them delivers those (librealsense
        flushes a sensor's queue when it closes), so the end comes after the last frameset, whatever the load."""
        flushed: Event | None = None  # set once the stopped player's sensors delivered what they held
        while not self._stop.is_set():
            ok, frames = self._syncer.try_wait_for_frames(100)
            if ok:
                yield frames
            elif flushed is None:
                if (
                    self._playback is not None
                    and self._playback.current_status() == import_realsense().playback_status.stopped
                ):
                    flushed = Event()
                    self._flush_thread = Thread(
                        target=self._close_played_sensors, args=(flushed,), name=f"{self}_flush", daemon=True
                    )
                    self._flush_thread.start()
            elif flushed.is_set():
                frames = self._syncer.poll_for_frames()
                if not frames:
                    return
                yield frames

    def _close_played_sensors(self, done: Event) -> None:
        # in its own thread: the player's sensors hand their last frames to the syncer, which the reader drains
        for sensor in self._sensors:
            sensor.close()
        done.set()

    def _framesets(self):
        """(colour frame, depth frame) pairs as the syncer gives them. At start it hands out a stream's first frame
        alone (nothing to pair it with yet): two such frames with one timestamp are one frameset."""
        alone = {}
        for frames in self._syncer_output():
            colour, depth = frames.get_color_frame(), frames.get_depth_frame()
            if colour and depth:
                yield colour, depth
                continue
            single = colour or depth
            if not single:
                continue
            single.keep()
            alone["colour" if colour else "depth"] = single
            if len(alone) == 2 and alone["colour"].get_timestamp() == alone["depth"].get_timestamp():
                yield alone.pop("colour"), alone.pop("depth")

    def _read_loop(self) -> None:
        # one intra-op thread for this reader's registration (OpenMP's setting is per thread: the control loop and
        # the policy keep theirs): each camera's reader taking every core oversubscribes the CPU
        # (benchmarks/bench_recording.py measures it)
        torch.set_num_threads(1)
        try:
            for colour_frame, depth_frame in self._framesets():
                for block in self._filters:  # on the camera's own depth, as librealsense designs them
                    depth_frame = block.process(depth_frame)
                colour = downsample_colour(np.asanyarray(colour_frame.get_data()), self.config.downsample)
                depth = self.register(np.asanyarray(depth_frame.get_data()))
                item = (
                    np.ascontiguousarray(colour),
                    depth[..., None],
                    colour_frame.get_frame_number(),
                    time.perf_counter(),
                )
                if self.lossless:  # replaying as fast as frames are read: the previous one first
                    while not self._consumed.wait(0.1):
                        if self._stop.is_set():
                            return
                    self._consumed.clear()
                with self._changed:
                    if self._unread:
                        self.frames_dropped += 1
                    self._latest, self._unread = item, True
                    self.framesets_received += 1
                    self._changed.notify_all()
            with self._changed:
                self._ended = not self._stop.is_set()
                self._changed.notify_all()
        except Exception as error:  # surfaced to the reader, never swallowed
            with self._changed:
                self._error = error
                self._changed.notify_all()

    @property
    def lossless(self) -> bool:
        """A recording played as fast as it is read: every frameset is returned once, none dropped."""
        return bool(self.config.playback_file) and not self.config.playback_real_time

    def register(self, raw: np.ndarray) -> np.ndarray:
        """The colour camera's depth (H, W) uint16 mm of a raw z16 depth image (0 = unknown: no return, an
        occlusion edge, or outside the depth camera's view)."""
        step, offset = self.config.downsample, self._depth_offset
        metres = torch.from_numpy(raw[offset::step, offset::step].astype(np.float32) * np.float32(self.depth_scale))
        K_depth, depth_to_colour, K_colour = self._registration
        z = register_depth(
            metres[None], K_depth, depth_to_colour, K_colour, (self.height, self.width), REGISTRATION_STEPS
        )
        return metres_to_millimetres(z[0].numpy())

    def _take(self, timeout_ms: float, wait: bool) -> tuple[np.ndarray, np.ndarray, int, float]:
        """The newest frameset; `wait`: block for an unread one and mark it read (a peek otherwise)."""
        with self._changed:
            news = lambda: self._unread or self._ended or self._error is not None
            if wait and not self._changed.wait_for(news, timeout_ms / 1000):
                raise CameraTimeoutError(f"{self}: no new frame within {timeout_ms} ms.")
            if self._error is not None:
                raise CameraReadError(f"{self}: the reader thread failed: {self._error!r}") from self._error
            if wait and not self._unread:
                raise RecordingEndedError(
                    f"{self}: the recording {self.config.playback_file} has ended; all {self.framesets_received} "
                    "of its framesets were returned."
                )
            if self._latest is None:
                raise CameraReadError(f"{self} has not captured a frame yet.")
            if wait:
                self._mark_read()
            return self._latest

    def _mark_read(self) -> None:
        self._unread = False
        self._consumed.set()

    @check_if_not_connected
    def async_read_rgbd(self, timeout_ms: float = 200) -> tuple[np.ndarray, np.ndarray]:
        """The next unread (colour (H, W, 3) uint8, depth (H, W, 1) uint16 mm) pair of one frameset."""
        colour, depth, self.read_frame_number, _ = self._take(timeout_ms, wait=True)
        return colour, depth

    @check_if_not_connected
    def read_rgbd(self) -> tuple[np.ndarray, np.ndarray]:
        """Wait for a frameset newer than this call, then return its (colour, depth)."""
        with self._changed:
            self._mark_read()
        return self.async_read_rgbd(timeout_ms=10_000)

    @check_if_not_connected
    def read_latest_rgbd(self, max_age_ms: int = 500) -> tuple[np.ndarray, np.ndarray]:
        """The newest (colour, depth) without waiting; refuses one older than `max_age_ms`."""
        colour, depth, _, arrived = self._take(0, wait=False)
        age_ms = (time.perf_counter() - arrived) * 1000
        if age_ms > max_age_ms:
            raise CameraTimeoutError(f"{self}: the newest frameset is {age_ms:.0f} ms old (max_age_ms={max_age_ms}).")
        return colour, depth

    def read(self) -> np.ndarray:
        return self.read_rgbd()[0]

    def async_read(self, timeout_ms: float = 200) -> np.ndarray:
        return self.async_read_rgbd(timeout_ms)[0]

    def read_latest(self, max_age_ms: int = 500) -> np.ndarray:
        return self.read_latest_rgbd(max_age_ms)[0]

    @staticmethod
    def _stop_sensors(started, opened=None) -> None:
        for sensor in started:
            sensor.stop()
        for sensor in started if opened is None else opened:
            sensor.close()

    @check_if_not_connected
    def disconnect(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()  # it checks the stop at least every 0.1 s
        if self._playback is not None:  # a recording played as fast as it is read waits for its reader: release it
            self._playback.pause()
            while self._syncer.poll_for_frames():
                pass
            # the recording's end closes its sensors, flushing their frames into the syncer: drained until done
            while self._flush_thread is not None and self._flush_thread.is_alive():
                self._syncer.poll_for_frames()
                self._flush_thread.join(0.05)
        self._stop_sensors(self._sensors, [] if self._flush_thread is not None else None)
        self._sensors = None
        self._thread = self._flush_thread = None
        logger.info(f"{self} disconnected.")
