"""obs_act's pre/post-processors: ACT's own pipeline (normalise state, env state and action; batch; device).

LeRobot 0.6.1 finds a policy type's processors by name, `make_<type>_pre_post_processors` in the
`processor_*` module beside its `configuration_*` module. Sensor keys (depth, K, cam2world) never reach the
normaliser: the config takes them out of `input_features` and the model's adapter scales them itself.
"""

from lerobot.policies.act.processor_act import make_act_pre_post_processors as make_obs_act_pre_post_processors

__all__ = ["make_obs_act_pre_post_processors"]
