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
"""

from __future__ import annotations

from dataclasses import field, make_dataclass

from lerobot.configs.policies import PreTrainedConfig

from lerobot_obsbench.encoders import default_encoder
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.policies.obs_act.configuration_obs_act import ObsACTConfig
from lerobot_obsbench.policies.obs_diffusion.configuration_obs_diffusion import ObsDiffusionConfig

# name prefix -> (base policy type, its config class)
BASES = {"act": ("obs_act", ObsACTConfig), "dp": ("obs_diffusion", ObsDiffusionConfig)}
SPACE_SUFFIXES = {"rgb": "rgb", "depth": "depth", "rgbd": "rgbd", "pointmap": "pointmap", "pcd": "pointcloud"}
EXTRA_ENCODERS = {"pcd_spunet": ("pointcloud", "spunet34")}

# type name -> (base policy type, obs_space, default encoder)
NAMED_POLICIES: dict[str, tuple[str, str, str]] = {
    **{
        f"{prefix}_{suffix}": (base_type, space, default_encoder(space))
        for prefix, (base_type, _) in BASES.items()
        for suffix, space in SPACE_SUFFIXES.items()
    },
    **{
        f"{prefix}_{suffix}": (base_type, space, encoder)
        for prefix, (base_type, _) in BASES.items()
        for suffix, (space, encoder) in EXTRA_ENCODERS.items()
    },
}


def class_name(type_name: str) -> str:
    """`act_pcd` -> `ActPcd` (LeRobot finds `ActPcdPolicy` in modeling_named from `ActPcdConfig`)."""
    return "".join(part.capitalize() for part in type_name.split("_"))


def _post_init(self) -> None:
    base_type, space, _ = NAMED_POLICIES[self.type]
    if self.obs_space != space:
        raise ConfigError(
            f"--policy.type={self.type} is {base_type} on obs_space={space!r}; got --policy.obs_space="
            f"{self.obs_space!r}. Use the named type of that space, or --policy.type={base_type}."
        )
    BASES[self.type.split("_")[0]][1].__post_init__(self)


def _make(type_name: str) -> type:
    base_type, space, encoder = NAMED_POLICIES[type_name]
    base = BASES[type_name.split("_")[0]][1]
    cls = make_dataclass(
        class_name(type_name) + "Config",
        [("obs_space", str, field(default=space)), ("encoder", str | None, field(default=encoder))],
        bases=(base,),
        namespace={
            "__post_init__": _post_init,
            "__doc__": f"`{base_type}` with obs_space={space!r}, encoder {encoder!r} by default.",
            "__module__": __name__,
            "base_type": base_type,  # the plugin type this one presets (model cards name it)
        },
    )
    return PreTrainedConfig.register_subclass(type_name)(cls)


NAMED_CONFIGS = {name: _make(name) for name in NAMED_POLICIES}
globals().update({cls.__name__: cls for cls in NAMED_CONFIGS.values()})
