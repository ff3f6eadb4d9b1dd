"""Two Koch follower arms with scene RGB-D cameras (the paper's bimanual set-up), composed from LeRobot's own
`KochFollower` the way LeRobot composes `bi_so_follower`."""

from __future__ import annotations

from dataclasses import asdict
from functools import cached_property

from lerobot.robots.koch_follower import KochFollower, KochFollowerConfig
from lerobot.robots.robot import Robot
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_obsbench.robots.checks import check_action_keys
from lerobot_obsbench.robots.koch.config_bi_koch_rgbd_follower import BiKochRGBDFollowerConfig
from lerobot_obsbench.robots.scene_cameras import SceneCameras, camera_features

SIDES = ("left", "right")


class BiKochRGBDFollower(Robot):
    config_class = BiKochRGBDFollowerConfig
    name = "obsbench_bi_koch_follower"

    def __init__(self, config: BiKochRGBDFollowerConfig):
        super().__init__(config)
        self.config = config
        self.arms = {
            side: KochFollower(
                KochFollowerConfig(
                    **asdict(getattr(config, f"{side}_arm_config")),
                    id=f"{config.id}_{side}" if config.id else None,
                    calibration_dir=config.calibration_dir,
                )
            )
            for side in SIDES
        }
        self.scene = SceneCameras(config.cameras, config.extrinsics_dir)
        self.cameras = self.scene.cameras  # LeRobot's tools look for `robot.cameras`

    @property
    def _motors_ft(self) -> dict[str, type]:
        return {f"{side}_{key}": kind for side, arm in self.arms.items() for key, kind in arm._motors_ft.items()}

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

    @property
    def is_calibrated(self) -> bool:
        return all(arm.is_calibrated for arm in self.arms.values())

    def calibrate(self) -> None:
        for arm in self.arms.values():
            arm.calibrate()

    def configure(self) -> None:
        for arm in self.arms.values():
            arm.configure()

    def setup_motors(self) -> None:
        for arm in self.arms.values():
            arm.setup_motors()

    @check_if_not_connected
    def get_observation(self) -> dict:
        obs = {}
        for side, arm in self.arms.items():
            joints = arm.bus.sync_read("Present_Position")
            obs.update({f"{side}_{motor}.pos": value for motor, value in joints.items()})
        return {**obs, **self.scene.read()}

    @check_if_not_connected
    def send_action(self, action: dict) -> dict:
        check_action_keys(action, self.action_features, self)
        sent = {}
        for side, arm in self.arms.items():
            mine = {key.removeprefix(f"{side}_"): value for key, value in action.items() if key.startswith(f"{side}_")}
            sent.update({f"{side}_{key}": value for key, value in arm.send_action(mine).items()})
        return sent

    @check_if_not_connected
    def disconnect(self) -> None:
        for arm in self.arms.values():
            arm.disconnect()
        self.scene.disconnect()
