"""Training-time augmentations as registered, named transforms, each declaring the spaces it applies to.

A policy names its recipe in one field (`--policy.augment=random_shift`, several joined by `+`); the observation
adapter runs it inside the policy's forward, so stock `lerobot-train` trains with it, and only in training: in
`eval()` every augmentation is the identity, except `random_crop`, which takes the centre crop at test as
Diffusion Policy does. Randomness comes from torch's generator on the tensors' device, which lerobot-train seeds,
so the same training seed gives the same augmented batches.

Four kinds, by where the adapter applies them:
- `image`: the space's input images (B, n_cam, C, H, W), every channel of a camera moved alike (colour, depth and
  xyz stay aligned), each camera and sample drawn on its own; the frame size is kept;
- `colour`: each camera's colour image (B, 3, H, W) in [0, 1], before it is normalised;
- `points`: the fused cloud in the world frame, before the crop box, so the box keeps what it would keep of a
  moved scene. Each also states how far it can move a point (`reach`), so that the adapter unprojects every pixel
  that can land in the box after it;
- `depth`: each camera's depth image as read (B, H, W, integer millimetres, 0 = none), before anything is built
  from it, so every space built from depth (depth, rgbd, pointmap, point clouds) sees it alike: `depth_noise_L`,
  the stereo sensor model of `lerobot_obsbench/depth_noise.py` at level L (the `depth_noise:L` perturbation's).

Magnitudes are the sources' where they have one (DrQ's pad of 4 pixels at 84², Diffusion Policy's 90% crop),
scaled to the frame; the point transforms are small (a few centimetres, a few degrees) because the actions are
not transformed with the scene. docs/recipes.md says what each does to which space.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lerobot_obsbench.depth_noise import noisy_depth
from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.schema import DEPTH_PREFIX, Space, available_spaces, space_info

# What each kind of transform acts on, asked of a space's record: its images, the colour of its images, its cloud,
# the depth it is built from (a fused space's parts give it theirs: rgb+pointcloud takes image and point transforms).
# A normalised recipe lists its names in this order of kinds: the adapter applies each kind at a point of its own
# (images after normalisation, colour before, points before the crop box, depth before anything), so only the order
# within a kind changes what trains; images before colour is how the grids' recipes are written
# (random_shift+colour_jitter), so their ids stay.
KINDS: dict[str, Callable[[Space], bool]] = {
    "image": lambda space: space.image,
    "colour": lambda space: space.colour,
    "points": lambda space: space.points,
    "depth": lambda space: DEPTH_PREFIX in space.sensors,
}
# DrQ pads 84-pixel frames by 4; other sizes are padded in proportion (3 pixels at 64²).
SHIFT_FRACTION = 4 / 84
# Diffusion Policy crops 84-pixel frames to 76 (90%) and takes the centre crop at test.
CROP_FRACTION = 0.9
# Colour jitter: brightness, contrast and saturation each scaled by a factor in 1 ± this.
COLOUR_STRENGTH = 0.2
POINT_ROTATION_DEG = 5.0  # about the vertical axis through the crop box's centre, uniform in ±this
POINT_SCALE = 0.05  # about the crop box's centre, a factor uniform in 1 ± this
POINT_TRANSLATION_M = 0.02  # per axis, uniform in ±this
POINT_JITTER_M = 0.002  # per point and axis, Gaussian with this deviation, clipped to JITTER_CLIP_M
JITTER_CLIP_M = 0.005
POINT_DROPOUT = 0.1  # fraction of points dropped at random


class AugmentationError(ObsBenchError, ValueError):
    """An augmentation name that does not exist, or that does not apply to the policy's space."""


@dataclass(frozen=True)
class AugmentationInfo:
    name: str
    kind: str  # one of KINDS: what of a space it acts on, and so which spaces it applies to
    summary: str
    apply: Callable
    # points only: (half extents of the box (3,)) -> the farthest, in metres, the transform can move a point of it
    reach: Callable[[Tensor], float] | None = None

    def applies_to(self, obs_space: str) -> bool:
        return KINDS[self.kind](space_info(obs_space))

    @property
    def spaces(self) -> tuple[str, ...]:
        """The registered spaces it applies to."""
        return available_spaces(KINDS[self.kind])


_REGISTRY: dict[str, AugmentationInfo] = {}


def register_augmentation(name: str, kind: str, summary: str, reach=None):
    """Decorator registering a transform under `name`: `colour` and `image` transforms take and return one
    tensor; `points` transforms take (xyz (B, N, 3), valid (B, N), centre (3,) or (B, 3)) and return (xyz, valid)
    and must declare their `reach`."""
    if kind not in KINDS:
        raise AugmentationError(f"augmentation {name!r}: kind must be one of {tuple(KINDS)}; got {kind!r}")
    if (kind == "points") != (reach is not None):
        raise AugmentationError(f"augmentation {name!r}: point transforms, and only they, declare a reach")

    def decorator(apply: Callable) -> Callable:
        if name in _REGISTRY:
            raise AugmentationError(f"an augmentation named {name!r} is already registered")
        _REGISTRY[name] = AugmentationInfo(name, kind, summary, apply, reach)
        return apply

    return decorator


def available_augmentations(obs_space: str | None = None) -> list[str]:
    """Registered names, optionally only those applying to `obs_space`."""
    return sorted(n for n, info in _REGISTRY.items() if obs_space is None or info.applies_to(obs_space))


def augmentation_info(name: str) -> AugmentationInfo:
    if name not in _REGISTRY:
        raise AugmentationError(
            f"unknown augmentation {name!r}; registered: {', '.join(available_augmentations())} "
            "(`obsbench encoders` lists each with its spaces)"
        )
    return _REGISTRY[name]


def parse_augment(recipe: str, obs_space: str) -> tuple[str, ...]:
    """The names of a recipe (`a+b`; empty: none), each checked to exist and to apply to `obs_space`."""
    if not recipe:
        return ()
    names = tuple(part.strip() for part in recipe.split("+"))
    if any(not n for n in names) or len(set(names)) != len(names):
        raise AugmentationError(f"augment={recipe!r}: names joined by '+', each once (e.g. random_shift+colour_jitter)")
    for name in names:
        info = augmentation_info(name)
        if not info.applies_to(obs_space):
            raise AugmentationError(
                f"augment: {name!r} does not apply to obs_space={obs_space!r} (it applies to "
                f"{', '.join(info.spaces)}); augmentations for {obs_space!r}: "
                f"{', '.join(available_augmentations(obs_space)) or 'none'}"
            )
    return names


RECIPE_KIND_ORDER = tuple(KINDS)


def normalised_recipe(recipe: str, space: str) -> str:
    """A recipe as runs name it: its names stripped of spaces and ordered by kind (RECIPE_KIND_ORDER), in the order
    written within a kind; "" for none. AugmentationError when a name does not exist or apply to `space`."""
    names = parse_augment(recipe.strip(), space)
    return "+".join(sorted(names, key=lambda n: RECIPE_KIND_ORDER.index(augmentation_info(n).kind)))


class Augmenter(nn.Module):
    """A recipe's transforms, applied by kind while training (`random_crop` also at test: its centre crop)."""

    def __init__(self, names: tuple[str, ...] = ()):
        super().__init__()
        self.names = tuple(names)
        self.by_kind = {kind: [_REGISTRY[n] for n in self.names if _REGISTRY[n].kind == kind] for kind in KINDS}

    def colour(self, rgb: Tensor) -> Tensor:
        for info in self.by_kind["colour"] if self.training else ():
            rgb = info.apply(rgb)
        return rgb

    def depth(self, depth_mm: Tensor, fx: Tensor) -> Tensor:
        """`depth_mm` (B, H, W) integer millimetres of a camera whose focal length is `fx` (B,) pixels."""
        for info in self.by_kind["depth"] if self.training else ():
            depth_mm = info.apply(depth_mm, fx)
        return depth_mm

    def image(self, images: Tensor) -> Tensor:
        for info in self.by_kind["image"]:
            if self.training or info.name == "random_crop":
                b, n = images.shape[:2]
                images = info.apply(images.flatten(0, 1), self.training).unflatten(0, (b, n))
        return images

    def point_reach(self, box: tuple[float, ...]) -> float:
        """How far, at most, the training transforms move a point of the box (widened as each one applies)."""
        if not self.training:
            return 0.0
        half = torch.tensor(box, dtype=torch.float64).reshape(3, 2).diff(dim=1)[:, 0] / 2
        total = 0.0
        for info in self.by_kind["points"]:
            total += info.reach(half + total)
        return total

    def points(self, xyz: Tensor, valid: Tensor, box: Tensor) -> tuple[Tensor, Tensor]:
        """`box` (6,) or (B, 6): the crop box, whose centre the rotation and scaling keep."""
        if not self.training:
            return xyz, valid
        centre = box.reshape(*box.shape[:-1], 3, 2).mean(-1)
        for info in self.by_kind["points"]:
            xyz, valid = info.apply(xyz, valid, centre)
        return xyz, valid

    def extra_repr(self) -> str:
        return "+".join(self.names) or "none"


# ---- images -----------------------------------------------------------------------------------------------------


def _window(images: Tensor, height: int, width: int, random: bool) -> Tensor:
    """A (height, width) window of each image (N, C, H, W): at a random offset per image, or the centre one."""
    n, c, full_h, full_w = images.shape
    device = images.device
    if random:
        rows = torch.randint(0, full_h - height + 1, (n,), device=device)
        columns = torch.randint(0, full_w - width + 1, (n,), device=device)
    else:
        rows = torch.full((n,), (full_h - height) // 2, device=device)
        columns = torch.full((n,), (full_w - width) // 2, device=device)
    v = (rows[:, None] + torch.arange(height, device=device))[:, None, :, None]
    u = (columns[:, None] + torch.arange(width, device=device))[:, None, None, :]
    return images[
        torch.arange(n, device=device)[:, None, None, None], torch.arange(c, device=device)[None, :, None, None], v, u
    ]


@register_augmentation(
    "random_shift",
    "image",
    "pad by 4/84 of the frame (edge pixels) and crop back at a random offset (DrQ)",
)
def random_shift(images: Tensor, training: bool) -> Tensor:
    height, width = images.shape[-2:]
    pad = max(1, round(SHIFT_FRACTION * max(height, width)))
    return _window(F.pad(images, (pad, pad, pad, pad), mode="replicate"), height, width, random=True)


@register_augmentation(
    "random_crop",
    "image",
    "a random 90% crop in training, the centre crop at test, resized back to the frame (Diffusion Policy)",
)
def random_crop(images: Tensor, training: bool) -> Tensor:
    height, width = images.shape[-2:]
    crop = _window(images, max(1, round(CROP_FRACTION * height)), max(1, round(CROP_FRACTION * width)), training)
    return F.interpolate(crop, size=(height, width), mode="bilinear", align_corners=False)


def _factor(n: int, like: Tensor) -> Tensor:
    return 1 + (torch.rand(n, 1, 1, 1, device=like.device, dtype=like.dtype) * 2 - 1) * COLOUR_STRENGTH


@register_augmentation(
    "colour_jitter",
    "colour",
    "brightness, contrast and saturation each scaled by 1 ± 0.2, per image",
)
def colour_jitter(rgb: Tensor) -> Tensor:
    n = len(rgb)
    out = rgb * _factor(n, rgb)
    mean = out.mean(dim=(1, 2, 3), keepdim=True)
    out = (out - mean) * _factor(n, rgb) + mean
    grey = (out * out.new_tensor([0.299, 0.587, 0.114]).view(1, 3, 1, 1)).sum(1, keepdim=True)
    out = (out - grey) * _factor(n, rgb) + grey
    return out.clamp(0, 1)


# ---- depth (as read, before anything is built from it) -------------------------------------------------------------


def _depth_noise(level: int) -> Callable[[Tensor, Tensor], Tensor]:
    def apply(depth_mm: Tensor, fx: Tensor) -> Tensor:
        return noisy_depth(depth_mm, fx, level)

    return apply


for _level in (1, 2):
    register_augmentation(
        f"depth_noise_{_level}",
        "depth",
        f"a stereo depth camera's noise at level {_level} (the depth_noise:{_level} perturbation): error growing with "
        "the squared distance, holes beside near edges and at random, millimetre steps",
    )(_depth_noise(_level))


# ---- points (world frame, before the crop box) --------------------------------------------------------------------


def _uniform(shape: tuple, like: Tensor, bound: float) -> Tensor:
    return (torch.rand(shape, device=like.device, dtype=like.dtype) * 2 - 1) * bound


def _radius_xy(half: Tensor) -> float:
    return float(half[:2].norm())


@register_augmentation(
    "point_rotate",
    "points",
    "rotate the scene about the vertical axis through the crop box's centre, ±5°",
    reach=lambda half: 2 * math.sin(math.radians(POINT_ROTATION_DEG) / 2) * _radius_xy(half),
)
def point_rotate(xyz: Tensor, valid: Tensor, centre: Tensor) -> tuple[Tensor, Tensor]:
    angle = _uniform((len(xyz),), xyz, math.radians(POINT_ROTATION_DEG))
    cos, sin = angle.cos()[:, None], angle.sin()[:, None]
    centre = centre.expand(len(xyz), 3)[:, None, :]
    rel = xyz - centre
    x, y = rel[..., 0], rel[..., 1]
    rotated = torch.stack([cos * x - sin * y, sin * x + cos * y, rel[..., 2]], dim=-1)
    return rotated + centre, valid


@register_augmentation(
    "point_scale",
    "points",
    "scale the scene about the crop box's centre by 1 ± 0.05",
    reach=lambda half: POINT_SCALE / (1 - POINT_SCALE) * float(half.norm()),
)
def point_scale(xyz: Tensor, valid: Tensor, centre: Tensor) -> tuple[Tensor, Tensor]:
    factor = 1 + _uniform((len(xyz), 1, 1), xyz, POINT_SCALE)
    centre = centre.expand(len(xyz), 3)[:, None, :]
    return (xyz - centre) * factor + centre, valid


@register_augmentation(
    "point_translate",
    "points",
    "move the scene by up to ±2 cm per axis",
    reach=lambda half: POINT_TRANSLATION_M * math.sqrt(3),
)
def point_translate(xyz: Tensor, valid: Tensor, centre: Tensor) -> tuple[Tensor, Tensor]:
    return xyz + _uniform((len(xyz), 1, 3), xyz, POINT_TRANSLATION_M), valid


@register_augmentation(
    "point_jitter",
    "points",
    "move each point by Gaussian noise (2 mm, clipped to 5 mm) per axis",
    reach=lambda half: JITTER_CLIP_M * math.sqrt(3),
)
def point_jitter(xyz: Tensor, valid: Tensor, centre: Tensor) -> tuple[Tensor, Tensor]:
    noise = (torch.randn_like(xyz) * POINT_JITTER_M).clamp(-JITTER_CLIP_M, JITTER_CLIP_M)
    return xyz + noise, valid


@register_augmentation("point_dropout", "points", "drop 10% of the points at random", reach=lambda half: 0.0)
def point_dropout(xyz: Tensor, valid: Tensor, centre: Tensor) -> tuple[Tensor, Tensor]:
    return xyz, valid & (torch.rand(valid.shape, device=valid.device) >= POINT_DROPOUT)
