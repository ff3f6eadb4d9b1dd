"""Observation encoders. Importing this package registers the built-in encoders: every module in it is imported,
so an encoder is added by adding its module (one that calls `register_encoder`), with no list to edit."""

import importlib
import pkgutil

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

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")
