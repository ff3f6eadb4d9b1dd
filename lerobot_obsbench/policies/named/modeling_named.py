"""Policy classes of the named types (see configuration_named): `obs_act` / `obs_diffusion` under another name."""

from __future__ import annotations

from lerobot_obsbench.policies.named.configuration_named import (
    ActDepthConfig,
    ActPcdConfig,
    ActPcdSpunetConfig,
    ActPointmapConfig,
    ActRgbConfig,
    ActRgbdConfig,
    DpDepthConfig,
    DpPcdConfig,
    DpPcdSpunetConfig,
    DpPointmapConfig,
    DpRgbConfig,
    DpRgbdConfig,
)
from lerobot_obsbench.policies.obs_act.modeling_obs_act import ObsACTPolicy
from lerobot_obsbench.policies.obs_diffusion.modeling_obs_diffusion import ObsDiffusionPolicy


class ActRgbPolicy(ObsACTPolicy):
    config_class = ActRgbConfig
    name = "act_rgb"


class ActDepthPolicy(ObsACTPolicy):
    config_class = ActDepthConfig
    name = "act_depth"


class ActRgbdPolicy(ObsACTPolicy):
    config_class = ActRgbdConfig
    name = "act_rgbd"


class ActPointmapPolicy(ObsACTPolicy):
    config_class = ActPointmapConfig
    name = "act_pointmap"


class ActPcdPolicy(ObsACTPolicy):
    config_class = ActPcdConfig
    name = "act_pcd"


class ActPcdSpunetPolicy(ObsACTPolicy):
    config_class = ActPcdSpunetConfig
    name = "act_pcd_spunet"


class DpRgbPolicy(ObsDiffusionPolicy):
    config_class = DpRgbConfig
    name = "dp_rgb"


class DpDepthPolicy(ObsDiffusionPolicy):
    config_class = DpDepthConfig
    name = "dp_depth"


class DpRgbdPolicy(ObsDiffusionPolicy):
    config_class = DpRgbdConfig
    name = "dp_rgbd"


class DpPointmapPolicy(ObsDiffusionPolicy):
    config_class = DpPointmapConfig
    name = "dp_pointmap"


class DpPcdPolicy(ObsDiffusionPolicy):
    config_class = DpPcdConfig
    name = "dp_pcd"


class DpPcdSpunetPolicy(ObsDiffusionPolicy):
    config_class = DpPcdSpunetConfig
    name = "dp_pcd_spunet"
