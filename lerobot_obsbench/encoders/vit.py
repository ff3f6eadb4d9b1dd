"""ViT-B/16 (`vit_b`) and MultiMAE-style MultiViT-B (`multivit_b`) image encoders, built from timm's blocks.

Both represent a camera frame by one token: ViT's [CLS] token (after the final norm), MultiViT's global token.
ACT gets that token per camera projected to its width (positions: a sine code of the camera index); Diffusion
Policy gets the concatenated tokens of all cameras.

- `vit_b`: timm's VisionTransformer, 1/3/4/6 input channels (rgb, depth, rgbd, pointmap), built for the camera
  resolution (frames whose size is not a multiple of 16 are zero-padded, in both encoders). `pretrained=` loads
  a MAE-layout checkpoint such as VC-1's (`cls_token`, `pos_embed`, `patch_embed.*`, `blocks.*`, `norm.*`; MAE's
  decoder keys are dropped): the position embedding is resampled to the camera's patch grid and extra input
  channels start at zero.
- `multivit_b`: rgbd only. One patch adapter per modality (rgb: 3 channels, depth: 1), each with a fixed 2-D
  sine-cosine position map interpolated to the patch grid; patch tokens of both modalities plus one learned
  global token go through 12 transformer blocks. Keys follow MultiMAE's layout (`input_adapters.{rgb,depth}.*`,
  `global_tokens`, `encoder.N.*`), so a MultiMAE checkpoint loads as is (other adapters and the decoders are
  ignored).
"""

from __future__ import annotations

from functools import partial

import torch
import torch.nn.functional as F
from lerobot.policies.act.modeling_act import create_sinusoidal_pos_embedding
from torch import Tensor, nn

from lerobot_obsbench.encoders.image_input import as_frame_size, resize_center_crop, zero_extra_channels
from lerobot_obsbench.encoders.pretrained import expand_input_channels, load_matching, read_state_dict
from lerobot_obsbench.encoders.registry import EncoderContext, EncoderOutput, register_encoder
from lerobot_obsbench.schema import input_channels, single_spaces

WIDTH, DEPTH, HEADS, PATCH = 768, 12, 12, 16


class _CameraTokens(nn.Module):
    """One feature per camera -> ACT tokens (B, n_cam, dim) + positions, or DP's (B, n_cam * width)."""

    def __init__(self, width: int, output: str, dim: int):
        super().__init__()
        self.output = output
        self.proj = nn.Linear(width, dim) if output == "tokens" else None

    def forward(self, features: Tensor, batch: int) -> Tensor | tuple[Tensor, Tensor]:
        features = features.reshape(batch, -1, features.shape[-1])
        if self.output == "global":
            return features.flatten(1)
        tokens = self.proj(features)
        pos = create_sinusoidal_pos_embedding(tokens.shape[1], tokens.shape[2])[None]
        return tokens, pos.to(device=tokens.device, dtype=tokens.dtype)


class ViTEncoder(nn.Module):
    """timm's ViT-B/16 built for `image_size`, or, with `input_size`, for the official pipeline's input: frames
    resized (bicubic) to 256/224 of it and centre-cropped to input_size (224: 196 patches)."""

    def __init__(
        self,
        in_channels: int,
        output: str,
        dim: int = 512,
        pretrained: str | None = None,
        image_size: tuple[int, int] = (224, 224),
        input_size: int | None = None,
        zero_extra: bool = False,
    ):
        super().__init__()
        from timm.models.vision_transformer import VisionTransformer

        self.input_size = input_size
        if input_size:
            image_size = (input_size, input_size)

        self.vit = VisionTransformer(
            img_size=image_size,
            patch_size=PATCH,
            in_chans=in_channels,
            num_classes=0,
            embed_dim=WIDTH,
            depth=DEPTH,
            num_heads=HEADS,
            global_pool="token",
            dynamic_img_size=True,
            dynamic_img_pad=True,
        )
        if zero_extra:
            zero_extra_channels(self.vit.patch_embed.proj.weight)
        if pretrained:
            self.load_mae(pretrained)
        self.head = _CameraTokens(WIDTH, output, dim)

    def load_mae(self, pretrained: str) -> dict:
        from timm.layers import resample_abs_pos_embed

        state = read_state_dict(pretrained)  # MAE's decoder keys are not the encoder's: reported as ignored
        grid = self.vit.patch_embed.grid_size
        if "pos_embed" in state and state["pos_embed"].shape != self.vit.pos_embed.shape:
            state["pos_embed"] = resample_abs_pos_embed(state["pos_embed"], new_size=list(grid), num_prefix_tokens=1)
        weight = state.get("patch_embed.proj.weight")
        if weight is not None and weight.shape[1] == 3:
            state["patch_embed.proj.weight"] = expand_input_channels(weight, self.vit.patch_embed.proj.in_channels)
        return load_matching(self.vit, state, f"MAE/VC-1 checkpoint {pretrained}")

    def forward(self, images: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """images (B, n_cam, C, H, W) -> ACT tokens + pos, or (B, n_cam * 768)."""
        frames = images.flatten(0, 1)
        frames = resize_center_crop(frames, self.input_size) if self.input_size else frames
        return self.head(self.vit(frames), images.shape[0])


def sincos_2d(h: int, w: int, dim: int) -> Tensor:
    """Fixed 2-D sine-cosine position map (1, dim, h, w): a quarter of the channels per sin/cos of x and y."""
    quarter = dim // 4
    omega = 1.0 / 10000 ** (torch.arange(quarter, dtype=torch.float32) / quarter)
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    ox, oy = xs.reshape(-1, 1) * omega, ys.reshape(-1, 1) * omega
    code = torch.cat([ox.sin(), ox.cos(), oy.sin(), oy.cos()], dim=1)  # (h*w, dim)
    return code.T.reshape(1, dim, h, w)


class PatchAdapter(nn.Module):
    """Patches of one modality -> tokens with an interpolated fixed position map (MultiMAE's adapter layout)."""

    def __init__(self, channels: int, grid: int = 14):
        super().__init__()
        self.proj = nn.Conv2d(channels, WIDTH, kernel_size=PATCH, stride=PATCH)
        self.pos_emb = nn.Parameter(sincos_2d(grid, grid, WIDTH), requires_grad=False)

    def forward(self, x: Tensor) -> Tensor:
        tokens = self.proj(x)
        pos = F.interpolate(self.pos_emb, size=tokens.shape[-2:], mode="bicubic", align_corners=False)
        return (tokens + pos).flatten(2).transpose(1, 2)


def standardize_depth(depth: Tensor, low: float = 0.1, high: float = 0.9) -> Tensor:
    """The official MultiViT depth input: standardised by the mean / std of the batch's depth values between
    their 10th and 90th percentiles."""
    flat = depth.detach().flatten().float()
    lo, hi = torch.quantile(flat, torch.tensor([low, high], device=flat.device))
    kept = flat[(flat >= lo) & (flat <= hi)]
    return (depth - kept.mean()) / kept.std().clamp_min(1e-6)


class MultiViTEncoder(nn.Module):
    """MultiMAE-style MultiViT-B. `input_size`: the official pipeline's resize + centre crop (224: 2 x 196
    patches); `depth_standardize`: the official depth standardisation (`standardize_depth`)."""

    def __init__(
        self,
        output: str,
        dim: int = 512,
        pretrained: str | None = None,
        input_size: int | None = None,
        depth_standardize: bool = False,
    ):
        super().__init__()
        from timm.models.vision_transformer import Block

        self.input_size, self.depth_standardize = input_size, depth_standardize
        self.input_adapters = nn.ModuleDict({"rgb": PatchAdapter(3), "depth": PatchAdapter(1)})
        self.global_tokens = nn.Parameter(torch.zeros(1, 1, WIDTH))
        nn.init.trunc_normal_(self.global_tokens, std=0.02)
        norm = partial(nn.LayerNorm, eps=1e-6)
        self.encoder = nn.Sequential(
            *[Block(WIDTH, HEADS, mlp_ratio=4.0, qkv_bias=True, norm_layer=norm) for _ in range(DEPTH)]
        )
        self.head = _CameraTokens(WIDTH, output, dim)
        if pretrained:
            self.load_multimae(pretrained)

    def load_multimae(self, pretrained: str) -> dict:
        state = read_state_dict(pretrained)  # other modalities' adapters and the decoders are reported as ignored
        return load_matching(self, state, f"MultiMAE checkpoint {pretrained}", allow_missing=("head.",))

    def forward(self, images: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """rgbd images (B, n_cam, 4, H, W) -> one global token per camera (ACT tokens or DP features)."""
        x = images.flatten(0, 1)
        if self.input_size:
            x = resize_center_crop(x, self.input_size)
        if self.depth_standardize:
            x = torch.cat([x[:, :3], standardize_depth(x[:, 3:4])], dim=1)
        x = F.pad(x, (0, -x.shape[-1] % PATCH, 0, -x.shape[-2] % PATCH))  # sizes not divisible by 16: pad
        tokens = torch.cat(
            [
                self.input_adapters["rgb"](x[:, :3]),
                self.input_adapters["depth"](x[:, 3:4]),
                self.global_tokens.expand(x.shape[0], -1, -1),
            ],
            dim=1,
        )
        return self.head(self.encoder(tokens)[:, -1], images.shape[0])


def describe_camera_tokens(
    obs_space: str, output: str, dim: int, context: EncoderContext, options: dict
) -> EncoderOutput:
    """One token per camera (ACT), or the cameras' features concatenated (Diffusion Policy)."""
    return EncoderOutput(context.cameras, dim) if output == "tokens" else EncoderOutput(None, context.cameras * WIDTH)


@register_encoder(
    "vit_b",
    single_spaces(lambda s: s.image),
    "ViT-B/16 (paper, 85.8M); [CLS] token",
    describe_camera_tokens,
    pretrained="VC-1 / MAE layout",
)
def build_vit(
    obs_space: str,
    output: str,
    dim: int,
    pretrained: str | None = None,
    image_size: int | tuple[int, int] = 224,
    input_size: int | None = None,
    zero_extra_channels: bool = False,
) -> ViTEncoder:
    """`image_size`: the camera frame size (height, width) or one side; the patch grid is built for it, or for
    `input_size` (the official resize + centre crop) when given."""
    size = as_frame_size(image_size)
    return ViTEncoder(
        input_channels(obs_space),
        output,
        dim=dim,
        pretrained=pretrained,
        image_size=size,
        input_size=input_size,
        zero_extra=zero_extra_channels,
    )


@register_encoder(
    "multivit_b",
    ("rgbd",),
    "MultiMAE-style MultiViT-B (paper, 86.1M); rgb + depth patch adapters, global token",
    describe_camera_tokens,
    pretrained="MultiMAE",
)
def build_multivit(
    obs_space: str,
    output: str,
    dim: int,
    pretrained: str | None = None,
    input_size: int | None = None,
    depth_standardize: bool = False,
) -> MultiViTEncoder:
    return MultiViTEncoder(
        output, dim=dim, pretrained=pretrained, input_size=input_size, depth_standardize=depth_standardize
    )
