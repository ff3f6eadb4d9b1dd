"""obs_act and obs_diffusion, and the named types of the paper's methods (act_pcd, dp_rgb, ...): importing
this package registers them (and the `onecycle` scheduler) with LeRobot."""

from lerobot_obsbench.policies.named import NAMED_POLICIES
from lerobot_obsbench.policies.obs_act import ObsACTConfig
from lerobot_obsbench.policies.obs_diffusion import ObsDiffusionConfig

__all__ = ["NAMED_POLICIES", "ObsACTConfig", "ObsDiffusionConfig"]
