"""The paper's point tokenizer around any per-point backbone (`pointnet`, `spunet34`).

A backbone is a module `(xyz (B, N, 3), features (B, N, C), mask (B, N)) -> (B, N, out_channels)` with an
`out_channels` attribute. Tokens for ACT:
- post-sampling (paper default): the backbone encodes every point, then FPS picks `num_tokens` seeds and each
  seed's `knn` nearest points are grouped as (relative xyz ‖ point feature) -> Linear -> BN -> ReLU -> max-pool:
  one token per seed;
- pre-sampling: the same grouping on the raw points (relative xyz ‖ input features -> Linear to the input
  width -> BN -> ReLU -> max-pool) gives one input point per seed; the backbone encodes those seeds and a
  linear map makes them tokens.
Each token's position is a 3D sine embedding of its seed. Global feature for Diffusion: a max-pool over the
encoded points (post) or seeds (pre), or the official tokenizer + projector (see `PointTokenEncoder`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from lerobot_obsbench import geometry
from lerobot_obsbench.encoders.registry import EncoderContext, EncoderError, EncoderOutput
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


# Normalisation layers of per-point MLPs: BatchNorm over the batch's valid points, or LayerNorm over each point's
# channels (which never mixes points or samples).
POINT_NORMS = ("batch", "layer")


def norm_relu(width: int, official: bool = False, norm: str = "batch") -> list[nn.Module]:
    """BatchNorm + ReLU: the PointNet / SpUNet norm (eps 1e-3, momentum 0.01), or PyTorch's defaults, which the
    official code's tokenizer and Diffusion Policy head use (`official=True`); `norm="layer"`: LayerNorm + ReLU."""
    if check_choice("norm", norm, POINT_NORMS) == "layer":
        layer = nn.LayerNorm(width)
    else:
        layer = nn.BatchNorm1d(width) if official else nn.BatchNorm1d(width, eps=1e-3, momentum=0.01)
    return [layer, nn.ReLU(inplace=True)]


def group(
    xyz: Tensor, mask: Tensor, num_tokens: int, knn: int, fps_start: str
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """FPS seeds (from `fps_start`, geometry.FPS_STARTS) + kNN groups: neighbour indices (B, S, k), their xyz
    relative to the seed (B, S, k, 3), seed xyz (B, S, 3) and the seed mask (B, S)."""
    seed_idx, seed_mask = geometry.farthest_point_sample(xyz, mask, num_tokens, fps_start)
    seeds = geometry.gather(xyz, seed_idx)
    neighbours = geometry.knn(seeds, xyz, mask, knn)
    return neighbours, geometry.gather(xyz, neighbours) - seeds[:, :, None], seeds, seed_mask


DP_HEAD_CHANNELS = 128  # the official Diffusion Policy point-cloud feature
GLOBAL_HEADS = ("maxpool", "official")
PIPELINES = ("plugin", "official")
# Where each pipeline's FPS starts: the official code's CUDA FPS starts every cloud at its first point, on every
# device here too; the plugin's lets CPU take QuickFPS's start, the faster one there (`geometry._fps_fpsample`).
FPS_START = {"plugin": "any", "official": "first"}


def apply_to_seeds(module: nn.Module, values: Tensor, seed_mask: Tensor, all_slots: bool) -> Tensor:
    """module over values (B, S, ..., C) of the valid seeds only (BatchNorm sees real groups), or of every slot,
    repeats included, as the official code does (`all_slots`); invalid slots are zero in the result."""
    used = torch.ones_like(seed_mask) if all_slots else seed_mask
    out = module(values[used].reshape(-1, values.shape[-1]))
    full = out.new_zeros(*values.shape[:-1], out.shape[-1])
    full[used] = out.reshape(int(used.sum()), *values.shape[2:-1], out.shape[-1])
    return full


def pool_groups(module: nn.Module, grouped: Tensor, seed_mask: Tensor, all_slots: bool = False) -> Tensor:
    """module over every grouped point (B, S, k, C), max over each group -> (B, S, D).

    Invalid seed slots (clouds with fewer points than seeds) copy the first seed's token, like the repeated
    indices of the reference CUDA FPS: ACT's decoder has no key-padding mask, so slots must hold real tokens.
    """
    pooled = apply_to_seeds(module, grouped, seed_mask, all_slots).amax(dim=2)
    return torch.where(seed_mask[..., None], pooled, pooled[:, :1])


class OfficialDiffusionHead(nn.Module):
    """The official code's Diffusion Policy point-cloud conditioning after the tokenizer: per-token MLP (Conv1d k=1
    + BN + ReLU per width), max over seeds, Conv1d + BN to `out_channels` (128)."""

    def __init__(self, width: int, widths: tuple[int, ...], out_channels: int = DP_HEAD_CHANNELS):
        super().__init__()
        layers: list[nn.Module] = []
        for w in widths:
            layers += [nn.Linear(width, w), *norm_relu(w, official=True)]
            width = w
        self.mlp = nn.Sequential(*layers)
        self.out = nn.Sequential(nn.Linear(width, out_channels), nn.BatchNorm1d(out_channels))

    def forward(self, tokens: Tensor, seed_mask: Tensor, all_slots: bool) -> Tensor:
        feats = apply_to_seeds(self.mlp, tokens, seed_mask, all_slots)
        used = torch.ones_like(seed_mask) if all_slots else seed_mask
        return self.out(feats.masked_fill(~used[..., None], float("-inf")).amax(dim=1))


@dataclass(frozen=True)
class PointTokenOptions:
    """How the point tokenizer turns per-point features into tokens: the option set every point encoder
    (`pointnet`, `spunet34`) takes, as encoder options of the same names (`encoders.registry`).

    - `sampling`: "post" (the paper's) or "pre" (see the module docstring); `num_tokens` FPS seeds of `knn`
      neighbours each.
    - `position_scale`: the token positions are the sine embedding of position_scale x seed xyz (metres); the
      official ACT code embeds raw metres (1.0), which leaves only a few channels varying over a table-top scene.
    - `pipeline="official"`: FPS starts each cloud at its first point on every device, the tokenizer's BatchNorm
      takes PyTorch's defaults and its batch statistics include the repeated slots of clouds with fewer points
      than seeds, as in the official code (`plugin`: on CPU FPS starts large clouds where QuickFPS does).
    - `global_head` (Diffusion Policy): "maxpool", a max over the encoded points (post) or seeds (pre); or
      "official", the official tokenizer + projector (see `PointTokenEncoder`).
    """

    sampling: str = "post"
    num_tokens: int = 2048
    knn: int = 16
    position_scale: float = 100.0
    pipeline: str = "plugin"
    global_head: str = "maxpool"

    def __post_init__(self) -> None:
        check_choice("sampling", self.sampling, SAMPLING)
        check_choice("pipeline", self.pipeline, PIPELINES)
        check_choice("global_head", self.global_head, GLOBAL_HEADS)
        if self.num_tokens < 1 or self.knn < 1:
            raise EncoderError(f"num_tokens and knn must be >= 1; got {self.num_tokens}, {self.knn}")
        if self.position_scale <= 0:
            raise EncoderError(f"position_scale must be > 0; got {self.position_scale}")
        if self.global_head == "official" and self.sampling != "post":
            raise EncoderError(
                "global_head='official' is the official post-sampling tokenizer + projector; "
                "use sampling='post' with it"
            )


PAPER_TOKENS = PointTokenOptions()  # the defaults: the paper's tokenizer


class PointTokenEncoder(nn.Module):
    """A per-point backbone + the point tokenizer (`tokens`: PointTokenOptions): ACT tokens (B, S, dim) with 3D
    sine positions, or one global feature for Diffusion Policy. With `global_head="official"`: `dp_projection`
    (an extra per-point Linear, PointNet's 512 -> 96), the tokenizer at the backbone's width, `dp_widths`
    per-token layers, max over seeds, 128-d."""

    def __init__(
        self,
        backbone: nn.Module,
        in_channels: int,
        output: str,
        dim: int = 512,
        tokens: PointTokenOptions = PAPER_TOKENS,
        dp_projection: int | None = None,
        dp_widths: tuple[int, ...] = (),
    ):
        super().__init__()
        sampling, pipeline = tokens.sampling, tokens.pipeline
        self.output, self.sampling, self.num_tokens, self.knn = output, sampling, tokens.num_tokens, tokens.knn
        self.position_scale, self.all_slots = tokens.position_scale, pipeline == "official"
        self.fps_start = FPS_START[pipeline]
        self.global_head = tokens.global_head if output == "global" else None
        self.backbone = backbone
        width = backbone.out_channels
        official = pipeline == "official"
        if self.global_head == "official":
            self.dp_projection = nn.Linear(width, dp_projection) if dp_projection else None
            width = dp_projection or width
            dim = width  # the official tokenizer keeps the feature width
        if sampling == "post" and (output == "tokens" or self.global_head == "official"):
            # Linear(relative xyz ‖ feature) split in two: the feature part is applied once per point before
            # grouping instead of once per (seed, neighbour) pair — the same map, ~knn times fewer FLOPs.
            self.feature_proj = nn.Linear(width, dim, bias=False)
            self.offset_proj = nn.Linear(3, dim, bias=False)
            self.group_act = nn.Sequential(*norm_relu(dim, official))
        if sampling == "pre":
            self.group_proj = nn.Sequential(
                nn.Linear(3 + in_channels, in_channels, bias=False), *norm_relu(in_channels, official)
            )
            if output == "tokens":
                self.tokenizer = nn.Linear(width, dim)
        if self.global_head == "official":
            self.head = OfficialDiffusionHead(dim, dp_widths)
        self.pos_dim = dim

    def _post_tokens(self, cloud: PointCloud, point_feats: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        neighbours, offsets, seeds, seed_mask = group(cloud.xyz, cloud.mask, self.num_tokens, self.knn, self.fps_start)
        if not self.training:
            return self._pooled_at_inference(cloud, point_feats, neighbours, seeds, seed_mask), seeds, seed_mask
        projected = geometry.gather(masked_apply(self.feature_proj, point_feats, cloud.mask), neighbours)
        return (
            pool_groups(self.group_act, projected + self.offset_proj(offsets), seed_mask, self.all_slots),
            seeds,
            seed_mask,
        )

    def _pooled_at_inference(
        self, cloud: PointCloud, point_feats: Tensor, neighbours: Tensor, seeds: Tensor, seed_mask: Tensor
    ) -> Tensor:
        """The post-sampling tokens without the (seeds x knn x dim) tensor, for inference: the same map, to float
        rounding (tested), and faster (docs/performance.md#measured-design-choices).

        A grouped point's input is feature_proj(f) + offset_proj(xyz - seed) = P[neighbour] - offset_proj(seed),
        with P = feature_proj(f) + offset_proj(xyz) computed once per point. With frozen statistics BatchNorm is
        a per-channel affine map a*x + b and ReLU is monotone, so the max over a group of ReLU(a*x + b) is
        ReLU(max(a*P[neighbour]) - a*offset_proj(seed) + b): a running max over the neighbours' rows of a*P.
        """
        norm = self.group_act[0]
        scale = norm.weight / torch.sqrt(norm.running_var + norm.eps)
        shift = norm.bias - norm.running_mean * scale
        per_point = (masked_apply(self.feature_proj, point_feats, cloud.mask) + self.offset_proj(cloud.xyz)) * scale
        pooled = geometry.gather(per_point, neighbours[..., 0])
        for j in range(1, neighbours.shape[-1]):
            pooled = torch.maximum(pooled, geometry.gather(per_point, neighbours[..., j]))
        pooled = torch.relu(pooled - self.offset_proj(seeds) * scale + shift)
        return torch.where(seed_mask[..., None], pooled, pooled[:, :1])

    def forward(self, cloud: PointCloud) -> Tensor | tuple[Tensor, Tensor]:
        if self.sampling == "post":
            point_feats = self.backbone(cloud.xyz, cloud.features, cloud.mask)
            if self.global_head == "maxpool":
                return point_feats.masked_fill(~cloud.mask[..., None], float("-inf")).amax(dim=1)
            if self.global_head == "official":
                if self.dp_projection is not None:
                    point_feats = masked_apply(self.dp_projection, point_feats, cloud.mask)
                tokens, _, seed_mask = self._post_tokens(cloud, point_feats)
                return self.head(tokens, seed_mask, self.all_slots)
            tokens, seeds, seed_mask = self._post_tokens(cloud, point_feats)
        else:
            neighbours, offsets, seeds, seed_mask = group(
                cloud.xyz, cloud.mask, self.num_tokens, self.knn, self.fps_start
            )
            grouped = torch.cat([offsets, geometry.gather(cloud.features, neighbours)], dim=-1)
            seed_feats = self.backbone(
                seeds, pool_groups(self.group_proj, grouped, seed_mask, self.all_slots), seed_mask
            )
            if self.output == "global":
                return seed_feats.masked_fill(~seed_mask[..., None], float("-inf")).amax(dim=1)
            tokens = torch.where(seed_mask[..., None], self.tokenizer(seed_feats), self.tokenizer(seed_feats[:, :1]))
        return tokens, sine_embedding_3d(seeds, self.pos_dim, scale=self.position_scale).to(tokens.dtype)


def describe_point_tokens(out_channels: int):
    """`describe` of a point encoder whose backbone outputs `out_channels` per point."""

    def describe(obs_space: str, output: str, dim: int, context: EncoderContext, options: dict) -> EncoderOutput:
        if output == "global":
            official = options.get("global_head") == "official"
            return EncoderOutput(None, DP_HEAD_CHANNELS if official else out_channels)
        return EncoderOutput(options["num_tokens"], dim)

    return describe
