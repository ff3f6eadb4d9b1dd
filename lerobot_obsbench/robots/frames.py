"""Robot observations and actions <-> the dataset schema (lerobot_obsbench/schema.py): the keys real recordings
write and real rollouts feed the policy, so every observation space works on real data as on simulated data.

| robot observation key     | schema key                         |
|---------------------------|------------------------------------|
| `<motor>.pos` (all)       | observation.state (joint order)    |
| `<cam>`                   | observation.images.<cam>           |
| `<cam>.depth`             | observation.depth.<cam>            |
| `<cam>.intrinsics`        | observation.intrinsics.<cam>       |
| `<cam>.cam2world`         | observation.cam2world.<cam>        |
| action `<motor>.pos`      | action (same order as the state)   |

Real arms record joint positions only (no end-effector pose), so the `ee` frame is refused on their datasets.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.robots.scene_cameras import CAM2WORLD_SUFFIX, DEPTH_SUFFIX, INTRINSICS_SUFFIX
from lerobot_obsbench.schema import (
    ACTION_KEY,
    STATE_KEY,
    cam2world_key,
    depth_key,
    image_key,
    intrinsics_key,
)

SUFFIX_TO_KEY = {DEPTH_SUFFIX: depth_key, INTRINSICS_SUFFIX: intrinsics_key, CAM2WORLD_SUFFIX: cam2world_key}


def motor_keys(robot) -> list[str]:
    """The robot's joint keys in action order (state and action share it)."""
    return list(robot.action_features)


def schema_key(robot_key: str) -> str:
    for suffix, key in SUFFIX_TO_KEY.items():
        if robot_key.endswith(suffix):
            return key(robot_key.removesuffix(suffix))
    return image_key(robot_key)


def dataset_features(robot) -> dict[str, dict]:
    """LeRobotDataset `features` for this robot's recordings."""
    motors = motor_keys(robot)
    features = {
        STATE_KEY: {"dtype": "float32", "shape": (len(motors),), "names": motors},
        ACTION_KEY: {"dtype": "float32", "shape": (len(motors),), "names": motors},
    }
    for key, shape in robot.observation_features.items():
        if key in robot.action_features:
            continue
        target = schema_key(key)
        if key.endswith(DEPTH_SUFFIX):
            features[target] = {"dtype": "uint16", "shape": tuple(shape), "names": ["height", "width", "channels"]}
        elif key.endswith((INTRINSICS_SUFFIX, CAM2WORLD_SUFFIX)):
            features[target] = {"dtype": "float32", "shape": tuple(shape), "names": None}
        else:
            features[target] = {"dtype": "video", "shape": tuple(shape), "names": ["height", "width", "channels"]}
    return features


def observation_frame(observation: Mapping, motors: list[str]) -> dict[str, np.ndarray]:
    """One robot observation as schema-keyed arrays (no action)."""
    frame = {STATE_KEY: np.array([observation[m] for m in motors], dtype=np.float32)}
    for key, value in observation.items():
        if key in motors:
            continue
        target = schema_key(key)
        if key.endswith((INTRINSICS_SUFFIX, CAM2WORLD_SUFFIX)):
            value = np.asarray(value, dtype=np.float32)
        frame[target] = value
    return frame


def action_values(action: Mapping, motors: list[str]) -> np.ndarray:
    return np.array([action[m] for m in motors], dtype=np.float32)


def action_dict(values, motors: list[str]) -> dict[str, float]:
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(values) != len(motors):
        raise ConfigError(f"the policy outputs {len(values)} action values, the robot has {len(motors)} motors")
    return {m: float(v) for m, v in zip(motors, values, strict=True)}
