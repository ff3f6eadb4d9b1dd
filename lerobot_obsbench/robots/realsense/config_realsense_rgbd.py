"""Configuration of the RealSense RGB-D camera (`--robot.cameras='{top: {type: obsbench_realsense_rgbd, ...}}'`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.cameras.configs import CameraConfig

from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.numeric import check_number

# librealsense post-processing filters the camera can apply to the depth before registering it, in the order given.
DEPTH_FILTERS = ("spatial", "temporal", "hole_filling")
# Hardware synchronisation between cameras: librealsense's `inter_cam_sync_mode` values (D400 series).
SYNC_MODES = {"off": 0, "master": 1, "slave": 2}
# Numeric fields -> their bounds (`numeric.check_number`).
NUMBER_FIELDS = {
    "fps": {"whole": True, "minimum": 1},
    "width": {"whole": True, "minimum": 1},
    "height": {"whole": True, "minimum": 1},
    "downsample": {"whole": True, "minimum": 1},
    "max_distortion": {"minimum": 0},
    "warmup_s": {"minimum": 0},
}


@CameraConfig.register_subclass("obsbench_realsense_rgbd")
@dataclass
class RealSenseRGBDCameraConfig(CameraConfig):
    """An Intel RealSense (D400 series) as one RGB-D sensor: colour and depth from one pipeline at the same fps,
    depth registered into the colour camera, both read from the same frameset, depth in uint16 millimetres.

    Example: `{type: obsbench_realsense_rgbd, serial_number: "128422271347", width: 640, height: 480, fps: 30}`.
    `obsbench find-cameras` lists the serials of connected cameras.
    """

    # The camera's serial number (`obsbench find-cameras`); may stay empty when `playback_file` is set.
    serial_number: str = ""
    # Colour stream (depth is captured at the same size and fps, then registered into the colour camera).
    fps: int | None = 30
    width: int | None = 640
    height: int | None = 480
    # Store colour (area) and registered depth at width/downsample x height/downsample, K scaled to match: policies
    # use 128-224 px, and a 640x480 uint16 depth map is 600 kB a frame in memory until the episode is saved.
    downsample: int = 2
    # librealsense depth filters to apply, any of DEPTH_FILTERS (e.g. ["spatial", "temporal"]).
    depth_filters: list[str] = field(default_factory=list)
    # Hardware sync between several cameras wired with a sync cable: "off", "master" (one camera) or "slave".
    sync_mode: str = "off"
    # Refuse a colour stream whose lens-distortion coefficients exceed this (the schema's K is a pinhole model).
    max_distortion: float = 0.01
    # Play a recorded .bag file instead of a live camera (testing, replaying a session).
    playback_file: str | None = None
    # Play the file at its recorded rate (True) or as fast as frames are read (False: every frameset once).
    playback_real_time: bool = True
    # Seconds of frames to read and drop after connecting (auto-exposure settles).
    warmup_s: float = 1.0

    def __post_init__(self) -> None:
        if not self.serial_number and not self.playback_file:
            raise ConfigError(
                "obsbench_realsense_rgbd: set serial_number (run `obsbench find-cameras` to list the connected "
                "cameras' serials) or playback_file (a recorded .bag)."
            )
        if None in (self.fps, self.width, self.height):
            raise ConfigError("obsbench_realsense_rgbd: fps, width and height must all be set (e.g. 30, 640, 480).")
        for name, bounds in NUMBER_FIELDS.items():
            check_number(f"obsbench_realsense_rgbd: {name}", getattr(self, name), **bounds)
        if self.width % self.downsample or self.height % self.downsample:
            raise ConfigError(
                f"obsbench_realsense_rgbd: downsample={self.downsample} must be a positive divisor of width "
                f"{self.width} and height {self.height}."
            )
        unknown = [f for f in self.depth_filters if f not in DEPTH_FILTERS]
        if unknown:
            raise ConfigError(f"obsbench_realsense_rgbd: unknown depth_filters {unknown}; choose from {DEPTH_FILTERS}.")
        if self.sync_mode not in SYNC_MODES:
            raise ConfigError(
                f"obsbench_realsense_rgbd: sync_mode {self.sync_mode!r}; choose one of {list(SYNC_MODES)}."
            )

    @property
    def stored_size(self) -> tuple[int, int]:
        """(height, width) of the frames the camera returns."""
        return self.height // self.downsample, self.width // self.downsample
