"""The sparse convolutional U-Net of `spunet34`: PonderV2 / Pointcept's SpUNet layout on spconv.

Layout (the paper's SpUNet-34): a 5x5x5 submanifold stem to 32 channels; 4 encoder stages, each a stride-2
sparse conv then (2, 3, 4, 6) residual blocks of two 3x3x3 submanifold convs (32-64-128-256 channels); 4
decoder stages, each an inverse sparse conv, concatenation with the encoder skip and (2, 2, 2, 2) residual
blocks (256-128-96-96 channels). Every conv is followed by BatchNorm (eps 1e-3, momentum 0.01) and ReLU.
Module names follow PonderV2's checkpoint keys (`conv_input`, `down.N`, `enc.N.blockM`, `up.N`, `dec.N.blockM`).
Initialised as Pointcept initialises it: submanifold convs from a truncated normal (std 0.02), the strided and
inverse convs with spconv's default, norms at weight 1 / bias 0.

Points are voxelized at `voxel_size` in the policy's frame (one voxel per point after the adapter's voxel
sampling; duplicates share a voxel) and the per-voxel output features are scattered back to the points.

Importing this module needs spconv. spconv 2.3.8's CPU wheel asks `torch.cuda.current_stream()` in its backward
pass, which fails on a CUDA-built torch without a GPU; `import_spconv` makes that lookup return stream 0 when
CUDA is unavailable. On a GPU machine install `spconv-cu126` instead; the code is the same.
"""

from __future__ import annotations

from collections import OrderedDict
from functools import partial

import torch
from torch import Tensor, nn

from lerobot_obsbench import geometry
from lerobot_obsbench.errors import MissingDependencyError

ENCODER_CHANNELS, ENCODER_BLOCKS = (32, 64, 128, 256), (2, 3, 4, 6)
DECODER_CHANNELS, DECODER_BLOCKS = (256, 128, 96, 96), (2, 2, 2, 2)
STEM_CHANNELS = 32
# spconv drops an input voxel whose strided output index falls outside the output grid, so the grid must hold
# every coordinate at each of the 4 stride-2 levels: a margin of 2**4 = 16 cells beyond the largest coordinate
# is enough. Pointcept (whose layout PonderV2's weights use) adds 96; kept for parity, it changes no output.
GRID_MARGIN = 96
SPCONV_HELP = (
    "spunet34 needs spconv: `pip install spconv==2.3.8` (CPU wheel) or `pip install spconv-cu126` (CUDA 12.x GPUs)"
)


def _current_stream() -> int:
    return torch.cuda.current_stream().cuda_stream if torch.cuda.is_available() else 0


def import_spconv():
    """`spconv.pytorch`, with its CUDA-stream lookup made safe on CPU-only machines."""
    try:
        import spconv.pytorch as sp
        from spconv.pytorch import cppcore, ops, utils
        from spconv.pytorch import hash as sp_hash
    except ImportError as err:
        raise MissingDependencyError(SPCONV_HELP) from err
    for module in (cppcore, ops, sp_hash, utils):
        if hasattr(module, "get_current_stream"):
            module.get_current_stream = _current_stream
    return sp


spconv = import_spconv()


def _norm(channels: int) -> nn.BatchNorm1d:
    return nn.BatchNorm1d(channels, eps=1e-3, momentum=0.01)


def _init_weights(module: nn.Module) -> None:
    if isinstance(module, spconv.SubMConv3d):
        nn.init.trunc_normal_(module.weight, std=0.02)
    elif isinstance(module, nn.BatchNorm1d):
        nn.init.ones_(module.weight)
        nn.init.zeros_(module.bias)


class ConvNormReLU(nn.Module):
    """A sparse conv + BN + ReLU with PonderV2's `.conv` / `.bn` names."""

    def __init__(self, conv: nn.Module, channels: int):
        super().__init__()
        self.conv, self.bn, self.relu = conv, _norm(channels), nn.ReLU()

    def forward(self, x):
        x = self.conv(x)
        return x.replace_feature(self.relu(self.bn(x.features)))


class BasicBlock(spconv.SparseModule):
    """Residual block of two 3x3x3 submanifold convs (+ a 1x1 projection when the width changes)."""

    def __init__(self, in_channels: int, channels: int, indice_key: str):
        super().__init__()
        subm = partial(spconv.SubMConv3d, kernel_size=3, padding=1, bias=False, indice_key=indice_key)
        self.conv1, self.bn1 = subm(in_channels, channels), _norm(channels)
        self.conv2, self.bn2 = subm(channels, channels), _norm(channels)
        self.relu = nn.ReLU()
        self.project = in_channels != channels
        if self.project:
            self.proj_conv = spconv.SubMConv3d(in_channels, channels, kernel_size=1, bias=False)
            self.proj_norm = _norm(channels)

    def forward(self, x):
        out = self.conv1(x)
        out = out.replace_feature(self.relu(self.bn1(out.features)))
        out = self.conv2(out)
        residual = self.proj_norm(self.proj_conv(x).features) if self.project else x.features
        return out.replace_feature(self.relu(self.bn2(out.features) + residual))


class SpUNet(nn.Module):
    """Sparse U-Net over voxels: (xyz (B, N, 3), features (B, N, C), mask (B, N)) -> (B, N, 96)."""

    def __init__(self, in_channels: int, voxel_size: float = 0.005):
        super().__init__()
        self.voxel_size = voxel_size
        self.out_channels = DECODER_CHANNELS[-1]  # = spunet34.OUT_CHANNELS
        self.conv_input = ConvNormReLU(
            spconv.SubMConv3d(in_channels, STEM_CHANNELS, kernel_size=5, padding=1, bias=False, indice_key="stem"),
            STEM_CHANNELS,
        )
        self.down, self.enc, self.up, self.dec = (nn.ModuleList() for _ in range(4))
        # Decoder stage s undoes down[s]: it upsamples from the level below (the next decoder stage's output,
        # or the bottleneck for the deepest) to dec_widths[s] and merges the skip that entered down[s].
        dec_widths = DECODER_CHANNELS[::-1]
        up_inputs = (*dec_widths[1:], ENCODER_CHANNELS[-1])
        skips = (STEM_CHANNELS, *ENCODER_CHANNELS[:-1])
        for s, channels in enumerate(ENCODER_CHANNELS):
            self.down.append(
                ConvNormReLU(
                    spconv.SparseConv3d(
                        skips[s], channels, kernel_size=2, stride=2, bias=False, indice_key=f"spconv{s + 1}"
                    ),
                    channels,
                )
            )
            self.enc.append(
                spconv.SparseSequential(
                    OrderedDict(
                        (f"block{i}", BasicBlock(channels, channels, f"subm{s + 1}")) for i in range(ENCODER_BLOCKS[s])
                    )
                )
            )
            width = dec_widths[s]
            self.up.append(
                ConvNormReLU(
                    spconv.SparseInverseConv3d(
                        up_inputs[s], width, kernel_size=2, bias=False, indice_key=f"spconv{s + 1}"
                    ),
                    width,
                )
            )
            self.dec.append(
                spconv.SparseSequential(
                    OrderedDict(
                        (f"block{i}", BasicBlock(width + skips[s] if i == 0 else width, width, f"subm{s}"))
                        for i in range(DECODER_BLOCKS[::-1][s])
                    )
                )
            )
        self.apply(_init_weights)

    def voxelize(self, xyz: Tensor, mask: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(voxel indices (M, 4) int32 [batch, x, y, z], index of each voxel's first point in the flat valid
        points (M,), voxel of every valid point (P,))."""
        cells, key = geometry.voxel_grid(xyz, mask, self.voxel_size)
        unique, point_voxel = torch.unique(key[mask], return_inverse=True)
        points = torch.arange(len(point_voxel), device=xyz.device)
        first = torch.full((len(unique),), len(point_voxel), device=xyz.device, dtype=torch.int64)
        first = first.scatter_reduce(0, point_voxel, points, reduce="amin")
        batch = torch.nonzero(mask)[:, 0]
        indices = torch.cat([batch[first, None], cells[mask][first]], dim=1)
        return indices.to(torch.int32), first, point_voxel

    def forward(self, xyz: Tensor, features: Tensor, mask: Tensor) -> Tensor:
        indices, first, point_voxel = self.voxelize(xyz, mask)
        shape = (indices[:, 1:].amax(dim=0) + GRID_MARGIN).tolist()
        x = spconv.SparseConvTensor(features[mask][first], indices, shape, mask.shape[0])
        x = self.conv_input(x)
        skips = [x]
        for down, enc in zip(self.down, self.enc, strict=True):
            x = enc(down(x))
            skips.append(x)
        x = skips.pop()
        for s in reversed(range(len(self.up))):
            x = self.up[s](x)
            x = x.replace_feature(torch.cat([x.features, skips.pop().features], dim=1))
            x = self.dec[s](x)
        out = x.features.new_zeros(*mask.shape, self.out_channels)
        out[mask] = x.features[point_voxel]
        return out
