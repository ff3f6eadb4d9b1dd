"""One Koch arm's settings inside a bimanual config: plain dataclasses, as LeRobot's `SOFollowerConfig` is for its
bimanual SO arms (a field typed with a registered robot / teleoperator config would make draccus offer every
registered type there, the bimanual ones included, and recurse)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot_obsbench.numeric import check_number


@dataclass
class KochFollowerArmConfig:
    # Port of the arm's Dynamixel bus (`lerobot-find-port`).
    port: str
    disable_torque_on_disconnect: bool = True
    # LeRobot's safety limit on each commanded step (one value for all motors, or per motor name).
    max_relative_target: float | dict[str, float] | None = None
    # Degrees instead of LeRobot's [-100, 100] range for the joints.
    use_degrees: bool = False

    def __post_init__(self) -> None:
        limits = self.max_relative_target
        for motor, limit in (
            limits.items() if isinstance(limits, dict) else [("", limits)] if limits is not None else []
        ):
            check_number(f"max_relative_target{f'[{motor}]' if motor else ''}", limit, above=0)


@dataclass
class KochLeaderArmConfig:
    # Port of the leader arm's Dynamixel bus.
    port: str
    # Gripper position the leader springs back to (LeRobot's `koch_leader` default).
    gripper_open_pos: float = 50.0

    def __post_init__(self) -> None:
        check_number("gripper_open_pos", self.gripper_open_pos, minimum=-100, maximum=100)
