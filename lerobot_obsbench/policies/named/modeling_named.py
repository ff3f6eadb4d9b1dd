"""Policy classes of the named types (see configuration_named): `obs_act` / `obs_diffusion` under another name."""

from __future__ import annotations

from lerobot_obsbench.policies.named.configuration_named import NAMED_CONFIGS, NAMED_POLICIES
from lerobot_obsbench.policies.obs_act.modeling_obs_act import ObsACTPolicy
from lerobot_obsbench.policies.obs_diffusion.modeling_obs_diffusion import ObsDiffusionPolicy

BASE_POLICIES = {"obs_act": ObsACTPolicy, "obs_diffusion": ObsDiffusionPolicy}


def _make(type_name: str) -> type:
    config_class = NAMED_CONFIGS[type_name]
    base = BASE_POLICIES[NAMED_POLICIES[type_name][0]]
    name = config_class.__name__.removesuffix("Config") + "Policy"
    return type(name, (base,), {"config_class": config_class, "name": type_name, "__module__": __name__})


NAMED_POLICY_CLASSES = {name: _make(name) for name in NAMED_POLICIES}
globals().update({cls.__name__: cls for cls in NAMED_POLICY_CLASSES.values()})
