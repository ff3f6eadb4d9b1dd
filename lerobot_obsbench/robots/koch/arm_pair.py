"""What the bimanual Koch follower and leader share: two LeRobot arms keyed `left` / `right`, their keys
prefixed `left_` / `right_`, per-arm calibration ids `<id>_left` / `<id>_right`, and the calibration and set-up
calls LeRobot's tools make, forwarded to both arms (as LeRobot composes its bimanual SO arms)."""

from __future__ import annotations

from dataclasses import asdict

SIDES = ("left", "right")


def make_arms(config, arm_class: type, arm_config_class: type) -> dict:
    """One LeRobot arm per side from `config.<side>_arm_config`, calibrated under `<config.id>_<side>`."""
    return {
        side: arm_class(
            arm_config_class(
                **asdict(getattr(config, f"{side}_arm_config")),
                id=f"{config.id}_{side}" if config.id else None,
                calibration_dir=config.calibration_dir,
            )
        )
        for side in SIDES
    }


def prefixed(per_side: dict[str, dict]) -> dict:
    """{side: {key: value}} -> {side_key: value}."""
    return {f"{side}_{key}": value for side, values in per_side.items() for key, value in values.items()}


class ArmPair:
    """Calibration and set-up of `self.arms` (both sides); mixed in before LeRobot's Robot / Teleoperator."""

    arms: dict

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
