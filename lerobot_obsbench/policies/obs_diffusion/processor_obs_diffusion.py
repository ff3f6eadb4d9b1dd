"""obs_diffusion's pre/post-processors: Diffusion Policy's own pipeline (normalise state, env state and action;
batch; device).

LeRobot 0.6.1 finds a policy type's processors by name, `make_<type>_pre_post_processors` in the
`processor_*` module beside its `configuration_*` module. Sensor keys (depth, K, cam2world) never reach the
normaliser: the config takes them out of `input_features` and the model's adapter scales them itself.
"""

from lerobot.policies.diffusion.processor_diffusion import (
    make_diffusion_pre_post_processors as make_obs_diffusion_pre_post_processors,
)

__all__ = ["make_obs_diffusion_pre_post_processors"]
