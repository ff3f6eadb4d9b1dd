"""Named policy types for the paper's compared methods (`--policy.type=act_pcd`, `dp_rgb`, ...): each is
`obs_act` or `obs_diffusion` with its observation space fixed and the paper's encoder as default."""

from lerobot_obsbench.policies.named.configuration_named import NAMED_POLICIES

__all__ = ["NAMED_POLICIES"]
