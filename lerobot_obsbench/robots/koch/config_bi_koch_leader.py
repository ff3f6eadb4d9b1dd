"""Configuration of two Koch leader arms (`--teleop.type=obsbench_bi_koch_leader`)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.teleoperators.config import TeleoperatorConfig

from lerobot_obsbench.robots.koch.config_koch_arm import KochLeaderArmConfig


@TeleoperatorConfig.register_subclass("obsbench_bi_koch_leader")
@dataclass
class BiKochLeaderConfig(TeleoperatorConfig):
    """Left and right Koch leaders composed as LeRobot composes `bi_so_leader` (`left_` / `right_` keys,
    calibration ids `<id>_left` / `<id>_right`): drives `obsbench_bi_koch_follower`."""

    left_arm_config: KochLeaderArmConfig
    right_arm_config: KochLeaderArmConfig
