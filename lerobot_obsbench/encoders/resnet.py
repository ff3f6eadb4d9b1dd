"""torchvision ResNet image encoders for rgb, depth, rgbd and pointmap inputs (1, 3, 4 or 6 channels)."""

from __future__ import annotations

from pathlib import Path

import torch
import torchvision
from lerobot.policies.act.modeling_act import ACTSinusoidalPositionEmbedding2d
from torch import Tensor, nn

from lerobot_obsbench.encoders.registry import register_encoder
from lerobot_obsbench.spaces import input_channels

IMAGE_SPACES = ("rgb", "depth", "rgbd", "pointmap")
IMAGENET_WEIGHTS = {"resnet18": "ResNet18_Weights.IMAGENET1K_V1", "resnet50": "ResNet50_Weights.IMAGENET1K_V2"}


def load_torchvision_state_dict(pretrained: str, arch: str) -> dict[str, Tensor]:
    """State dict of `pretrained`: "imagenet" (downloads torchvision's weights: asked for explicitly) or a
    local file holding a torchvision-layout state dict (optionally under a "state_dict" key)."""
    if pretrained == "imagenet":
        weights = torchvision.models.get_weight(IMAGENET_WEIGHTS[arch])
        try:
            return weights.get_state_dict(progress=False)
        except OSError as err:  # URLError is an OSError: no network, proxy refused...
            raise RuntimeError(
                f"Could not download torchvision's ImageNet weights for {arch} ({err}). On an offline machine, "
                f"save them elsewhere and pass the file: --policy.pretrained=/path/to/{arch}.pth"
            ) from err
    path = Path(pretrained)
    if not path.is_file():
        raise FileNotFoundError(
            f"pretrained={pretrained!r} is neither 'imagenet' nor an existing checkpoint file for {arch}."
        )
    state = torch.load(path, map_location="cpu", weights_only=True)
    return state.get("state_dict", state)


def expand_stem(weight: Tensor, in_channels: int) -> Tensor:
    """Adapt a pretrained RGB stem (out, 3, k, k) to `in_channels`.

    Extra channels (depth, xyz) start at zero so the pretrained RGB response is unchanged at initialisation,
    as in the paper. A single-channel (depth-only) input gets the mean of the RGB filters instead, since an
    all-zero stem would make the whole network blind.
    """
    out, _, kh, kw = weight.shape
    if in_channels == 1:
        return weight.mean(dim=1, keepdim=True)
    new = weight.new_zeros(out, in_channels, kh, kw)
    new[:, :3] = weight
    return new


class ResNetEncoder(nn.Module):
    def __init__(self, arch: str, in_channels: int, output: str, dim: int = 512, pretrained: str | None = None):
        super().__init__()
        net = getattr(torchvision.models, arch)(weights=None)
        if pretrained:
            state = {k: v for k, v in load_torchvision_state_dict(pretrained, arch).items() if not k.startswith("fc.")}
            state["conv1.weight"] = expand_stem(state["conv1.weight"], in_channels)
        net.conv1 = nn.Conv2d(in_channels, 64, kernel_size=7, stride=2, padding=3, bias=False)
        if pretrained:
            missing, unexpected = net.load_state_dict(state, strict=False)
            missing = [k for k in missing if not k.startswith("fc.")]
            if missing or unexpected:
                raise ValueError(f"{arch} checkpoint {pretrained!r}: missing keys {missing}, unexpected {unexpected}")
        feature_channels = net.fc.in_features
        self.body = nn.Sequential(*list(net.children())[:-2])  # up to layer4: (B, C, H/32, W/32)
        self.output = output
        if output == "tokens":
            self.proj = nn.Conv2d(feature_channels, dim, kernel_size=1)
            self.pos = ACTSinusoidalPositionEmbedding2d(dim // 2)
            self.out_dim = dim
        else:
            self.out_dim = feature_channels

    def forward(self, images: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """images (B, n_cam, C, H, W) -> tokens (B, n_cam*h*w, D) + pos (1, n_cam*h*w, D), or (B, n_cam*C')."""
        b, n_cam = images.shape[:2]
        fmap = self.body(images.flatten(0, 1))
        if self.output == "global":
            return fmap.mean(dim=(2, 3)).reshape(b, -1)
        pos = self.pos(fmap).flatten(2).transpose(1, 2).repeat(1, n_cam, 1)
        tokens = self.proj(fmap).flatten(2).transpose(1, 2)  # (B*n, h*w, D)
        return tokens.reshape(b, -1, tokens.shape[-1]), pos.to(tokens.dtype)


def _builder(arch: str):
    def build(obs_space: str, output: str, dim: int = 512, pretrained: str | None = None, **_: object):
        return ResNetEncoder(arch, input_channels(obs_space), output, dim=dim, pretrained=pretrained)

    return build


register_encoder("resnet18", IMAGE_SPACES, "torchvision ResNet-18 (CPU presets); layer4 map -> tokens / pooled")(
    _builder("resnet18")
)
register_encoder("resnet50", IMAGE_SPACES, "torchvision ResNet-50 (paper, 23.5M); layer4 map -> tokens / pooled")(
    _builder("resnet50")
)
