"""obs_diffusion: LeRobot's Diffusion Policy with the observation space as one config field."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.policies.observation_config import ENCODER_FIELDS, ObservationConfig
from lerobot_obsbench.schema import check_choice

DENOISERS = ("unet", "transformer")
DP_POINT_HEADS = ("maxpool", "official")
IMAGE_PIPELINE = (
    "the observation encoder replaces Diffusion Policy's image pipeline (crop, resize, spatial "
    "softmax): choose it with --policy.encoder / --policy.pretrained"
)


@PreTrainedConfig.register_subclass("obs_diffusion")
@dataclass
class ObsDiffusionConfig(ObservationConfig, DiffusionConfig):
    """Diffusion Policy (LeRobot 0.6.1, 1-D conditional UNet) whose observation encoder is chosen by
    `obs_space` / `encoder`.

    The paper's values (2 observation steps, down dims 512-1024-2048, kernel 5, 8 groups, step embedding 128,
    FiLM scale, 100 DDPM steps) are LeRobot's defaults; the ones LeRobot 0.6 changed are pinned here (horizon,
    action steps, and the replaced image-pipeline fields at their 0.4.4 values, which checkpoints saved by the
    plugin on 0.4.4 carry). The optimiser is the paper's AdamW + OneCycle (betas (0.9, 0.999): the official code
    never passes its configured (0.9, 0.95)). See `lerobot_obsbench.presets` for the small CPU preset.
    """

    # Paper (and LeRobot <= 0.5): a 16-step horizon of which 8 actions are executed (LeRobot 0.6: 64 / 32).
    horizon: int = 16
    n_action_steps: int = 8
    # Diffusion's own image pipeline, unused here (REPLACED_FIELDS): pinned to the values the plugin's
    # checkpoints have always saved, so that nothing downloads and old checkpoints load with their values.
    pretrained_backbone_weights: str | None = None
    use_group_norm: bool = True
    use_separate_rgb_encoder_per_camera: bool = False

    # Paper learning rates {1e-5, 5e-5, 1e-4}.
    optimizer_lr: float = 1e-4
    # Local runs must not require --policy.repo_id.
    push_to_hub: bool = False
    # Noise-prediction network: "unet" (LeRobot's 1-D conditional UNet, the paper's main setting) or
    # "transformer" (Diffusion Policy's time-series transformer, the paper's ablation).
    denoiser: str = "unet"
    # Transformer denoiser: layers, attention heads, width, attention dropout, causal attention over the
    # action sequence (Diffusion Policy's defaults).
    transformer_layers: int = 8
    transformer_heads: int = 4
    transformer_dim: int = 256
    transformer_attn_dropout: float = 0.3
    transformer_causal: bool = True
    # Point-cloud conditioning: "maxpool" (a max over the encoded points) or "official" (the official code's
    # tokenizer + projector to a 128-d feature; with PointNet an extra 512 -> 96 point layer first).
    dp_point_head: str = "maxpool"

    REPLACED_FIELDS: ClassVar[dict[str, str]] = {
        **{
            name: IMAGE_PIPELINE
            for name in (
                "vision_backbone",
                "pretrained_backbone_weights",
                "resize_shape",
                "crop_ratio",
                "crop_shape",
                "crop_is_random",
                "use_group_norm",
                "spatial_softmax_num_keypoints",
                "use_separate_rgb_encoder_per_camera",
            )
        },
        "scheduler_name": "the schedule is the paper's OneCycle (--policy.scheduler_pct_start, ...)",
        "scheduler_warmup_steps": "the schedule is the paper's OneCycle (--policy.scheduler_pct_start, ...)",
    }
    ENCODER_FIELDS: ClassVar[dict[str, str]] = {**ENCODER_FIELDS, "dp_point_head": "global_head"}

    def __post_init__(self):
        super().__post_init__()
        check_choice("denoiser", self.denoiser, DENOISERS)
        check_choice("dp_point_head", self.dp_point_head, DP_POINT_HEADS)
        if self.denoiser == "transformer" and self.transformer_dim % self.transformer_heads:
            raise ConfigError(
                f"transformer_dim ({self.transformer_dim}) must be divisible by transformer_heads "
                f"({self.transformer_heads})"
            )
