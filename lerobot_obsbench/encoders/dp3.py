"""`dp3`: the compact point encoder of 3D Diffusion Policy (DP3; Ze et al., RSS 2024), beyond the paper.

DP3 conditions its policy on one 64-d vector from a deliberately small PointNet: a shared per-point MLP, a max
over the points and a projection. It is the compact end of the point encoders (59k parameters on xyz, 207k on
rgb+xyz; the `pointnet` backbone has 84k and `spunet34` 39M, before their tokenizer) and reads the cloud through
one global max, with no grouping or per-point tokens. The layout follows DP3's `pointnet_extractor.py` with the
settings of its `dp3.yaml` (`use_layernorm: true`, `final_norm: layernorm`, `encoder_output_dim: 64`):
- `point_features="xyz"` (DP3's default, `use_pc_color: false`; `PointNetEncoderXYZ`): Linear + LayerNorm + ReLU
  3 -> 64 -> 128 -> 256, max over the points, Linear 256 -> 64 + LayerNorm: 59,072 parameters;
- `point_features="rgb+xyz"` (`use_pc_color: true`; `PointNetEncoderXYZRGB`): Linear + LayerNorm + ReLU
  6 -> 64 -> 128 -> 256, then a bare Linear 256 -> 512 (no norm or ReLU, as in DP3), max, Linear 512 -> 64 +
  LayerNorm: 207,232 parameters. DP3 has no colour-only variant: `point_features="rgb"` is refused.
Per-point LayerNorm, unlike BatchNorm, never mixes points, so padding cannot leak into real points; the max
ignores padded points. Points: DP3 farthest-point-samples each cloud to a fixed count (512 in its Adroit and
MetaWorld task configs, 1024 for DexArt and its real-robot tasks); here that count is the `num_tokens` option
(the config's `num_tokens`, "the number of FPS seeds"; set --policy.num_tokens=512 for DP3's simulation setting):
FPS picks that many of the voxel-sampled cloud's points, and a cloud with fewer points is used whole.

Outputs: Diffusion Policy gets the 64-d feature (DP3's conditioning); ACT gets it as one token, a Linear to the
model width, with one learned position.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lerobot_obsbench import geometry
from lerobot_obsbench.encoders.point_tokenizer import POINT_NORMS, masked_apply
from lerobot_obsbench.encoders.registry import EncoderContext, EncoderError, EncoderOutput, register_encoder
from lerobot_obsbench.schema import PointCloud, input_channels, single_spaces

# DP3's per-point widths (`block_channel`) per point-feature choice, and whether the last layer is a bare Linear.
DP3_WIDTHS = {"xyz": (64, 128, 256), "rgb+xyz": (64, 128, 256, 512)}
DP3_BARE_LAST = {"xyz": False, "rgb+xyz": True}
OUT_CHANNELS = 64  # DP3's `encoder_output_dim`
DP3_NUM_POINTS = 512  # DP3's Adroit / MetaWorld point count (the builder's default; the config passes num_tokens)


def check_point_features(point_features: str) -> str:
    if point_features not in DP3_WIDTHS:
        raise EncoderError(
            f"encoder 'dp3' encodes xyz (DP3's PointNetEncoderXYZ) or rgb+xyz (PointNetEncoderXYZRGB) points; "
            f"got point_features={point_features!r} (choose one of {', '.join(DP3_WIDTHS)})"
        )
    return point_features


class DP3Encoder(nn.Module):
    """PointCloud -> DP3's 64-d feature (B, 64), or one ACT token (B, 1, dim) + its learned position (1, 1, dim)."""

    def __init__(
        self, point_features: str, output: str, dim: int = 512, num_points: int = DP3_NUM_POINTS, norm: str = "layer"
    ):
        super().__init__()
        check_point_features(point_features)
        if num_points < 1:
            raise EncoderError(f"num_tokens (the points DP3 samples) must be >= 1; got {num_points}")
        self.output, self.num_points, self.norm = output, num_points, norm
        norm_layer = nn.LayerNorm if norm == "layer" else nn.BatchNorm1d
        in_channels = input_channels("pointcloud", point_features)
        widths = DP3_WIDTHS[point_features]
        layers: list[nn.Module] = []
        for i, width in enumerate(widths):
            layers.append(nn.Linear(in_channels, width))
            if not (DP3_BARE_LAST[point_features] and i == len(widths) - 1):
                layers += [norm_layer(width), nn.ReLU()]
            in_channels = width
        self.mlp = nn.Sequential(*layers)
        self.projection = nn.Sequential(nn.Linear(in_channels, OUT_CHANNELS), norm_layer(OUT_CHANNELS))
        if output == "tokens":
            self.token = nn.Linear(OUT_CHANNELS, dim)
            self.pos = nn.Parameter(torch.zeros(1, 1, dim))
            nn.init.normal_(self.pos, std=0.02)

    def sample(self, cloud: PointCloud) -> tuple[Tensor, Tensor]:
        """DP3's FPS down-sampling: features (B, M, C) of at most `num_points` points per cloud, and their mask."""
        if cloud.features.shape[1] <= self.num_points:
            return cloud.features, cloud.mask
        # beyond the paper, so no seeds to match: CPU may start large clouds where QuickFPS does, the faster start
        idx, mask = geometry.farthest_point_sample(cloud.xyz, cloud.mask, self.num_points, start="any")
        return geometry.gather(cloud.features, idx), mask

    def forward(self, cloud: PointCloud) -> Tensor | tuple[Tensor, Tensor]:
        features, mask = self.sample(cloud)
        # per point: padding changes no real point's value (BatchNorm sees the valid points only)
        per_point = self.mlp(features) if self.norm == "layer" else masked_apply(self.mlp, features, mask)
        pooled = per_point.masked_fill(~mask[..., None], float("-inf")).amax(dim=1)
        feature = self.projection(pooled)
        if self.output == "global":
            return feature
        token = self.token(feature)[:, None]
        return token, self.pos.to(token.dtype)


def describe_dp3(obs_space: str, output: str, dim: int, context: EncoderContext, options: dict) -> EncoderOutput:
    """One token of width `dim` (ACT), or DP3's 64-d feature (Diffusion Policy)."""
    check_point_features(options["point_features"])
    return EncoderOutput(1, dim) if output == "tokens" else EncoderOutput(None, OUT_CHANNELS)


@register_encoder(
    "dp3",
    single_spaces(lambda s: s.points),
    "DP3's compact PointNet (3D Diffusion Policy): per-point MLP + LayerNorm, max-pool, 64-d (59.1k on xyz)",
    describe_dp3,
    choices={"norm": POINT_NORMS},
)
def build_dp3(
    obs_space: str,
    output: str,
    dim: int,
    point_features: str = "xyz",
    num_tokens: int = DP3_NUM_POINTS,
    norm: str | None = None,
) -> DP3Encoder:
    """`num_tokens`: the points FPS keeps per cloud (DP3: 512 or 1024); `point_features`: xyz (DP3's default) or
    rgb+xyz; `norm`: DP3's LayerNorm (None, "layer") or BatchNorm ("batch") after each layer."""
    return DP3Encoder(point_features, output, dim=dim, num_points=num_tokens, norm=norm or "layer")
