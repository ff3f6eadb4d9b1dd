"""Early, explicit errors for real-robot set-ups: wrong action keys, uncalibrated arms, and a checkpoint that does
not fit the robot it is about to drive."""

from __future__ import annotations

from collections.abc import Mapping

from lerobot_obsbench.errors import ObsBenchError


class RobotSetupError(ObsBenchError, RuntimeError):
    """The robot, teleoperator or checkpoint do not fit together; the message names the fix."""


def check_action_keys(action: Mapping, expected: Mapping, device: object) -> None:
    """The action must name exactly the robot's motors (a single-arm leader on a bimanual robot, or the reverse,
    fails here instead of moving half a robot)."""
    missing = sorted(set(expected) - set(action))
    extra = sorted(set(action) - set(expected))
    if missing or extra:
        raise RobotSetupError(
            f"{device}: action keys do not match the robot's motors (missing {missing[:6]}, unexpected "
            f"{extra[:6]}). Pair the robot with its leader: obsbench_koch_follower with koch_leader, "
            "obsbench_bi_koch_follower with obsbench_bi_koch_leader."
        )


def require_calibrated(device: object, kind: str) -> None:
    """A connected robot / teleoperator whose arms carry the calibration of their files; otherwise the command
    that calibrates them (LeRobot would otherwise start an interactive calibration mid-recording)."""
    if not device.is_calibrated:
        config = device.config
        raise RobotSetupError(
            f"{device} is not calibrated (no calibration file for id {config.id!r}, or it does not match the "
            f"motors). Run: lerobot-calibrate --{kind}.type={config.type} --{kind}.id={config.id} ... (same ports)."
        )
