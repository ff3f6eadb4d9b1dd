"""Observation encoders. Importing this package registers the built-in encoders."""

from lerobot_obsbench.encoders import blind, pointnet, resnet, spunet34, vit  # noqa: F401  (registration)
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
