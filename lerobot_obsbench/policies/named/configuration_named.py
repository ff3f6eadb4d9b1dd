"""The paper's compared methods as LeRobot policy types: `--policy.type=act_pcd` is `--policy.type=obs_act
--policy.obs_space=pointcloud --policy.encoder=pointnet`, and a checkpoint saved under `act_pcd` loads back as
`act_pcd`. Each type is a thin preset — a subclass that fixes `obs_space` and sets the encoder's default — of
`obs_act` (ACT) or `obs_diffusion` (Diffusion Policy); every other field and all the code are theirs.

| type | policy | obs_space | encoder (default) |
|---|---|---|---|
| act_rgb, dp_rgb | ACT, DP | rgb | resnet50 |
| act_depth, dp_depth | ACT, DP | depth | resnet50 |
| act_rgbd, dp_rgbd | ACT, DP | rgbd | resnet50 |
| act_pointmap, dp_pointmap | ACT, DP | pointmap | resnet50 |
| act_pcd, dp_pcd | ACT, DP | pointcloud | pointnet (the paper's PCD-PointNet) |
| act_pcd_spunet, dp_pcd_spunet | ACT, DP | pointcloud | spunet34 (the paper's PCD-SpUNet) |

`tests/policies/test_policies.py` keeps this table equal to the classes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from lerobot.configs.policies import PreTrainedConfig

from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.policies.obs_act.configuration_obs_act import ObsACTConfig
from lerobot_obsbench.policies.obs_diffusion.configuration_obs_diffusion import ObsDiffusionConfig


class NamedType:
    """What a named type adds to the type it presets (`base_type`): its observation space, fixed."""

    base_type: ClassVar[str]  # the plugin type it presets (model cards name it)

    def __post_init__(self):
        space = type(self).__dataclass_fields__["obs_space"].default
        if self.obs_space != space:
            raise ConfigError(
                f"--policy.type={self.type} is {self.base_type} on obs_space={space!r}; got --policy.obs_space="
                f"{self.obs_space!r}. Use the named type of that space, or --policy.type={self.base_type}."
            )
        super().__post_init__()


@PreTrainedConfig.register_subclass("act_rgb")
@dataclass
class ActRgbConfig(NamedType, ObsACTConfig):
    """`obs_act` with obs_space='rgb', encoder 'resnet50' by default."""

    base_type: ClassVar[str] = "obs_act"
    obs_space: str = "rgb"
    encoder: str | None = "resnet50"


@PreTrainedConfig.register_subclass("act_depth")
@dataclass
class ActDepthConfig(NamedType, ObsACTConfig):
    """`obs_act` with obs_space='depth', encoder 'resnet50' by default."""

    base_type: ClassVar[str] = "obs_act"
    obs_space: str = "depth"
    encoder: str | None = "resnet50"


@PreTrainedConfig.register_subclass("act_rgbd")
@dataclass
class ActRgbdConfig(NamedType, ObsACTConfig):
    """`obs_act` with obs_space='rgbd', encoder 'resnet50' by default."""

    base_type: ClassVar[str] = "obs_act"
    obs_space: str = "rgbd"
    encoder: str | None = "resnet50"


@PreTrainedConfig.register_subclass("act_pointmap")
@dataclass
class ActPointmapConfig(NamedType, ObsACTConfig):
    """`obs_act` with obs_space='pointmap', encoder 'resnet50' by default."""

    base_type: ClassVar[str] = "obs_act"
    obs_space: str = "pointmap"
    encoder: str | None = "resnet50"


@PreTrainedConfig.register_subclass("act_pcd")
@dataclass
class ActPcdConfig(NamedType, ObsACTConfig):
    """`obs_act` with obs_space='pointcloud', encoder 'pointnet' by default."""

    base_type: ClassVar[str] = "obs_act"
    obs_space: str = "pointcloud"
    encoder: str | None = "pointnet"


@PreTrainedConfig.register_subclass("act_pcd_spunet")
@dataclass
class ActPcdSpunetConfig(NamedType, ObsACTConfig):
    """`obs_act` with obs_space='pointcloud', encoder 'spunet34' by default."""

    base_type: ClassVar[str] = "obs_act"
    obs_space: str = "pointcloud"
    encoder: str | None = "spunet34"


@PreTrainedConfig.register_subclass("dp_rgb")
@dataclass
class DpRgbConfig(NamedType, ObsDiffusionConfig):
    """`obs_diffusion` with obs_space='rgb', encoder 'resnet50' by default."""

    base_type: ClassVar[str] = "obs_diffusion"
    obs_space: str = "rgb"
    encoder: str | None = "resnet50"


@PreTrainedConfig.register_subclass("dp_depth")
@dataclass
class DpDepthConfig(NamedType, ObsDiffusionConfig):
    """`obs_diffusion` with obs_space='depth', encoder 'resnet50' by default."""

    base_type: ClassVar[str] = "obs_diffusion"
    obs_space: str = "depth"
    encoder: str | None = "resnet50"


@PreTrainedConfig.register_subclass("dp_rgbd")
@dataclass
class DpRgbdConfig(NamedType, ObsDiffusionConfig):
    """`obs_diffusion` with obs_space='rgbd', encoder 'resnet50' by default."""

    base_type: ClassVar[str] = "obs_diffusion"
    obs_space: str = "rgbd"
    encoder: str | None = "resnet50"


@PreTrainedConfig.register_subclass("dp_pointmap")
@dataclass
class DpPointmapConfig(NamedType, ObsDiffusionConfig):
    """`obs_diffusion` with obs_space='pointmap', encoder 'resnet50' by default."""

    base_type: ClassVar[str] = "obs_diffusion"
    obs_space: str = "pointmap"
    encoder: str | None = "resnet50"


@PreTrainedConfig.register_subclass("dp_pcd")
@dataclass
class DpPcdConfig(NamedType, ObsDiffusionConfig):
    """`obs_diffusion` with obs_space='pointcloud', encoder 'pointnet' by default."""

    base_type: ClassVar[str] = "obs_diffusion"
    obs_space: str = "pointcloud"
    encoder: str | None = "pointnet"


@PreTrainedConfig.register_subclass("dp_pcd_spunet")
@dataclass
class DpPcdSpunetConfig(NamedType, ObsDiffusionConfig):
    """`obs_diffusion` with obs_space='pointcloud', encoder 'spunet34' by default."""

    base_type: ClassVar[str] = "obs_diffusion"
    obs_space: str = "pointcloud"
    encoder: str | None = "spunet34"


# type name -> its config class, and (base policy type, obs_space, default encoder)
NAMED_CONFIGS: dict[str, type] = {
    "act_rgb": ActRgbConfig,
    "act_depth": ActDepthConfig,
    "act_rgbd": ActRgbdConfig,
    "act_pointmap": ActPointmapConfig,
    "act_pcd": ActPcdConfig,
    "act_pcd_spunet": ActPcdSpunetConfig,
    "dp_rgb": DpRgbConfig,
    "dp_depth": DpDepthConfig,
    "dp_rgbd": DpRgbdConfig,
    "dp_pointmap": DpPointmapConfig,
    "dp_pcd": DpPcdConfig,
    "dp_pcd_spunet": DpPcdSpunetConfig,
}
NAMED_POLICIES: dict[str, tuple[str, str, str]] = {
    name: (cls.base_type, cls.obs_space, cls.encoder) for name, cls in NAMED_CONFIGS.items()
}
