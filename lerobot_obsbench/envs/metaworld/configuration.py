"""`--env.type=obsbench_metaworld --env.task=drawer-open-v3`: a Meta-World task in the plugin's sensor schema as a
LeRobot EnvConfig, for stock `lerobot-eval` of a plugin checkpoint trained on Meta-World demonstrations."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_obsbench.envs.base_task import check_cameras
from lerobot_obsbench.envs.metaworld.env import ACTION_SIZE, STATE_SIZE, rendered_sensors
from lerobot_obsbench.envs.metaworld.tasks import CONTROL_FPS, DEFAULT_CAMERA, MAX_STEPS, metaworld_task
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.numeric import check_number
from lerobot_obsbench.schema import (
    ACTION_KEY,
    DEFAULT_POINT_FEATURES,
    DEPTH_PREFIX,
    IMAGE_PREFIX,
    MIN_IMAGE_SIZE,
    STATE_KEY,
    image_key,
)

GYM_NAMESPACE = "obsbench_metaworld"


@EnvConfig.register_subclass("obsbench_metaworld")
@dataclass
class MetaWorldEnvConfig(EnvConfig):
    """A Meta-World task returning the OBSBench sensor frame (rgb, uint16 depth, K, cam2world, state, object poses)."""

    # Task name, LeRobot's (`drawer-open-v3`; envs.metaworld.tasks.metaworld_tasks() lists them).
    task: str = "drawer-open-v3"
    # Steps per second of Meta-World's control (LeRobot's).
    fps: int = CONTROL_FPS
    # Cameras to render (LeRobot renders corner2).
    cameras: list[str] = field(default_factory=lambda: [DEFAULT_CAMERA])
    # Square image size of every camera: the policy's training size.
    image_size: int = 128
    # Steps per episode; None = Meta-World's 500.
    episode_length: int | None = None
    # The policy's `--policy.obs_space` and `--policy.point_features`: the env renders only the sensors such a
    # policy reads (depth alone for DP3's xyz point clouds, nothing for the controls), which sets how fast an
    # evaluation runs. None: colour and depth.
    obs_space: str | None = None
    point_features: str = DEFAULT_POINT_FEATURES

    def __post_init__(self):
        check_cameras(metaworld_task(self.task), self.cameras)
        check_number("image_size (pixels)", self.image_size, whole=True, minimum=MIN_IMAGE_SIZE)
        check_number("fps", self.fps, whole=True, minimum=1)
        if self.episode_length is not None:
            check_number(
                "episode_length (steps; or None for Meta-World's own)", self.episode_length, whole=True, minimum=1
            )
        if self.obs_space is None and self.point_features != DEFAULT_POINT_FEATURES:
            raise ConfigError(
                f"--env.point_features={self.point_features} is read with --env.obs_space only (the policy's space)"
            )
        sensors = self.sensors  # refuses an unknown space or point feature here, before the policy loads
        colour = [cam for cam in self.cameras if IMAGE_PREFIX in sensors]
        size = (self.image_size, self.image_size, 3)
        self.features = {
            "action": PolicyFeature(FeatureType.ACTION, (ACTION_SIZE,)),
            "agent_pos": PolicyFeature(FeatureType.STATE, (STATE_SIZE,)),
            **{f"pixels/{cam}": PolicyFeature(FeatureType.VISUAL, size) for cam in colour},
        }
        self.features_map = {
            "action": ACTION_KEY,
            "agent_pos": STATE_KEY,
            **{f"pixels/{cam}": image_key(cam) for cam in colour},
        }

    @property
    def sensors(self) -> tuple[str, ...]:
        """What the env renders per camera (schema prefixes)."""
        if self.obs_space is None:
            return (IMAGE_PREFIX, DEPTH_PREFIX)
        return rendered_sensors(self.obs_space, self.point_features)

    @property
    def package_name(self) -> str:
        return "lerobot_obsbench.envs.metaworld"

    @property
    def gym_id(self) -> str:
        return f"{GYM_NAMESPACE}/{metaworld_task(self.task).name}"

    @property
    def gym_kwargs(self) -> dict:
        steps = self.episode_length or MAX_STEPS
        # `max_episode_steps` is gym.make's TimeLimit (lerobot-eval reads it); `episode_length` reaches the env.
        return {
            "cameras": list(self.cameras),
            "sensors": self.sensors,
            "image_size": self.image_size,
            "episode_length": steps,
            "max_episode_steps": steps,
        }
