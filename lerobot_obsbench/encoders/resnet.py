"""torchvision ResNet image encoders for rgb, depth, rgbd and pointmap inputs (1, 3, 4 or 6 channels)."""

from __future__ import annotations

import math

import torchvision
from lerobot.policies.act.modeling_act import ACTSinusoidalPositionEmbedding2d
from torch import Tensor, nn

from lerobot_obsbench.encoders.image_input import resize, zero_extra_channels
from lerobot_obsbench.encoders.pretrained import (
    CheckpointError,
    expand_input_channels,
    load_matching,
    read_state_dict,
    strip_prefix,
)
from lerobot_obsbench.encoders.registry import EncoderContext, EncoderOutput, register_encoder
from lerobot_obsbench.schema import input_channels, single_spaces

R3M_PREFIX = "module.convnet."
FEATURE_CHANNELS = {"resnet18": 512, "resnet50": 2048}  # layer4's channels
STRIDE = 32  # layer4's total downsampling
IMAGENET_WEIGHTS = {"resnet18": "ResNet18_Weights.IMAGENET1K_V1", "resnet50": "ResNet50_Weights.IMAGENET1K_V2"}


def resnet_state_dict(pretrained: str, arch: str) -> tuple[dict[str, Tensor], str]:
    """(torchvision-layout state dict without `fc.`, source name) of `pretrained`: "imagenet" (downloads
    torchvision's weights: asked for explicitly), or a checkpoint file / Hub file in torchvision's layout or
    R3M's official one (`module.convnet.*`, R3M -> resnet50)."""
    if pretrained == "imagenet":
        weights = torchvision.models.get_weight(IMAGENET_WEIGHTS[arch])
        try:
            state, source = weights.get_state_dict(progress=False), f"torchvision ImageNet {arch}"
        except OSError as err:  # URLError is an OSError: no network, proxy refused...
            raise CheckpointError(
                f"Could not download torchvision's ImageNet weights for {arch} ({err}). On an offline machine, "
                f"save them elsewhere and pass the file: --policy.pretrained=/path/to/{arch}.pth"
            ) from err
    else:
        state, source = read_state_dict(pretrained), str(pretrained)
        if any(k.startswith(R3M_PREFIX) for k in state):
            state, source = strip_prefix(state, R3M_PREFIX), f"R3M checkpoint {pretrained}"
    return {k: v for k, v in state.items() if not k.startswith("fc.")}, source


class ResNetEncoder(nn.Module):
    """A torchvision ResNet up to layer4. `input_size`: frames are resized to it first (the official pipeline
    feeds 224 px, 7x7 = 49 tokens per camera); `zero_extra_channels`: the stem's non-RGB channels start at zero
    also when training from scratch (pretrained stems always start them at zero)."""

    def __init__(
        self,
        arch: str,
        in_channels: int,
        output: str,
        dim: int = 512,
        pretrained: str | None = None,
        input_size: int | None = None,
        zero_extra: bool = False,
    ):
        super().__init__()
        net = getattr(torchvision.models, arch)(weights=None)
        net.conv1 = nn.Conv2d(in_channels, 64, kernel_size=7, stride=2, padding=3, bias=False)
        if zero_extra:
            zero_extra_channels(net.conv1.weight)
        if pretrained:
            state, source = resnet_state_dict(pretrained, arch)
            if "conv1.weight" in state and state["conv1.weight"].shape[1] == 3:
                state["conv1.weight"] = expand_input_channels(state["conv1.weight"], in_channels)
            load_matching(net, state, source, allow_missing=("fc.",))
        self.body = nn.Sequential(*list(net.children())[:-2])  # up to layer4: (B, C, H/STRIDE, W/STRIDE)
        self.output, self.input_size = output, input_size
        if output == "tokens":
            self.proj = nn.Conv2d(FEATURE_CHANNELS[arch], dim, kernel_size=1)
            self.pos = ACTSinusoidalPositionEmbedding2d(dim // 2)

    def forward(self, images: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """images (B, n_cam, C, H, W) -> tokens (B, n_cam*h*w, D) + pos (1, n_cam*h*w, D), or (B, n_cam*C')."""
        b, n_cam = images.shape[:2]
        frames = images.flatten(0, 1)
        fmap = self.body(resize(frames, self.input_size) if self.input_size else frames)
        if self.output == "global":
            return fmap.mean(dim=(2, 3)).reshape(b, -1)
        pos = self.pos(fmap).flatten(2).transpose(1, 2).repeat(1, n_cam, 1)
        tokens = self.proj(fmap).flatten(2).transpose(1, 2)  # (B*n, h*w, D)
        return tokens.reshape(b, -1, tokens.shape[-1]), pos.to(tokens.dtype)


def _describer(arch: str):
    def describe(obs_space: str, output: str, dim: int, context: EncoderContext, options: dict) -> EncoderOutput:
        if output == "global":
            return EncoderOutput(None, context.cameras * FEATURE_CHANNELS[arch])
        height, width = (options["input_size"],) * 2 if options.get("input_size") else context.image_size
        return EncoderOutput(context.cameras * math.ceil(height / STRIDE) * math.ceil(width / STRIDE), dim)

    return describe


def _builder(arch: str):
    def build(
        obs_space: str,
        output: str,
        dim: int,
        pretrained: str | None = None,
        input_size: int | None = None,
        zero_extra_channels: bool = False,
    ) -> ResNetEncoder:
        return ResNetEncoder(
            arch,
            input_channels(obs_space),
            output,
            dim=dim,
            pretrained=pretrained,
            input_size=input_size,
            zero_extra=zero_extra_channels,
        )

    return build


register_encoder(
    "resnet18",
    single_spaces(lambda s: s.image),
    "torchvision ResNet-18 (CPU presets); layer4 map -> tokens / pooled",
    _describer("resnet18"),
    pretrained="imagenet, or a torchvision-layout file",
)(_builder("resnet18"))
register_encoder(
    "resnet50",
    single_spaces(lambda s: s.image),
    "torchvision ResNet-50 (paper, 23.5M); layer4 map -> tokens / pooled",
    _describer("resnet50"),
    pretrained="imagenet, a torchvision-layout file, or R3M (module.convnet.*)",
    default_for=single_spaces(lambda s: s.image),
)(_builder("resnet50"))
