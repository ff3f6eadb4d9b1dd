from lerobot_obsbench.policies.obs_act.configuration_obs_act import ObsACTConfig

__all__ = ["ObsACTConfig"]
