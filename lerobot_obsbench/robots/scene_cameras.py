"""A robot's cameras as the dataset schema needs them: colour, and for RGB-D cameras aligned depth, K and the
calibrated cam2world, read together every control step.

Robot observation keys (LeRobot style, no prefix): `<cam>` colour (H, W, 3) uint8; for RGB-D cameras also
`<cam>.depth` (H, W, 1) uint16 mm, `<cam>.intrinsics` (3, 3) float32, `<cam>.cam2world` (4, 4) float32. Colour-only
cameras (e.g. a wrist camera through LeRobot's `opencv` type) give `<cam>` alone.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from lerobot.cameras import Camera, CameraConfig
from lerobot.cameras.utils import make_cameras_from_configs

from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.robots.extrinsics import load_extrinsics

DEPTH_SUFFIX = ".depth"
INTRINSICS_SUFFIX = ".intrinsics"
CAM2WORLD_SUFFIX = ".cam2world"


def is_rgbd(config: CameraConfig) -> bool:
    return hasattr(config, "stored_size")


def camera_features(configs: dict[str, CameraConfig]) -> dict[str, tuple]:
    """LeRobot `observation_features` entries of the cameras."""
    features: dict[str, tuple] = {}
    for name, cfg in configs.items():
        if is_rgbd(cfg):
            h, w = cfg.stored_size
            features[name] = (h, w, 3)
            features[name + DEPTH_SUFFIX] = (h, w, 1)
            features[name + INTRINSICS_SUFFIX] = (3, 3)
            features[name + CAM2WORLD_SUFFIX] = (4, 4)
        elif getattr(cfg, "use_depth", False):
            # LeRobot 0.6's own depth (`<cam>_depth`: unregistered, no K or pose) beside the schema's would be two
            # sources of depth for one camera
            raise ConfigError(
                f"camera {name!r}: {cfg.type} with use_depth=true records LeRobot's own unregistered depth; in the "
                "plugin's robots use type obsbench_realsense_rgbd (depth registered into colour, K and cam2world), or "
                "record with LeRobot's koch_follower and `obsbench attach-calibration` afterwards"
            )
        else:
            features[name] = (cfg.height, cfg.width, 3)
    return features


class SceneCameras:
    """The cameras of one robot; RGB-D ones read in parallel, each returning colour and depth of one frameset."""

    def __init__(
        self,
        configs: dict[str, CameraConfig],
        extrinsics_dir: Path | str | None = None,
        cameras: dict[str, Camera] | None = None,
    ):
        self.configs = configs
        self.extrinsics_dir = extrinsics_dir
        # built here, or already by the LeRobot robot class this extends
        self.cameras = make_cameras_from_configs(configs) if cameras is None else cameras
        self._cam2world: dict[str, np.ndarray] = {}
        self._pool = ThreadPoolExecutor(max_workers=max(len(configs), 1), thread_name_prefix="scene_cameras")

    @property
    def is_connected(self) -> bool:
        return all(cam.is_connected for cam in self.cameras.values())

    def connect(self) -> None:
        for cam in self.cameras.values():
            cam.connect()

    def load_extrinsics(self) -> None:
        """Each RGB-D camera's cam2world from `obsbench calibrate-cameras` (by serial, known once connected);
        a missing file is an error naming the command."""
        for name, cam in self.cameras.items():
            if is_rgbd(self.configs[name]) and name not in self._cam2world:
                calibration = load_extrinsics(cam.serial_number, self.extrinsics_dir)
                self._cam2world[name] = calibration.matrix().astype(np.float32)

    def _read_one(self, name: str) -> dict[str, np.ndarray]:
        cam = self.cameras[name]
        if not is_rgbd(self.configs[name]):
            return {name: cam.async_read()}
        # a live camera that sends nothing for a second has stalled; a recording played as fast as it is read
        # (`lossless`) always sends its next frameset, however slowly this machine registers it
        colour, depth = cam.async_read_rgbd(timeout_ms=60_000 if getattr(cam, "lossless", False) else 1000)
        return {
            name: colour,
            name + DEPTH_SUFFIX: depth,
            name + INTRINSICS_SUFFIX: cam.K,
            name + CAM2WORLD_SUFFIX: self._cam2world[name],
        }

    def read(self) -> dict[str, np.ndarray]:
        """One new frame (set) of every camera."""
        self.load_extrinsics()
        out: dict[str, np.ndarray] = {}
        for part in self._pool.map(self._read_one, self.cameras):
            out.update(part)
        return out

    def disconnect(self) -> None:
        for cam in self.cameras.values():
            if cam.is_connected:
                cam.disconnect()
