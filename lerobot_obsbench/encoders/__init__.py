"""Observation encoders. Importing this package registers the built-in encoders."""

from lerobot_obsbench.encoders import (  # noqa: F401  (registration)
    blind,
    dp3,
    keypoints,
    oracle,
    pointnet,
    resnet,
    spunet34,
    vit,
)
from lerobot_obsbench.encoders.registry import (
    EncoderContext,
    EncoderOutput,
    available_encoders,
    check_encoder,
    default_encoder,
    encoder_info,
    encoder_output,
    make_encoder,
    register_encoder,
)

__all__ = [
    "EncoderContext",
    "EncoderOutput",
    "available_encoders",
    "check_encoder",
    "default_encoder",
    "encoder_info",
    "encoder_output",
    "make_encoder",
    "register_encoder",
]
