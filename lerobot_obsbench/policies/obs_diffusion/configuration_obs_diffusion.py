"""obs_diffusion: LeRobot's Diffusion Policy with the observation space as one config field."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

from lerobot_obsbench.policies.common import ObservationConfig


@PreTrainedConfig.register_subclass("obs_diffusion")
@dataclass
class ObsDiffusionConfig(ObservationConfig, DiffusionConfig):
    """Diffusion Policy (LeRobot 0.4.4, 1-D conditional UNet) whose observation encoder is chosen by
    `obs_space` / `encoder`.

    LeRobot's defaults already match the paper (horizon 16, 2 observation steps, 8 action steps, down dims
    512-1024-2048, kernel 5, 8 groups, step embedding 128, FiLM scale, 100 DDPM steps); the optimiser is the
    paper's AdamW + OneCycle. See `lerobot_obsbench.presets` for the small CPU preset.
    """

    # Paper learning rates {1e-5, 5e-5, 1e-4}.
    optimizer_lr: float = 1e-4
    # Local runs must not require --policy.repo_id.
    push_to_hub: bool = False
