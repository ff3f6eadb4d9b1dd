"""`pointnet`: the paper's PointNet backbone with the point tokenizer.

The paper's PointNet is five kernel-1 sparse convolutions 64-64-64-128-512 without bias, each followed by
BatchNorm (eps 1e-3, momentum 0.01) and ReLU. Here it is a shared per-point MLP with exactly those weights,
applied to the valid points only (padding never enters the BatchNorm statistics). The two are the same map: a
kernel-1 convolution over voxels multiplies each voxel's feature by one matrix, independent of its neighbours,
and voxel sampling already left one point per voxel. 83,968 parameters for rgb+xyz input.

For Diffusion Policy's official head (`global_head="official"`) the official code adds a 512 -> 96 output layer
before the tokenizer; with the tokenizer's Linear + BN that is Table 1's "PointNet 0.14M" (142,912).
"""

from __future__ import annotations

from torch import Tensor, nn

from lerobot_obsbench.encoders.point_tokenizer import (
    PAPER_TOKENS,
    POINT_NORMS,
    PointTokenEncoder,
    PointTokenOptions,
    describe_point_tokens,
    masked_apply,
    norm_relu,
)
from lerobot_obsbench.encoders.registry import register_encoder
from lerobot_obsbench.schema import input_channels

POINTNET_WIDTHS = (64, 64, 64, 128, 512)
# The official Diffusion Policy head: an extra 512 -> 96 point layer, then one 96-wide token layer.
DP_PROJECTION, DP_WIDTHS = 96, (96,)


class PointNetBackbone(nn.Module):
    """(xyz, features (B, N, C), mask) -> (B, N, 512): the paper's PointNet on every valid point."""

    def __init__(self, in_channels: int, norm: str = "batch"):
        super().__init__()
        layers: list[nn.Module] = []
        for width in POINTNET_WIDTHS:
            layers += [nn.Linear(in_channels, width, bias=False), *norm_relu(width, norm=norm)]
            in_channels = width
        self.mlp = nn.Sequential(*layers)
        self.out_channels = POINTNET_WIDTHS[-1]

    def forward(self, xyz: Tensor, features: Tensor, mask: Tensor) -> Tensor:
        return masked_apply(self.mlp, features, mask)


@register_encoder(
    "pointnet",
    ("pointcloud",),
    "PointNet: 5 kernel-1 convs 64-64-64-128-512 + BN (the paper's PointNet; 84.0k parameters, "
    "see docs/observation-spaces.md)",
    describe_point_tokens(POINTNET_WIDTHS[-1]),
    default_for=("pointcloud",),
    choices={"norm": POINT_NORMS},
)
def build_pointnet(
    obs_space: str,
    output: str,
    dim: int,
    point_features: str = "rgb+xyz",
    tokens: PointTokenOptions = PAPER_TOKENS,
    norm: str | None = None,
) -> PointTokenEncoder:
    """`norm`: the backbone's per-point normalisation (None: the paper's BatchNorm; "layer": LayerNorm)."""
    channels = input_channels(obs_space, point_features)
    return PointTokenEncoder(
        PointNetBackbone(channels, norm or "batch"),
        channels,
        output,
        dim=dim,
        tokens=tokens,
        dp_projection=DP_PROJECTION,
        dp_widths=DP_WIDTHS,
    )
