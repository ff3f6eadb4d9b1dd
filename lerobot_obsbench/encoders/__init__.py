"""Observation encoders. Importing this package registers the built-in encoders."""

from lerobot_obsbench.encoders import pointnet, resnet, spunet, vit  # noqa: F401  (registration side effects)
from lerobot_obsbench.encoders.registry import (
    available_encoders,
    check_encoder,
    encoder_info,
    make_encoder,
    register_encoder,
)

__all__ = ["available_encoders", "check_encoder", "encoder_info", "make_encoder", "register_encoder"]
