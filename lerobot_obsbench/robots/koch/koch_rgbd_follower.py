"""A Koch follower arm with scene RGB-D cameras: LeRobot's `KochFollower`, whose observation carries depth, K and
cam2world per RGB-D camera (see `lerobot_obsbench.robots.scene_cameras`)."""

from __future__ import annotations

from functools import cached_property

from lerobot.robots.koch_follower import KochFollower
from lerobot.utils.decorators import check_if_not_connected

from lerobot_obsbench.robots.checks import check_action_keys
from lerobot_obsbench.robots.koch.config_koch_rgbd_follower import KochRGBDFollowerConfig
from lerobot_obsbench.robots.scene_cameras import SceneCameras, camera_features


class KochRGBDFollower(KochFollower):
    config_class = KochRGBDFollowerConfig
    name = "obsbench_koch_follower"

    def __init__(self, config: KochRGBDFollowerConfig):
        super().__init__(config)
        self.scene = SceneCameras(config.cameras, config.extrinsics_dir, cameras=self.cameras)

    @property
    def _cameras_ft(self) -> dict[str, tuple]:
        return camera_features(self.config.cameras)

    @cached_property
    def observation_features(self) -> dict[str, type | tuple]:
        return {**self._motors_ft, **self._cameras_ft}

    @check_if_not_connected
    def get_observation(self) -> dict:
        joints = self.bus.sync_read("Present_Position")
        return {**{f"{motor}.pos": value for motor, value in joints.items()}, **self.scene.read()}

    @check_if_not_connected
    def send_action(self, action: dict) -> dict:
        check_action_keys(action, self.action_features, self)
        return super().send_action(action)
