"""The paper's point tokenizer (DESIGN §4) around any per-point backbone (`pointnet`, `spunet34`).

A backbone is a module `(xyz (B, N, 3), features (B, N, C), mask (B, N)) -> (B, N, out_channels)` with an
`out_channels` attribute. Tokens for ACT:
- post-sampling (paper default): the backbone encodes every point, then FPS picks `num_tokens` seeds and each
  seed's `knn` nearest points are grouped as (relative xyz ‖ point feature) -> Linear -> BN -> ReLU -> max-pool:
  one token per seed;
- pre-sampling: the same grouping on the raw points (relative xyz ‖ input features -> Linear to the input
  width -> BN -> ReLU -> max-pool) gives one input point per seed; the backbone encodes those seeds and a
  linear map makes them tokens.
Each token's position is a 3D sine embedding of its seed. Global feature for Diffusion: a max-pool over the
encoded points (post) or seeds (pre).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lerobot_obsbench import geometry
from lerobot_obsbench.encoders.registry import EncoderContext, EncoderOutput
from lerobot_obsbench.schema import SAMPLING, PointCloud, check_choice


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


def norm_relu(width: int) -> list[nn.Module]:
    return [nn.BatchNorm1d(width, eps=1e-3, momentum=0.01), nn.ReLU(inplace=True)]


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


class PointTokenEncoder(nn.Module):
    """A per-point backbone + the point tokenizer: ACT tokens (B, S, dim) with 3D sine positions, or one
    global feature (B, width) for Diffusion Policy."""

    def __init__(
        self,
        backbone: nn.Module,
        in_channels: int,
        output: str,
        dim: int = 512,
        sampling: str = "post",
        num_tokens: int = 2048,
        knn: int = 16,
    ):
        super().__init__()
        check_choice("sampling", sampling, SAMPLING)
        if num_tokens < 1 or knn < 1:
            raise ValueError(f"num_tokens and knn must be >= 1; got {num_tokens}, {knn}")
        self.output, self.sampling, self.num_tokens, self.knn = output, sampling, num_tokens, knn
        self.backbone = backbone
        width = backbone.out_channels
        if sampling == "post" and output == "tokens":
            # Linear(relative xyz ‖ feature) split in two: the feature part is applied once per point before
            # grouping instead of once per (seed, neighbour) pair — the same map, ~knn times fewer FLOPs.
            self.feature_proj = nn.Linear(width, dim, bias=False)
            self.offset_proj = nn.Linear(3, dim, bias=False)
            self.group_act = nn.Sequential(*norm_relu(dim))
        if sampling == "pre":
            self.group_proj = nn.Sequential(
                nn.Linear(3 + in_channels, in_channels, bias=False), *norm_relu(in_channels)
            )
            if output == "tokens":
                self.tokenizer = nn.Linear(width, dim)
        self.pos_dim = dim

    def forward(self, cloud: PointCloud) -> Tensor | tuple[Tensor, Tensor]:
        if self.sampling == "post":
            point_feats = self.backbone(cloud.xyz, cloud.features, cloud.mask)
            if self.output == "global":
                return point_feats.masked_fill(~cloud.mask[..., None], float("-inf")).amax(dim=1)
            neighbours, offsets, seeds, seed_mask = group(cloud.xyz, cloud.mask, self.num_tokens, self.knn)
            projected = geometry.gather(masked_apply(self.feature_proj, point_feats, cloud.mask), neighbours)
            tokens = pool_groups(self.group_act, projected + self.offset_proj(offsets), seed_mask)
        else:
            neighbours, offsets, seeds, seed_mask = group(cloud.xyz, cloud.mask, self.num_tokens, self.knn)
            grouped = torch.cat([offsets, geometry.gather(cloud.features, neighbours)], dim=-1)
            seed_feats = self.backbone(seeds, pool_groups(self.group_proj, grouped, seed_mask), seed_mask)
            if self.output == "global":
                return seed_feats.masked_fill(~seed_mask[..., None], float("-inf")).amax(dim=1)
            tokens = torch.where(seed_mask[..., None], self.tokenizer(seed_feats), self.tokenizer(seed_feats[:, :1]))
        return tokens, sine_embedding_3d(seeds, self.pos_dim).to(tokens.dtype)


def describe_point_tokens(out_channels: int):
    """`describe` of a point encoder whose backbone outputs `out_channels` per point."""

    def describe(obs_space: str, output: str, dim: int, context: EncoderContext, options: dict) -> EncoderOutput:
        if output == "global":
            return EncoderOutput(None, out_channels)
        return EncoderOutput(options["num_tokens"], dim)

    return describe
