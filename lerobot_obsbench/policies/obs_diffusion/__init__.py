from lerobot_obsbench.policies.obs_diffusion.configuration_obs_diffusion import ObsDiffusionConfig

__all__ = ["ObsDiffusionConfig"]
