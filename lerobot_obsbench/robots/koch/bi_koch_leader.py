"""Two Koch leader arms, composed from LeRobot's own `KochLeader` the way LeRobot composes `bi_so_leader`."""

from __future__ import annotations

from functools import cached_property

from lerobot.teleoperators.koch_leader import KochLeader, KochLeaderConfig
from lerobot.teleoperators.teleoperator import Teleoperator
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_obsbench.robots.koch.arm_pair import ArmPair, make_arms, prefixed
from lerobot_obsbench.robots.koch.config_bi_koch_leader import BiKochLeaderConfig


class BiKochLeader(ArmPair, Teleoperator):
    config_class = BiKochLeaderConfig
    name = "obsbench_bi_koch_leader"

    def __init__(self, config: BiKochLeaderConfig):
        super().__init__(config)
        self.config = config
        self.arms = make_arms(config, KochLeader, KochLeaderConfig)

    @cached_property
    def action_features(self) -> dict[str, type]:
        return prefixed({side: arm.action_features for side, arm in self.arms.items()})

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

    @check_if_not_connected
    def get_action(self) -> dict[str, float]:
        return prefixed({side: arm.get_action() for side, arm in self.arms.items()})

    def send_feedback(self, feedback: dict[str, float]) -> None:
        raise NotImplementedError("Koch leaders take no feedback.")

    @check_if_not_connected
    def disconnect(self) -> None:
        for arm in self.arms.values():
            arm.disconnect()
