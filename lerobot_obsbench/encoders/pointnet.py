"""PointNet encoder and the point tokenizer (DESIGN §4).

PointNet here is a shared per-point MLP 64-64-64-128-512 with BatchNorm, applied to the valid points only
(padding never enters the BatchNorm statistics). That is exactly the paper's kernel-1 convolution over voxels:
a 1x1 convolution is a per-point linear map, and voxel sampling already left one point per voxel.

Tokens for ACT:
- post-sampling (paper default): encode every point, then FPS `num_tokens` seeds, group each seed's `knn`
  nearest points as (relative xyz ‖ point feature) -> Linear -> BN -> ReLU -> max-pool: one token per seed;
- pre-sampling: the same grouping on the raw points (relative xyz ‖ input features), the PointNet MLP on every
  grouped point, max-pool, then a linear projection to the token size.
Each token's position is a 3D sine embedding of its seed. Global feature for Diffusion: a max-pool over all
encoded points (post) or over the seed tokens (pre).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lerobot_obsbench import geometry
from lerobot_obsbench.encoders.registry import register_encoder
from lerobot_obsbench.spaces import PointCloud, input_channels

POINTNET_WIDTHS = (64, 64, 64, 128, 512)
SAMPLING = ("post", "pre")


def masked_apply(module: nn.Module, x: Tensor, mask: Tensor) -> Tensor:
    """Run `module` on the entries x[mask] (so BatchNorm sees real points only); zeros elsewhere."""
    out = module(x[mask])
    full = out.new_zeros(*mask.shape, out.shape[-1])
    full[mask] = out
    return full


def sine_embedding_3d(xyz: Tensor, dim: int, temperature: float = 10000.0, scale: float = 100.0) -> Tensor:
    """Sine/cosine embedding (…, dim) of 3D positions in metres (`scale` maps 1 cm to one radian unit).

    Each axis gets dim // 6 frequency pairs; leftover channels are zero.
    """
    n_freq = dim // 6
    freqs = temperature ** (-torch.arange(n_freq, device=xyz.device, dtype=xyz.dtype) / max(n_freq, 1))
    angles = (xyz * scale)[..., None] * freqs  # (…, 3, n_freq)
    emb = torch.cat([angles.sin(), angles.cos()], dim=-1).flatten(-2)  # (…, 6 * n_freq)
    return nn.functional.pad(emb, (0, dim - emb.shape[-1]))


def shared_mlp(in_channels: int, widths: tuple[int, ...] = POINTNET_WIDTHS) -> nn.Sequential:
    layers: list[nn.Module] = []
    for width in widths:
        layers += [nn.Linear(in_channels, width), nn.BatchNorm1d(width), nn.ReLU(inplace=True)]
        in_channels = width
    return nn.Sequential(*layers)


def group(xyz: Tensor, mask: Tensor, num_tokens: int, knn: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """FPS seeds + kNN groups: neighbour indices (B, S, k), their xyz relative to the seed (B, S, k, 3), seed xyz
    (B, S, 3) and the seed mask (B, S)."""
    seed_idx, seed_mask = geometry.farthest_point_sample(xyz, mask, num_tokens)
    seeds = geometry.gather(xyz, seed_idx)
    neighbours = geometry.knn(seeds, xyz, mask, knn)
    return neighbours, geometry.gather(xyz, neighbours) - seeds[:, :, None], seeds, seed_mask


def pool_groups(module: nn.Module, grouped: Tensor, seed_mask: Tensor) -> Tensor:
    """module over every grouped point of valid seeds (so BatchNorm sees real groups only), max over each
    group -> (B, S, D).

    Invalid seed slots (clouds with fewer points than seeds) copy the first seed's token, like the repeated
    indices of the reference CUDA FPS: ACT's decoder has no key-padding mask, so slots must hold real tokens.
    """
    b, s, k, c = grouped.shape
    flat = module(grouped[seed_mask].reshape(-1, c))  # (P*k, D)
    pooled = flat.reshape(-1, k, flat.shape[-1]).amax(dim=1)
    tokens = pooled.new_zeros(b, s, pooled.shape[-1])
    tokens[seed_mask] = pooled
    return torch.where(seed_mask[..., None], tokens, tokens[:, :1])


class PointNetEncoder(nn.Module):
    def __init__(self, in_channels: int, output: str, dim: int = 512, sampling: str = "post",
                 num_tokens: int = 2048, knn: int = 16):
        super().__init__()
        if sampling not in SAMPLING:
            raise ValueError(f"sampling must be one of {SAMPLING}; got {sampling!r}")
        if num_tokens < 1 or knn < 1:
            raise ValueError(f"num_tokens and knn must be >= 1; got {num_tokens}, {knn}")
        self.output, self.sampling, self.num_tokens, self.knn = output, sampling, num_tokens, knn
        width = POINTNET_WIDTHS[-1]
        if sampling == "post":
            self.backbone = shared_mlp(in_channels)
            if output == "tokens":
                # Linear(relative xyz ‖ feature) split in two: the feature part is applied once per point before
                # grouping instead of once per (seed, neighbour) pair — the same map, ~knn times fewer FLOPs.
                self.feature_proj = nn.Linear(width, dim)
                self.offset_proj = nn.Linear(3, dim, bias=False)
                self.group_act = nn.Sequential(nn.BatchNorm1d(dim), nn.ReLU(inplace=True))
        else:
            self.backbone = shared_mlp(3 + in_channels)
            if output == "tokens":
                self.tokenizer = nn.Linear(width, dim)
        self.out_dim = dim if output == "tokens" else width
        self.pos_dim = dim

    def forward(self, cloud: PointCloud) -> Tensor | tuple[Tensor, Tensor]:
        if self.sampling == "post":
            point_feats = masked_apply(self.backbone, cloud.features, cloud.mask)
            if self.output == "global":
                return point_feats.masked_fill(~cloud.mask[..., None], float("-inf")).amax(dim=1)
            neighbours, offsets, seeds, seed_mask = group(cloud.xyz, cloud.mask, self.num_tokens, self.knn)
            projected = geometry.gather(masked_apply(self.feature_proj, point_feats, cloud.mask), neighbours)
            tokens = pool_groups(self.group_act, projected + self.offset_proj(offsets), seed_mask)
        else:
            neighbours, offsets, seeds, seed_mask = group(cloud.xyz, cloud.mask, self.num_tokens, self.knn)
            grouped = torch.cat([offsets, geometry.gather(cloud.features, neighbours)], dim=-1)
            group_feats = pool_groups(self.backbone, grouped, seed_mask)
            if self.output == "global":
                return group_feats.amax(dim=1)
            tokens = self.tokenizer(group_feats)
        return tokens, sine_embedding_3d(seeds, self.pos_dim).to(tokens.dtype)


@register_encoder("pointnet", ("pointcloud",), "PointNet shared MLP 64-64-64-128-512 with BN (paper, 0.14M)")
def build_pointnet(obs_space: str, output: str, dim: int = 512, point_features: str = "rgb+xyz",
                   sampling: str = "post", num_tokens: int = 2048, knn: int = 16, **_: object) -> PointNetEncoder:
    return PointNetEncoder(input_channels(obs_space, point_features), output, dim=dim, sampling=sampling,
                           num_tokens=num_tokens, knn=knn)

