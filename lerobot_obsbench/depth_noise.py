"""What a stereo depth camera does to a perfect depth image: the noise model behind the `depth_noise:L` evaluation
perturbation (envs/perturbations.py) and the `depth_noise_L` training augmentations (augmentations.py).

Simulators render exact depth; a stereo camera (the RealSense D400 family this project records with) measures depth
from the disparity between two imagers a baseline B apart, z = f B / d, and so:

- its axial noise grows with the square of the distance: an error of s pixels in the disparity (the "subpixel" RMS
  of the stereo matcher) is an error of z² s / (f B) in depth (Intel's white paper "Tuning depth cameras for best
  performance": depth RMS error = distance² x subpixel / (focal length x baseline));
- it has holes where the second imager does not see what the first one sees: beside every near edge, the band of
  the farther surface that the nearer one hides from the other imager (left-right occlusion; D400 depth is the left
  imager's, the right imager is B to its right), and at random where matching fails (the datasheet's fill rate);
- it reports whole depth units (1 mm by default).

`noisy_depth` applies the three to a batch of depth images at a `level`: level 1 is a D415 on a well-textured
scene by its datasheet (B = 55 mm, 65° horizontal field of view over 1280 pixels, a subpixel RMS of 0.08 and a 99%
fill rate); level L multiplies the disparity error and the random holes by L (level 2: a scene the matcher finds
twice as hard). The occlusion bands are geometry: they follow from B and the rendered camera's own focal length,
whatever the level. docs/simulation.md#depth-sensor-noise lists the parameters with their sources and the measured
deviations. Pure batched tensor code: any device, torch's global generator unless one is given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lerobot_obsbench.errors import ObsBenchError


@dataclass(frozen=True)
class StereoDepthSensor:
    """A stereo depth camera's error model, each field from its datasheet or its maker's white papers."""

    name: str
    baseline_m: float  # between the two imagers
    focal_px: float  # of its depth imagers, at its own depth resolution
    subpixel_rms: float  # the stereo matcher's disparity error on a well-textured scene, pixels
    fill_rate: float  # the fraction of pixels with a depth on such a scene
    depth_unit_m: float  # the step of the depth it reports

    def axial_sigma_m(self, z_m: Tensor | float, level: float = 1.0) -> Tensor | float:
        """The standard deviation of a depth reading at `z_m` metres, at `level`."""
        return z_m**2 * self.subpixel_rms * level / (self.focal_px * self.baseline_m)


# D415: 55 mm baseline, 65° horizontal field of view at 1280 x 720, depth in 1 mm units (Intel RealSense D400 Series
# Product Family Datasheet); subpixel RMS 0.08 and fill rate 99% for a well-textured target (Intel's white papers
# "Tuning depth cameras for best performance" and "Depth quality testing").
D415 = StereoDepthSensor(
    name="Intel RealSense D415",
    baseline_m=0.055,
    focal_px=1280 / 2 / math.tan(math.radians(65 / 2)),
    subpixel_rms=0.08,
    fill_rate=0.99,
    depth_unit_m=0.001,
)
MAX_LEVEL = 4.0  # beyond, the random holes (4% at level 4) and the error are no longer a working D415's


class DepthNoiseError(ObsBenchError, ValueError):
    """A noise level outside (0, MAX_LEVEL]."""


def check_level(level: float) -> float:
    if not (isinstance(level, int | float) and 0 < level <= MAX_LEVEL):
        raise DepthNoiseError(
            f"depth noise level must be in (0, {MAX_LEVEL:g}] (1: a D415 by its datasheet); got {level!r}"
        )
    return float(level)


def occluded_pixels(depth_m: Tensor, fx: Tensor, baseline_m: float) -> Tensor:
    """(B, H, W) bool: the pixels of `depth_m` (B, H, W; 0 = no depth) that a second imager `baseline_m` to the
    right of the camera cannot see, because a nearer surface to their right in the image hides them from it: pixel u
    is hidden when some pixel u + k has a disparity (fx B / z, pixels) larger than its own by k or more."""
    valid = depth_m > 0
    disparity = torch.where(valid, fx.reshape(-1, 1, 1) * baseline_m / depth_m.clamp_min(1e-6), 0.0)
    if not bool(valid.any()):
        return torch.zeros_like(valid)
    spread = float(disparity.max() - disparity[valid].min())
    hidden = torch.zeros_like(valid)
    for k in range(1, min(math.ceil(spread), depth_m.shape[-1] - 1) + 1):
        right = torch.nn.functional.pad(disparity[..., k:], (0, k))
        hidden |= valid & (right - disparity >= k)
    return hidden


def noisy_depth(
    depth_mm: Tensor,
    fx: Tensor,
    level: float = 1.0,
    *,
    sensor: StereoDepthSensor = D415,
    generator: torch.Generator | None = None,
) -> Tensor:
    """`depth_mm` (B, H, W) integer millimetres (0 = no depth) as `sensor` would report it at `level`: occlusion
    bands and random holes set to 0, axial noise of `sensor.axial_sigma_m` added, rounded to its depth unit; `fx`
    (B,) the rendered camera's focal length in pixels. The same dtype back."""
    level = check_level(level)
    z = depth_mm.to(torch.float32) / 1000.0
    valid = z > 0
    hidden = occluded_pixels(z, fx.to(z), sensor.baseline_m)
    dropped = torch.rand(z.shape, generator=generator, device=z.device) < level * (1 - sensor.fill_rate)
    noise = torch.randn(z.shape, generator=generator, device=z.device) * sensor.axial_sigma_m(z, level)
    unit = sensor.depth_unit_m
    measured = torch.round((z + noise) / unit) * unit
    keep = valid & ~hidden & ~dropped & (measured > 0)
    return torch.where(keep, torch.round(measured * 1000.0), 0.0).to(depth_mm.dtype)
