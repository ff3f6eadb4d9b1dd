"""Configuration of two Koch follower arms with scene RGB-D cameras (`--robot.type=obsbench_bi_koch_follower`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.cameras import CameraConfig
from lerobot.robots.config import RobotConfig

from lerobot_obsbench.robots.koch.config_koch_arm import KochFollowerArmConfig


@RobotConfig.register_subclass("obsbench_bi_koch_follower")
@dataclass
class BiKochRGBDFollowerConfig(RobotConfig):
    """Left and right Koch followers composed as LeRobot composes its bimanual SO arms (`left_` / `right_` keys,
    calibration ids `<id>_left` / `<id>_right`), plus the scene cameras (e.g. two `obsbench_realsense_rgbd`).

    Example: `--robot.left_arm_config.port=/dev/ttyACM0 --robot.right_arm_config.port=/dev/ttyACM1`.
    """

    left_arm_config: KochFollowerArmConfig
    right_arm_config: KochFollowerArmConfig
    # Scene cameras, shared by both arms.
    cameras: dict[str, CameraConfig] = field(default_factory=dict)
    # Where `obsbench calibrate-cameras` saved each camera's cam2world (None: its default directory).
    extrinsics_dir: str | None = None
