"""Configuration of a Koch follower arm with scene RGB-D cameras (`--robot.type=obsbench_koch_follower`)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.robots.config import RobotConfig
from lerobot.robots.koch_follower import KochFollowerConfig


@RobotConfig.register_subclass("obsbench_koch_follower")
@dataclass
class KochRGBDFollowerConfig(KochFollowerConfig):
    """LeRobot's `koch_follower` (port, max_relative_target, use_degrees, cameras) whose RGB-D cameras
    (`obsbench_realsense_rgbd`) give depth, K and cam2world with every colour frame, in the dataset schema."""

    # Where `obsbench calibrate-cameras` saved each camera's cam2world (None: its default directory).
    extrinsics_dir: str | None = None
