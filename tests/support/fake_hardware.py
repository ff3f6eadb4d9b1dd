"""A fake Dynamixel bus for LeRobot's own Koch classes (no dynamixel-sdk, no arm), as LeRobot's tests do it.

`install(monkeypatch)` swaps `DynamixelMotorsBus` in LeRobot's `koch_follower` and `koch_leader` modules for
`FakeDynamixelBus`. The motors' state lives per port in `MOTORS` (see `motor_state`), like physical servos
outliving a bus object: what calibration they hold, their present positions, the goals written to them. A leader's
positions can follow a script (`script(port, fn)`: fn(read_index) -> {motor: position}); a follower moves to each
goal it is sent.
"""

from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from lerobot.motors import MotorCalibration


@dataclass
class MotorState:
    calibration: dict = field(default_factory=dict)  # what the servos hold
    positions: dict = field(default_factory=dict)  # normalized present positions
    goals: list = field(default_factory=list)  # every Goal_Position sync_write, in order
    script: object = None  # leader: fn(read_index) -> positions
    reads: int = 0


MOTORS: dict[str, MotorState] = {}


def motor_state(port: str) -> MotorState:
    return MOTORS.setdefault(port, MotorState())


def script(port: str, fn) -> None:
    motor_state(port).script = fn


class FakeDynamixelBus:
    """The subset of `DynamixelMotorsBus` LeRobot's Koch follower and leader use."""

    def __init__(self, port: str, motors: dict, calibration: dict | None = None):
        self.port, self.motors, self.calibration = port, motors, calibration or {}
        self.state = motor_state(port)
        for name in motors:
            self.state.positions.setdefault(name, 0.0)
        self._connected = False

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self, handshake: bool = True) -> None:
        self._connected = True

    def disconnect(self, disable_torque: bool = True) -> None:
        self._connected = False

    @property
    def is_calibrated(self) -> bool:
        return bool(self.calibration) and self.calibration == self.state.calibration

    def read_calibration(self) -> dict:
        return dict(self.state.calibration)

    def write_calibration(self, calibration: dict, cache: bool = True) -> None:
        self.state.calibration = dict(calibration)
        if cache:
            self.calibration = dict(calibration)

    def set_half_turn_homings(self, motors=None) -> dict:
        return {name: 0 for name in self.motors}

    def record_ranges_of_motion(self, motors=None, display_values: bool = True) -> tuple[dict, dict]:
        names = motors or list(self.motors)
        return {name: 100 for name in names}, {name: 3995 for name in names}

    def sync_read(self, data_name: str, motors=None, normalize: bool = True, num_retry: int = 0) -> dict:
        if data_name != "Present_Position":
            return {name: 0 for name in (motors or self.motors)}
        if self.state.script is not None:
            self.state.positions.update(self.state.script(self.state.reads))
        self.state.reads += 1
        return {name: float(self.state.positions[name]) for name in (motors or self.motors)}

    def sync_write(self, data_name: str, values: dict, normalize: bool = True, num_retry: int = 0) -> None:
        if data_name == "Goal_Position":
            self.state.goals.append(dict(values))
            self.state.positions.update(values)  # an ideal servo: at the goal by the next read

    def write(self, data_name: str, motor: str, value, normalize: bool = True, num_retry: int = 0) -> None:
        if data_name == "Goal_Position":
            self.state.positions[motor] = value

    def read(self, data_name: str, motor: str, normalize: bool = True, num_retry: int = 0):
        return self.state.positions.get(motor, 0.0) if data_name == "Present_Position" else 0

    def enable_torque(self, motors=None, num_retry: int = 0) -> None:
        pass

    def disable_torque(self, motors=None, num_retry: int = 0) -> None:
        pass

    @contextmanager
    def torque_disabled(self, motors=None):
        yield

    def configure_motors(self, return_delay_time: int = 0) -> None:
        pass


def install(monkeypatch) -> None:
    """Use the fake bus in LeRobot's Koch follower and leader modules; fresh motors for the test."""
    from lerobot.robots.koch_follower import koch_follower
    from lerobot.teleoperators.koch_leader import koch_leader

    MOTORS.clear()
    monkeypatch.setattr(koch_follower, "DynamixelMotorsBus", FakeDynamixelBus)
    monkeypatch.setattr(koch_leader, "DynamixelMotorsBus", FakeDynamixelBus)


KOCH_MOTORS = {"shoulder_pan": 1, "shoulder_lift": 2, "elbow_flex": 3, "wrist_flex": 4, "wrist_roll": 5, "gripper": 6}


def calibrate_arm(directory: Path, arm_id: str, port: str) -> Path:
    """A LeRobot calibration file for one Koch arm, and servos holding the same calibration (a calibrated arm)."""
    calibration = {
        name: MotorCalibration(id=motor_id, drive_mode=0, homing_offset=0, range_min=100, range_max=3995)
        for name, motor_id in KOCH_MOTORS.items()
    }
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{arm_id}.json"
    path.write_text(json.dumps({name: vars(c) for name, c in calibration.items()}, indent=2))
    motor_state(port).calibration = calibration
    return path
