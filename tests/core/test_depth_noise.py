"""The stereo depth camera's noise model (lerobot_obsbench/depth_noise.py), measured: its deviation at two
distances against the datasheet model's, its holes beside near edges against a second camera ray-cast by the
synthetic scene's own renderer (an independent reference), its random holes and millimetre steps; and what every
space built from depth makes of a noisy frame (no point from a pixel without depth); and the `depth_noise_L`
training augmentations, the identity at evaluation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lerobot_obsbench.augmentations import Augmenter, parse_augment
from lerobot_obsbench.depth_noise import D415, DepthNoiseError, noisy_depth, occluded_pixels
from lerobot_obsbench.schema import depth_key
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
from tests.support.helpers import CAM, frame_batch

QUANTISATION_MM = 1 / math.sqrt(12)  # the deviation rounding to whole millimetres adds


@pytest.mark.parametrize("level", [1.0, 2.0])
def test_the_deviation_at_two_distances_is_the_datasheet_models(level):
    """A flat wall at 1 m and at 2 m, 4 x 128 x 128 readings each: the readings' deviation is the model's
    z² s L / (f B) (D415: 1.45 mm at 1 m and 5.79 at 2 m at level 1) with the millimetre steps', within 3%, and grows
    with the square of the distance; holes at random are the datasheet's 1% times the level."""
    measured = {}
    for z in (1.0, 2.0):
        wall = torch.full((4, 128, 128), int(z * 1000), dtype=torch.int32)
        out = noisy_depth(wall, torch.full((4,), 100.0), level, generator=torch.Generator().manual_seed(0))
        valid = out > 0
        readings = out[valid].double()
        model_mm = D415.axial_sigma_m(z, level) * 1000
        measured[z] = float(readings.std())
        assert measured[z] == pytest.approx(math.hypot(model_mm, QUANTISATION_MM), rel=0.03)
        assert float(readings.mean()) == pytest.approx(z * 1000, abs=0.2)  # no bias
        assert torch.equal(out[valid], readings.round().to(torch.int32))  # whole millimetres
        assert 1 - float(valid.double().mean()) == pytest.approx(level * (1 - D415.fill_rate), rel=0.1)
    assert measured[2.0] / measured[1.0] == pytest.approx(4.0, rel=0.05)
    assert D415.axial_sigma_m(1.0) * 1000 == pytest.approx(1.448, abs=0.001)


def test_the_holes_beside_a_near_edge_are_what_a_second_camera_cannot_see(synthetic_module):
    """A cube on the table seen from 0.6 m: the pixels `occluded_pixels` hides are those whose surface point a second
    camera B to the right does not see, found by ray-casting the scene from that camera (the synthetic renderer):
    the band beside the cube's left edge."""
    synthetic, size = synthetic_module, 96
    K = synthetic.intrinsics(size)
    left = synthetic.look_at(eye=(0.35, 0.0, 0.5), target=(0.0, 0.0, 0.0))
    cube = (np.array([0.0, 0.0, 0.06]), 0.06, synthetic.CUBE_RGB)
    _, depth, points = synthetic.render(K, left, size, [cube])
    right = left.copy()
    right[:3, 3] += left[:3, 0] * D415.baseline_m  # the camera's x axis: to the right in its image
    _, right_depth, _ = synthetic.render(K, right, size, [cube])
    # each left pixel's point, seen from the right camera: hidden where the right camera's ray meets something nearer
    in_right = (points.reshape(-1, 3) - right[:3, 3]) @ right[:3, :3]
    u = np.round(K[0, 0] * in_right[:, 0] / in_right[:, 2] + K[0, 2]).astype(int)
    v = np.round(K[1, 1] * in_right[:, 1] / in_right[:, 2] + K[1, 2]).astype(int)
    inside = (u >= 0) & (u < size) & (v >= 0) & (v < size) & (depth.reshape(-1) > 0)
    seen_depth = np.full(len(u), np.inf)
    seen_depth[inside] = right_depth[v[inside], u[inside], 0] / 1000
    reference = (inside & (seen_depth < in_right[:, 2] - 0.01)).reshape(size, size)
    model = occluded_pixels(torch.tensor(depth[..., 0] / 1000.0)[None], torch.tensor([K[0, 0]]), D415.baseline_m)[0]
    model = model.numpy()
    assert reference.sum() > 20  # a band of pixels, not a line
    overlap = (model & reference).sum() / (model | reference).sum()
    assert overlap > 0.85, (model.sum(), reference.sum())
    # and nowhere else: the band's pixels lie beside the cube (the table is seen by both cameras)
    noisy = noisy_depth(torch.tensor(depth[..., 0].astype(np.int32))[None], torch.tensor([K[0, 0]]), 1.0)[0]
    assert (noisy.numpy()[model] == 0).all()


def test_a_level_outside_its_range_is_refused():
    depth = torch.full((1, 4, 4), 500, dtype=torch.int32)
    for level in (0, -1, 4.5, float("nan")):
        with pytest.raises(DepthNoiseError, match=r"level must be in \(0, 4\]"):
            noisy_depth(depth, torch.tensor([50.0]), level)


@pytest.mark.parametrize("obs_space", ["depth", "rgbd", "pointmap", "pointcloud", "rgb+pointcloud"])
def test_every_space_built_from_a_noisy_frame_takes_no_point_from_a_pixel_without_depth(synthetic_module, obs_space):
    batch = frame_batch(synthetic_module, batch_size=2, size=48)
    key = depth_key(CAM)
    clean = batch[key][..., 0]
    noisy = noisy_depth(
        clean, batch[f"observation.intrinsics.{CAM}"][:, 0, 0], 2.0, generator=torch.Generator().manual_seed(1)
    )
    assert (noisy == 0).sum() > (clean == 0).sum()  # holes made
    batch[key] = noisy[..., None]
    config = AdapterConfig(obs_space=obs_space, cameras=[CAM], workspace=[-0.5, 0.5, -0.5, 0.5, -0.05, 0.5])
    adapter = ObservationAdapter(config).eval()
    holes = noisy == 0
    if obs_space in ("pointcloud", "rgb+pointcloud"):
        xyz, _, valid = adapter.fuse_cameras(batch, (-10, 10, -10, 10, -10, 10))  # every pixel a candidate
        assert torch.equal(valid, ~holes.flatten(1))
        return
    out = adapter(batch)
    if obs_space == "pointmap":
        xyz = out[:, 0, 3:]
        assert (xyz.permute(0, 2, 3, 1)[holes] == 0).all() and (xyz.permute(0, 2, 3, 1)[~holes].abs().sum(-1) > 0).all()
    else:  # a hole is the depth image's near bound, as any missing reading
        depth = out[:, 0, -1]
        assert torch.allclose(depth[holes], torch.tensor(-1.0))


def test_the_depth_noise_augmentation_trains_on_noisy_depth_and_evaluates_on_the_frame(synthetic_module):
    batch = frame_batch(synthetic_module, batch_size=2, size=32)
    clean = batch[depth_key(CAM)].clone()
    config = AdapterConfig(obs_space="depth", cameras=[CAM], augment="depth_noise_2")
    adapter = ObservationAdapter(config)
    assert parse_augment("depth_noise_2", "depth") == ("depth_noise_2",)
    torch.manual_seed(0)
    trained = adapter(batch)
    torch.manual_seed(0)
    again = adapter(batch)
    assert torch.equal(trained, again)  # torch's generator, which lerobot-train seeds
    assert torch.equal(batch[depth_key(CAM)], clean)  # the batch itself is left as it was
    adapter.eval()
    evaluated = adapter(batch)
    assert not torch.equal(trained, evaluated)
    assert torch.equal(evaluated, ObservationAdapter(AdapterConfig(obs_space="depth", cameras=[CAM])).eval()(batch))
    depth_mm = clean[..., 0]
    out = Augmenter(("depth_noise_1",)).depth(depth_mm, batch[f"observation.intrinsics.{CAM}"][:, 0, 0])
    assert out.shape == depth_mm.shape and out.dtype == depth_mm.dtype and not torch.equal(out, depth_mm)
