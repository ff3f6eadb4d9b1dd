"""Processors of the named types (act_pcd, dp_rgb, ...): the pipeline of the type each one presets.

LeRobot 0.6.1 looks up `make_<type>_pre_post_processors` in this module for every type configured in
`configuration_named`, so one entry per named type is made here from `NAMED_POLICIES`.
"""

from __future__ import annotations

from lerobot_obsbench.policies.named.configuration_named import NAMED_POLICIES
from lerobot_obsbench.policies.obs_act.processor_obs_act import make_obs_act_pre_post_processors
from lerobot_obsbench.policies.obs_diffusion.processor_obs_diffusion import make_obs_diffusion_pre_post_processors

BASE_PROCESSORS = {
    "obs_act": make_obs_act_pre_post_processors,
    "obs_diffusion": make_obs_diffusion_pre_post_processors,
}
NAMED_PROCESSORS = {
    f"make_{name}_pre_post_processors": BASE_PROCESSORS[base_type] for name, (base_type, _, _) in NAMED_POLICIES.items()
}
globals().update(NAMED_PROCESSORS)
