"""`spunet34`: the sparse U-Net of `sparse_unet.py` with the point tokenizer, and PonderV2's checkpoints.

PonderV2 trains one set of norms per dataset ("PDNorm": `bn.bns.K.*` per condition, plus an adaptive
`bn.modulation` from a learned per-dataset context `embedding_table`). For one chosen condition that norm is an
ordinary BatchNorm followed by a constant per-channel scale and shift, which `ponderv2_to_spunet` folds into the
BatchNorm's affine parameters — an exact conversion, so the encoder itself keeps plain BatchNorm.

Only building the encoder imports spconv (`sparse_unet.py`); registering it and converting checkpoints do not.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lerobot_obsbench.encoders.point_tokenizer import (
    PAPER_TOKENS,
    PointTokenEncoder,
    PointTokenOptions,
    describe_point_tokens,
)
from lerobot_obsbench.encoders.pretrained import load_matching, read_state_dict
from lerobot_obsbench.encoders.registry import EncoderError, register_encoder
from lerobot_obsbench.schema import input_channels

PONDERV2_CONDITIONS = ("ScanNet", "S3DIS", "Structured3D")
OUT_CHANNELS = 96  # the last decoder stage's width
DP_WIDTHS = (96, 128)  # the official Diffusion Policy head's token layers


def ponderv2_to_spunet(state: dict[str, Tensor], condition: str = "ScanNet") -> dict[str, Tensor]:
    """PonderV2 checkpoint (`module.backbone.*` with PDNorm, `module.embedding_table.weight`) -> SpUNet keys,
    keeping the norms of `condition` and folding its adaptive modulation into the BatchNorm affine."""
    if condition not in PONDERV2_CONDITIONS:
        raise EncoderError(f"PonderV2 condition must be one of {PONDERV2_CONDITIONS}; got {condition!r}")
    k = PONDERV2_CONDITIONS.index(condition)
    backbone = {key[len("module.backbone.") :]: v for key, v in state.items() if key.startswith("module.backbone.")}
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
            raise EncoderError("PonderV2 checkpoint has adaptive norms but no embedding_table")
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


@register_encoder(
    "spunet34",
    ("pointcloud",),
    "sparse-conv U-Net, PonderV2 layout (paper, 39.2M); needs spconv",
    describe_point_tokens(OUT_CHANNELS),
    pretrained="PonderV2 (module.backbone.*)",
)
def build_spunet(
    obs_space: str,
    output: str,
    dim: int,
    point_features: str = "rgb+xyz",
    tokens: PointTokenOptions = PAPER_TOKENS,
    voxel_size: float = 0.005,
    pretrained: str | None = None,
) -> PointTokenEncoder:
    from lerobot_obsbench.encoders.sparse_unet import SpUNet  # spconv is needed from here on only

    channels = input_channels(obs_space, point_features)
    backbone = SpUNet(channels, voxel_size=voxel_size)
    if pretrained:
        load_ponderv2(backbone, pretrained)
    return PointTokenEncoder(
        backbone,
        channels,
        output,
        dim=dim,
        tokens=tokens,
        dp_widths=DP_WIDTHS,
    )
