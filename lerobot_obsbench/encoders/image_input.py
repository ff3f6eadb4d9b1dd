"""Input preparation shared by the image encoders: the official pipelines' resizing and the zero start of the
stem's extra (non-RGB) input channels."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

# The official ViT / MultiViT pipeline: Resize(256, bicubic) then CenterCrop(224), i.e. resize to 256/224 of the
# crop size first.
VIT_RESIZE_RATIO = 256 / 224


def as_frame_size(image_size: int | tuple[int, int] | list[int]) -> tuple[int, int]:
    """A builder's `image_size` (one side of a square frame, or (height, width)) as (height, width)."""
    return (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)


def resize(images: Tensor, size: int, mode: str = "bilinear") -> Tensor:
    """(N, C, H, W) -> (N, C, size, size) (torchvision's Resize of a square frame, antialiased)."""
    if images.shape[-2:] == (size, size):
        return images
    return F.interpolate(images, size=(size, size), mode=mode, align_corners=False, antialias=True)


def resize_center_crop(images: Tensor, size: int) -> Tensor:
    """Resize(round(size * 256 / 224), bicubic) + CenterCrop(size), the official ViT input pipeline."""
    resized = resize(images, round(size * VIT_RESIZE_RATIO), mode="bicubic")
    top = (resized.shape[-2] - size) // 2
    left = (resized.shape[-1] - size) // 2
    return resized[..., top : top + size, left : left + size]


@torch.no_grad()
def zero_extra_channels(weight: Tensor) -> None:
    """Zero a stem filter's non-RGB input channels in place (channels 3.. of rgbd / pointmap; every channel of a
    depth-only stem), as the official code does also when training from scratch."""
    first_extra = 3 if weight.shape[1] >= 3 else 0  # a depth-only stem has no RGB channel to keep
    weight[:, first_extra:] = 0
