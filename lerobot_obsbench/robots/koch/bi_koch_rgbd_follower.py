"""Two Koch follower arms with scene RGB-D cameras (the paper's bimanual set-up), composed from LeRobot's own
`KochFollower` the way LeRobot composes `bi_so_follower`."""

from __future__ import annotations

from functools import cached_property

from lerobot.robots.koch_follower import KochFollower, KochFollowerConfig
from lerobot.robots.robot import Robot
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_obsbench.robots.checks import check_action_keys
from lerobot_obsbench.robots.koch.arm_pair import ArmPair, make_arms, prefixed
from lerobot_obsbench.robots.koch.config_bi_koch_rgbd_follower import BiKochRGBDFollowerConfig
from lerobot_obsbench.robots.scene_cameras import SceneCameras, camera_features


class BiKochRGBDFollower(ArmPair, Robot):
    config_class = BiKochRGBDFollowerConfig
    name = "obsbench_bi_koch_follower"

    def __init__(self, config: BiKochRGBDFollowerConfig):
        super().__init__(config)
        self.config = config
        self.arms = make_arms(config, KochFollower, KochFollowerConfig)
        self.scene = SceneCameras(config.cameras, config.extrinsics_dir)
        self.cameras = self.scene.cameras  # LeRobot's tools look for `robot.cameras`

    @property
    def _motors_ft(self) -> dict[str, type]:
        return prefixed({side: arm._motors_ft for side, arm in self.arms.items()})

    @cached_property
    def observation_features(self) -> dict[str, type | tuple]:
        return {**self._motors_ft, **camera_features(self.config.cameras)}

    @cached_property
    def action_features(self) -> dict[str, type]:
        return self._motors_ft

    @property
    def is_connected(self) -> bool:
        return all(arm.is_connected for arm in self.arms.values()) and self.scene.is_connected

    @check_if_already_connected
    def connect(self, calibrate: bool = True) -> None:
        for arm in self.arms.values():
            arm.connect(calibrate)
        self.scene.connect()

    @check_if_not_connected
    def get_observation(self) -> dict:
        joints = {
            side: {f"{motor}.pos": value for motor, value in arm.bus.sync_read("Present_Position").items()}
            for side, arm in self.arms.items()
        }
        return {**prefixed(joints), **self.scene.read()}

    @check_if_not_connected
    def send_action(self, action: dict) -> dict:
        check_action_keys(action, self.action_features, self)
        sent = {}
        for side, arm in self.arms.items():
            mine = {key.removeprefix(f"{side}_"): value for key, value in action.items() if key.startswith(f"{side}_")}
            sent[side] = arm.send_action(mine)
        return prefixed(sent)

    @check_if_not_connected
    def disconnect(self) -> None:
        for arm in self.arms.values():
            arm.disconnect()
        self.scene.disconnect()
