"""obs_act: LeRobot's ACT with the observation space as one config field."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.act.configuration_act import ACTConfig

from lerobot_obsbench.policies.observation_config import ENCODER_FIELDS, ObservationConfig
from lerobot_obsbench.schema import check_choice

ACTION_LOSSES = ("l1", "mse")


@PreTrainedConfig.register_subclass("obs_act")
@dataclass
class ObsACTConfig(ObservationConfig, ACTConfig):
    """LeRobot's ACT whose observation encoder is chosen by `obs_space` / `encoder`.

    Defaults are the paper's (its Appendix C); see `lerobot_obsbench.presets` for the small CPU preset.
    """

    # Paper: feed-forward width 32 (LeRobot's default is 3200).
    dim_feedforward: int = 32
    # The original ACT builds 7 decoder layers but reads only the first one's output; LeRobot reproduces that
    # behaviour with a single decoder layer.
    n_decoder_layers: int = 1
    # Paper: temporal ensembling with k = 0.01, which queries the policy every step.
    temporal_ensemble_coeff: float | None = 0.01
    n_action_steps: int = 1
    # Never download torchvision weights implicitly (ACT's default would); weights come from `pretrained`.
    pretrained_backbone_weights: str | None = None
    # Paper learning rates {1e-5, 5e-5, 1e-4}.
    optimizer_lr: float = 1e-4
    # Learning rate of the observation encoder; None: the same as optimizer_lr (the paper's setting).
    optimizer_lr_backbone: float | None = None
    # Local runs must not require --policy.repo_id.
    push_to_hub: bool = False
    # Action reconstruction loss: "l1" (LeRobot's ACT) or "mse" (the official code's, which the paper reports).
    action_loss: str = "l1"
    # Point tokens' positions are the sine embedding of position_scale x seed xyz (metres): 100 maps 1 cm to one
    # radian unit; the official code embeds raw metres (1.0), where only a few channels vary over a table top.
    position_scale: float = 100.0

    REPLACED_FIELDS: ClassVar[dict[str, str]] = {
        "vision_backbone": "choose the encoder with --policy.encoder (`obsbench encoders` lists them)",
        "pretrained_backbone_weights": "load encoder weights with --policy.pretrained",
        "replace_final_stride_with_dilation": "the plugin's encoders keep their strides",
    }
    ENCODER_FIELDS: ClassVar[dict[str, str]] = {**ENCODER_FIELDS, "position_scale": "position_scale"}

    def __post_init__(self):
        super().__post_init__()
        check_choice("action_loss", self.action_loss, ACTION_LOSSES)
