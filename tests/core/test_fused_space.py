"""The fused space rgb+pointcloud (beyond the paper): it reads what its parts read, the adapter gives each part's
input exactly as the part's own space does, the encoder pair puts each part encoder's tokens side by side (ACT) or
concatenates their features (Diffusion Policy), both policies train and act on it, and grids, presets and configs
treat it as a point-cloud space with images."""

from __future__ import annotations

import pytest
import torch

from lerobot_obsbench.encoders import (
    EncoderContext,
    available_encoders,
    check_encoder,
    default_encoder,
    encoder_info,
    encoder_output,
    make_encoder,
)
from lerobot_obsbench.schema import FUSED_SPACES, OBS_SPACES, PointCloud, reads_images, reads_points, sensor_keys
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
from tests.support.helpers import CAM, frame_batch

FUSED = "rgb+pointcloud"
WORKSPACE = (-0.5, 0.5, -0.5, 0.5, 0.005, 0.5)
PAIR_OPTIONS = {"image_size": (32, 32), "point_features": "xyz", "num_tokens": 8}


def test_a_fused_space_reads_what_its_parts_read():
    assert FUSED in OBS_SPACES and FUSED_SPACES[FUSED] == ("rgb", "pointcloud")
    assert set(sensor_keys(FUSED, [CAM])) == set(sensor_keys("rgb", [CAM])) | set(sensor_keys("pointcloud", [CAM]))
    assert reads_points(FUSED) and reads_images(FUSED) and not reads_points("rgb") and not reads_images("pointcloud")


def test_the_adapter_gives_each_parts_input_as_the_parts_own_space_does(synthetic_module):
    batch = frame_batch(synthetic_module, batch_size=2, size=32)
    images, cloud = ObservationAdapter(AdapterConfig(FUSED, [CAM], workspace=WORKSPACE)).eval()(batch)
    alone_images = ObservationAdapter(AdapterConfig("rgb", [CAM], workspace=WORKSPACE)).eval()(batch)
    alone_cloud = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=WORKSPACE)).eval()(batch)
    assert isinstance(cloud, PointCloud)
    assert torch.equal(images, alone_images)
    assert torch.equal(cloud.xyz, alone_cloud.xyz) and torch.equal(cloud.features, alone_cloud.features)


def test_encoder_pairs_are_named_by_their_parts_and_checked_in_order():
    pairs = available_encoders(FUSED)
    assert "spatial_softmax+dp3" in pairs and "resnet50+pointnet" in pairs and all("+" in p for p in pairs)
    assert default_encoder(FUSED) == f"{default_encoder('rgb')}+{default_encoder('pointcloud')}"
    check_encoder("spatial_softmax+dp3", FUSED)
    with pytest.raises(ValueError, match="no fused space has parts these encoders accept in this order"):
        check_encoder("dp3+spatial_softmax", FUSED)
    with pytest.raises(ValueError, match="Unknown encoder 'spatial_softmax\\+dp4'"):
        check_encoder("spatial_softmax+dp4", FUSED)
    with pytest.raises(ValueError, match="does not accept obs_space='pointcloud'"):
        check_encoder("spatial_softmax+dp3", "pointcloud")
    info = encoder_info("spatial_softmax+dp3")
    assert "norm" not in info.options  # both parts take one: ambiguous for the pair
    assert {"num_keypoints", "point_features", "num_tokens"} <= set(info.options)


@pytest.mark.parametrize("output", ["tokens", "global"])
def test_the_pair_puts_its_parts_outputs_side_by_side(synthetic_module, output):
    batch = frame_batch(synthetic_module, batch_size=3, size=32)
    images, cloud = ObservationAdapter(AdapterConfig(FUSED, [CAM], workspace=WORKSPACE, point_features="xyz")).eval()(
        batch
    )
    torch.manual_seed(0)
    pair = make_encoder("spatial_softmax+dp3", FUSED, output, dim=16, **PAIR_OPTIONS).eval()
    image_part, point_part = pair.parts
    declared = encoder_output(
        "spatial_softmax+dp3", FUSED, output, dim=16, context=EncoderContext(1, (32, 32)), **PAIR_OPTIONS
    )
    with torch.no_grad():
        out, alone = pair((images, cloud)), (image_part(images), point_part(cloud))
    if output == "global":
        torch.testing.assert_close(out, torch.cat(alone, dim=-1))
        assert declared.width == out.shape[-1] == alone[0].shape[-1] + alone[1].shape[-1]
        return
    tokens, pos = out
    (image_tokens, image_pos), (point_tokens, point_pos) = alone
    assert tokens.shape == (3, declared.tokens, 16) and declared.tokens == image_tokens.shape[1] + point_tokens.shape[1]
    torch.testing.assert_close(tokens, torch.cat([image_tokens, point_tokens], dim=1))
    torch.testing.assert_close(pos[:1], torch.cat([image_pos, point_pos], dim=1)[:1])


@pytest.mark.parametrize("policy_type", ["obs_act", "obs_diffusion"])
def test_both_policies_train_and_act_on_the_fused_space_with_a_recipe(synthetic_module, policy_type):
    from tests.encoders.test_compact_encoders import _policy, _training_batch

    policy = _policy(
        policy_type,
        FUSED,
        "spatial_softmax+dp3",
        num_tokens=8,
        point_features="xyz",
        augment="random_shift+point_jitter",
    )
    observation = policy.model.observation if policy_type == "obs_act" else policy.diffusion.observation
    assert [type(p).__name__ for p in observation.encoder.parts] == ["SpatialSoftmaxEncoder", "DP3Encoder"]
    policy.train()
    batch = _training_batch(synthetic_module, policy)
    loss, _ = policy.forward(batch)
    loss.backward()
    for part in observation.encoder.parts:  # both parts learn
        assert sum(float(p.grad.abs().sum()) for p in part.parameters() if p.grad is not None) > 0
    policy.eval()
    policy.reset()
    frames = {k: v for k, v in batch.items() if k.startswith("observation")}
    if policy_type == "obs_diffusion":
        frames = {k: v[:, 0] for k, v in frames.items()}
    assert policy.select_action(frames).shape == (2, 7)


def test_configs_presets_and_grids_treat_the_fused_space_as_points_with_images():
    from lerobot_obsbench.bench.grid import parse_grid
    from lerobot_obsbench.policies import ObsACTConfig
    from lerobot_obsbench.presets import preset_encoder, preset_overrides

    config = ObsACTConfig(device="cpu", obs_space=FUSED, workspace_jitter=0.01, frame="ee")
    assert config.encoder == "resnet50+pointnet"
    with pytest.raises(ValueError, match="encoder_norm='batch' is not an option of encoder 'spatial_softmax\\+dp3'"):
        ObsACTConfig(device="cpu", obs_space=FUSED, encoder="spatial_softmax+dp3", encoder_norm="batch")
    assert preset_encoder("cpu", FUSED) == "resnet18+pointnet"
    fields = preset_overrides("cpu", "obs_act", FUSED, "spatial_softmax+dp3")
    assert fields["point_features"] == "xyz" and fields["num_tokens"] == 128 and "encoder" not in fields
    grid = parse_grid(
        {
            "tasks": ["PushCubeWide-v1"],
            "obs_spaces": ["pointcloud", FUSED],
            "encoders": {"pointcloud": ["dp3"], FUSED: ["spatial_softmax+dp3"]},
            "augmentations": {FUSED: ["", "random_shift+point_jitter"]},
            "steps": 10,
            "preset": "cpu",
        }
    )
    fused = [r for r in grid.expand() if r.obs_space == FUSED]
    assert [r.augment for r in fused] == ["", "random_shift+point_jitter"]
    workspace = dict(fused[0].policy_overrides)["workspace"]
    assert workspace == dict(grid.expand()[0].policy_overrides)["workspace"]  # the task's crop box, as pointcloud's
    assert fused[1].method == "obs_act/rgb+pointcloud/spatial_softmax+dp3/random_shift+point_jitter"
