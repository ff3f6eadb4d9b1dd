"""Sparse convolutional U-Net backbone (`spunet34`): PonderV2 / Pointcept's SpUNet layout on spconv.

Layout (the paper's SpUNet-34): a 5x5x5 submanifold stem to 32 channels; 4 encoder stages, each a stride-2
sparse conv then (2, 3, 4, 6) residual blocks of two 3x3x3 submanifold convs (32-64-128-256 channels); 4
decoder stages, each an inverse sparse conv, concatenation with the encoder skip and (2, 2, 2, 2) residual
blocks (256-128-96-96 channels). Every conv is followed by BatchNorm (eps 1e-3, momentum 0.01) and ReLU.
Module names follow PonderV2's checkpoint keys (`conv_input`, `down.N`, `enc.N.blockM`, `up.N`, `dec.N.blockM`).

Points are voxelized at `voxel_size` in the policy's frame (one voxel per point after the adapter's voxel
sampling; duplicates share a voxel) and the per-voxel output features are scattered back to the points.

PonderV2 trains one set of norms per dataset ("PDNorm": `bn.bns.K.*` per condition, plus an adaptive
`bn.modulation` from a learned per-dataset context `embedding_table`). For one chosen condition that norm is an
ordinary BatchNorm followed by a constant per-channel scale and shift, which `ponderv2_to_spunet` folds into the
BatchNorm's affine parameters — an exact conversion, so the encoder itself keeps plain BatchNorm.

spconv 2.3.8's CPU wheel asks `torch.cuda.current_stream()` in its backward pass, which fails on a CUDA-built
torch without a GPU; `import_spconv` makes that lookup return stream 0 when CUDA is unavailable (DESIGN §5).
On a GPU machine install `spconv-cu126` instead; the code is the same.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lerobot_obsbench.encoders.pretrained import load_matching, read_state_dict
from lerobot_obsbench.encoders.registry import register_encoder
from lerobot_obsbench.spaces import input_channels

ENCODER_CHANNELS, ENCODER_BLOCKS = (32, 64, 128, 256), (2, 3, 4, 6)
DECODER_CHANNELS, DECODER_BLOCKS = (256, 128, 96, 96), (2, 2, 2, 2)
STEM_CHANNELS = 32
PONDERV2_CONDITIONS = ("ScanNet", "S3DIS", "Structured3D")
SPCONV_HELP = ("spunet34 needs spconv: `pip install spconv==2.3.8` (CPU wheel) or `pip install spconv-cu126` "
               "(CUDA 12.x GPUs)")
_PATCHED = False


def _current_stream() -> int:
    return torch.cuda.current_stream().cuda_stream if torch.cuda.is_available() else 0


def import_spconv():
    """`spconv.pytorch`, with its CUDA-stream lookup made safe on CPU-only machines."""
    global _PATCHED
    try:
        import spconv.pytorch as spconv
    except ImportError as err:
        raise ImportError(SPCONV_HELP) from err
    if not _PATCHED:
        from spconv.pytorch import cppcore, hash as sp_hash, ops, utils

        for module in (cppcore, ops, sp_hash, utils):
            if hasattr(module, "get_current_stream"):
                module.get_current_stream = _current_stream
        _PATCHED = True
    return spconv


def ponderv2_to_spunet(state: dict[str, Tensor], condition: str = "ScanNet") -> dict[str, Tensor]:
    """PonderV2 checkpoint (`module.backbone.*` with PDNorm, `module.embedding_table.weight`) -> SpUNet keys,
    keeping the norms of `condition` and folding its adaptive modulation into the BatchNorm affine."""
    if condition not in PONDERV2_CONDITIONS:
        raise ValueError(f"PonderV2 condition must be one of {PONDERV2_CONDITIONS}; got {condition!r}")
    k = PONDERV2_CONDITIONS.index(condition)
    backbone = {key[len("module.backbone."):]: v for key, v in state.items() if key.startswith("module.backbone.")}
    table = state.get("module.embedding_table.weight", backbone.pop("embedding_table.weight", None))
    out = {}
    for key, value in backbone.items():
        if ".bns." in key:
            norm, rest = key.split(".bns.", 1)
            index, field = rest.split(".", 1)
            if int(index) == k:
                out[f"{norm}.{field}"] = value
        elif ".modulation." not in key:
            out[key] = value
    for key in [key for key in backbone if key.endswith(".modulation.1.weight")]:
        norm = key[: -len(".modulation.1.weight")]
        if table is None:
            raise ValueError("PonderV2 checkpoint has adaptive norms but no embedding_table")
        context = torch.nn.functional.silu(table[k])
        shift, scale = (backbone[key] @ context + backbone[f"{norm}.modulation.1.bias"]).chunk(2)
        out[f"{norm}.weight"] = out[f"{norm}.weight"] * (1 + scale)
        out[f"{norm}.bias"] = out[f"{norm}.bias"] * (1 + scale) + shift
    return out


def load_ponderv2(backbone, pretrained: str, condition: str = "ScanNet") -> dict:
    """Load a PonderV2 checkpoint (or one already in this module's keys) into a SpUNet."""
    state = read_state_dict(pretrained)
    if any(key.startswith("module.backbone.") for key in state):
        state = ponderv2_to_spunet(state, condition)
        source = f"PonderV2 checkpoint {pretrained} (norms of {condition})"
    else:
        source = f"SpUNet checkpoint {pretrained}"
    return load_matching(backbone, state, source)


@register_encoder("spunet34", ("pointcloud",), "sparse-conv U-Net, PonderV2 layout (paper, 39.2M); needs spconv",
                  pretrained="PonderV2 (module.backbone.*)")
def build_spunet(obs_space: str, output: str, dim: int = 512, point_features: str = "rgb+xyz",
                 sampling: str = "post", num_tokens: int = 2048, knn: int = 16, voxel_size: float = 0.005,
                 pretrained: str | None = None, **_: object):
    from lerobot_obsbench.encoders.pointnet import PointTokenEncoder
    from lerobot_obsbench.encoders.sparse_unet import SpUNet

    channels = input_channels(obs_space, point_features)
    backbone = SpUNet(channels, voxel_size=voxel_size)
    if pretrained:
        load_ponderv2(backbone, pretrained)
    return PointTokenEncoder(backbone, channels, output, dim=dim, sampling=sampling, num_tokens=num_tokens, knn=knn)
