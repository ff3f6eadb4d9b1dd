"""obs_act and obs_diffusion: importing this package registers both policy types (and the `onecycle`
scheduler) with LeRobot."""

from lerobot_obsbench.policies.obs_act import ObsACTConfig
from lerobot_obsbench.policies.obs_diffusion import ObsDiffusionConfig

__all__ = ["ObsACTConfig", "ObsDiffusionConfig"]
