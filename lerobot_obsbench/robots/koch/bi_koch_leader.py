"""Two Koch leader arms, composed from LeRobot's own `KochLeader` the way LeRobot composes `bi_so_leader`."""

from __future__ import annotations

from dataclasses import asdict
from functools import cached_property

from lerobot.teleoperators.koch_leader import KochLeader, KochLeaderConfig
from lerobot.teleoperators.teleoperator import Teleoperator
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_obsbench.robots.koch.config_bi_koch_leader import BiKochLeaderConfig

SIDES = ("left", "right")


class BiKochLeader(Teleoperator):
    config_class = BiKochLeaderConfig
    name = "obsbench_bi_koch_leader"

    def __init__(self, config: BiKochLeaderConfig):
        super().__init__(config)
        self.config = config
        self.arms = {
            side: KochLeader(
                KochLeaderConfig(
                    **asdict(getattr(config, f"{side}_arm_config")),
                    id=f"{config.id}_{side}" if config.id else None,
                    calibration_dir=config.calibration_dir,
                )
            )
            for side in SIDES
        }

    @cached_property
    def action_features(self) -> dict[str, type]:
        return {f"{side}_{key}": kind for side, arm in self.arms.items() for key, kind in arm.action_features.items()}

    @cached_property
    def feedback_features(self) -> dict[str, type]:
        return {}

    @property
    def is_connected(self) -> bool:
        return all(arm.is_connected for arm in self.arms.values())

    @check_if_already_connected
    def connect(self, calibrate: bool = True) -> None:
        for arm in self.arms.values():
            arm.connect(calibrate)

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
    def get_action(self) -> dict[str, float]:
        return {f"{side}_{key}": value for side, arm in self.arms.items() for key, value in arm.get_action().items()}

    def send_feedback(self, feedback: dict[str, float]) -> None:
        raise NotImplementedError("Koch leaders take no feedback.")

    @check_if_not_connected
    def disconnect(self) -> None:
        for arm in self.arms.values():
            arm.disconnect()
