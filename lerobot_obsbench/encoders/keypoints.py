"""`spatial_softmax`: a small conv stack trained from scratch + spatial soft-argmax keypoints, beyond the paper.

The compact image encoder of Diffusion Policy's lineage (Levine et al. 2016, Finn et al.'s deep spatial
autoencoders, robomimic, LeRobot's `DiffusionRgbEncoder`): instead of pooling a feature map, each of K channels
becomes a softmax over the pixels and the encoder keeps its expected image position, a keypoint (x, y) in
[-1, 1] (x along the width). It puts an image encoder of 0.14M parameters (140,576 on rgb) that keeps only
"where" next to the ResNets' and ViTs' millions, on any image space (rgb, depth, rgbd, pointmap: 3, 1, 4 or 6
channels).

- Backbone: four 3x3 / 5x5 convolutions 32-64-64-128 (strides 2, 2, 1, 1; a 96 px frame gives a 24 x 24 map,
  128 px 32 x 32), each followed by GroupNorm (channels / 16 groups, as LeRobot's `use_group_norm`) and ReLU,
  shared by the cameras; then LeRobot's own `SpatialSoftmax` (a 1x1 conv to K maps, softmax, expected
  coordinates) with K = `num_keypoints` (32, LeRobot's `spatial_softmax_num_keypoints`).
- The soft-argmax is built for one frame size: `image_size` (the camera resolution, which the policy config
  passes), or `input_size` when frames are resized first (the config's `image_input_size`). A frame of another
  size is refused.
- Diffusion Policy (`output="global"`): per camera the K x 2 coordinates -> Linear(2K, 2K) + ReLU (LeRobot's
  `DiffusionRgbEncoder` head), cameras concatenated: 2K x cameras features (64 per camera).
- ACT (`output="tokens"`): one token per keypoint and camera, a learned embedding of the keypoint's index plus a
  linear map of its (x, y); positions are learned per keypoint index (1, K, dim) plus a sine code of the camera
  index (the camera count is not known when the encoder is built), K x cameras tokens.
"""

from __future__ import annotations

import torch
from lerobot.policies.act.modeling_act import create_sinusoidal_pos_embedding
from lerobot.policies.diffusion.modeling_diffusion import SpatialSoftmax
from torch import Tensor, nn

from lerobot_obsbench.encoders.image_input import as_frame_size, resize
from lerobot_obsbench.encoders.registry import EncoderContext, EncoderError, EncoderOutput, register_encoder
from lerobot_obsbench.schema import input_channels, single_spaces

# (out channels, kernel, stride) of each conv layer; padding kernel // 2 ("same" at stride 1).
CONV_LAYERS = ((32, 5, 2), (64, 3, 2), (64, 3, 1), (128, 3, 1))
GROUP_SIZE = 16  # GroupNorm groups = channels / 16, as LeRobot's Diffusion Policy with use_group_norm
IMAGE_NORMS = ("group", "batch")  # the convolutions' normalisation: GroupNorm (per image) or BatchNorm
NUM_KEYPOINTS = 32  # LeRobot's spatial_softmax_num_keypoints
DEFAULT_IMAGE_SIZE = 96  # used when no camera resolution is given (Diffusion Policy's 96 px frames)


def feature_map_size(height: int, width: int) -> tuple[int, int]:
    """(h, w) of the conv stack's output for (height, width) frames."""
    for _, kernel, stride in CONV_LAYERS:
        pad = kernel // 2
        height = (height + 2 * pad - kernel) // stride + 1
        width = (width + 2 * pad - kernel) // stride + 1
    return height, width


class SpatialSoftmaxEncoder(nn.Module):
    def __init__(
        self,
        in_channels: int,
        output: str,
        dim: int = 512,
        image_size: tuple[int, int] = (DEFAULT_IMAGE_SIZE, DEFAULT_IMAGE_SIZE),
        input_size: int | None = None,
        num_keypoints: int = NUM_KEYPOINTS,
        norm: str = "group",
    ):
        super().__init__()
        if num_keypoints < 1:
            raise EncoderError(f"num_keypoints must be >= 1; got {num_keypoints}")
        self.output, self.input_size, self.num_keypoints = output, input_size, num_keypoints
        self.frame_size = (input_size, input_size) if input_size else tuple(image_size)
        layers: list[nn.Module] = []
        for channels, kernel, stride in CONV_LAYERS:
            layers += [
                nn.Conv2d(in_channels, channels, kernel, stride=stride, padding=kernel // 2),
                nn.GroupNorm(channels // GROUP_SIZE, channels) if norm == "group" else nn.BatchNorm2d(channels),
                nn.ReLU(),
            ]
            in_channels = channels
        self.backbone = nn.Sequential(*layers)
        self.pool = SpatialSoftmax((in_channels, *feature_map_size(*self.frame_size)), num_kp=num_keypoints)
        if output == "global":
            self.out = nn.Sequential(nn.Linear(2 * num_keypoints, 2 * num_keypoints), nn.ReLU())
        else:
            self.xy = nn.Linear(2, dim)
            self.identity = nn.Parameter(torch.randn(num_keypoints, dim) * 0.02)
            self.pos = nn.Parameter(torch.randn(1, num_keypoints, dim) * 0.02)

    def keypoints(self, images: Tensor) -> Tensor:
        """images (B, n_cam, C, H, W) -> keypoints (B, n_cam, K, 2): each map's expected (x, y) in [-1, 1]."""
        b, n_cam = images.shape[:2]
        frames = images.flatten(0, 1)
        if self.input_size:
            frames = resize(frames, self.input_size)
        if tuple(frames.shape[-2:]) != self.frame_size:
            raise EncoderError(
                f"spatial_softmax was built for {self.frame_size[0]}x{self.frame_size[1]} frames (its soft-argmax "
                f"grid is fixed) but got {frames.shape[-2]}x{frames.shape[-1]}; build it with image_size= the "
                "camera resolution, or resize frames with input_size (--policy.image_input_size)"
            )
        return self.pool(self.backbone(frames)).reshape(b, n_cam, self.num_keypoints, 2)

    def forward(self, images: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """images (B, n_cam, C, H, W) -> tokens (B, n_cam*K, D) + pos (1, n_cam*K, D), or (B, n_cam*2K)."""
        points = self.keypoints(images)
        if self.output == "global":
            return self.out(points.flatten(2)).flatten(1)
        b, n_cam = points.shape[:2]
        tokens = (self.xy(points) + self.identity).reshape(b, n_cam * self.num_keypoints, -1)
        camera = create_sinusoidal_pos_embedding(n_cam, tokens.shape[-1]).to(device=tokens.device)
        pos = (self.pos[:, None] + camera[None, :, None]).reshape(1, n_cam * self.num_keypoints, -1)
        return tokens, pos.to(tokens.dtype)


def describe_spatial_softmax(
    obs_space: str, output: str, dim: int, context: EncoderContext, options: dict
) -> EncoderOutput:
    """K tokens per camera (ACT), or 2K features per camera, concatenated (Diffusion Policy)."""
    keypoints = options["num_keypoints"]
    if output == "tokens":
        return EncoderOutput(context.cameras * keypoints, dim)
    return EncoderOutput(None, context.cameras * 2 * keypoints)


@register_encoder(
    "spatial_softmax",
    single_spaces(lambda s: s.image),
    "4-layer GroupNorm conv stack + spatial soft-argmax, 32 keypoints per camera (0.14M, from scratch)",
    describe_spatial_softmax,
    choices={"norm": IMAGE_NORMS},
)
def build_spatial_softmax(
    obs_space: str,
    output: str,
    dim: int,
    image_size: int | tuple[int, int] = DEFAULT_IMAGE_SIZE,
    input_size: int | None = None,
    num_keypoints: int = NUM_KEYPOINTS,
    norm: str | None = None,
) -> SpatialSoftmaxEncoder:
    """`image_size`: the camera frame size (height, width) or one side, which the soft-argmax grid is built for,
    or `input_size` when frames are resized to it first; `num_keypoints`: K per camera; `norm`: GroupNorm (None,
    "group") or BatchNorm ("batch") after each convolution."""
    size = as_frame_size(image_size)
    return SpatialSoftmaxEncoder(
        input_channels(obs_space),
        output,
        dim=dim,
        image_size=size,
        input_size=input_size,
        num_keypoints=num_keypoints,
        norm=norm or "group",
    )
