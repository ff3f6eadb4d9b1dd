"""The fused space rgb+pointcloud (beyond the paper): it reads what its parts read, the adapter gives each part's
input exactly as the part's own space does, the encoder pair puts each part encoder's tokens side by side (ACT) or
concatenates their features (Diffusion Policy), both policies train and act on it, and grids, presets and configs
treat it as a point-cloud space with images. And a fused space the package does not ship (rgb+depth), registered
in a test alone, is taken by every consumer."""

from __future__ import annotations

import pytest
import torch

from lerobot_obsbench import schema
from lerobot_obsbench.encoders import (
    EncoderContext,
    available_encoders,
    check_encoder,
    default_encoder,
    encoder_info,
    encoder_output,
    make_encoder,
)
from lerobot_obsbench.schema import (
    IMAGE_PREFIX,
    SENSOR_PREFIXES,
    PointCloud,
    available_spaces,
    fused_space,
    read_sensors,
    reads_images,
    reads_points,
    register_space,
    sensor_keys,
    space_info,
)
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
from tests.support.helpers import CAM, frame_batch

FUSED = "rgb+pointcloud"
WORKSPACE = (-0.5, 0.5, -0.5, 0.5, 0.005, 0.5)
PAIR_OPTIONS = {"image_size": (32, 32), "point_features": "xyz", "num_tokens": 8}


def test_a_fused_space_reads_what_its_parts_read():
    assert FUSED in available_spaces() and space_info(FUSED).parts == ("rgb", "pointcloud")
    assert set(sensor_keys(FUSED, [CAM])) == set(sensor_keys("rgb", [CAM])) | set(sensor_keys("pointcloud", [CAM]))
    assert reads_points(FUSED) and reads_images(FUSED) and not reads_points("rgb") and not reads_images("pointcloud")


def test_colour_is_read_only_where_an_input_takes_it():
    """A cloud of xyz points reads depth and the calibration but no colour; the fused space's rgb part and a
    pointmap's image read colour whatever the point features."""
    assert read_sensors("pointcloud") == SENSOR_PREFIXES
    assert read_sensors("pointcloud", "xyz") == tuple(p for p in SENSOR_PREFIXES if p != IMAGE_PREFIX)
    assert read_sensors("pointcloud", "rgb") == SENSOR_PREFIXES
    for space in (FUSED, "pointmap", "rgb", "rgbd"):
        assert read_sensors(space, "xyz") == space_info(space).sensors, space
    assert IMAGE_PREFIX + CAM not in sensor_keys("pointcloud", [CAM], "xyz")
    with pytest.raises(ValueError, match="point_features"):
        read_sensors("pointcloud", "normals")


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
    assert "norm" in info.options  # both parts take it: one value sets both
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
    # an option both parts take sets both, to a value each allows (dp3 offers batch and layer, spatial softmax
    # group and batch)
    ObsACTConfig(device="cpu", obs_space=FUSED, encoder="spatial_softmax+dp3", encoder_norm="batch")
    with pytest.raises(ValueError, match="encoder_norm='group': encoder 'spatial_softmax\\+dp3' takes batch"):
        ObsACTConfig(device="cpu", obs_space=FUSED, encoder="spatial_softmax+dp3", encoder_norm="group")
    pair = make_encoder("spatial_softmax+dp3", FUSED, "tokens", dim=16, norm="batch", **PAIR_OPTIONS)
    batch_norms = (torch.nn.BatchNorm1d, torch.nn.BatchNorm2d)
    assert all(any(isinstance(m, batch_norms) for m in part.modules()) for part in pair.parts)
    assert preset_encoder("cpu", FUSED) == "resnet18+pointnet"
    fields = preset_overrides("cpu", "obs_act", FUSED, "spatial_softmax+dp3")
    assert fields["point_features"] == "xyz" and fields["num_tokens"] == 128
    assert fields["encoder"] == "resnet18+pointnet"  # the preset's pair; the grid's encoder axis wins over it
    # the dp3 preset's pair, with DP3's point settings: not the default pair (resnet50+pointnet) with them
    assert preset_overrides("dp3", "obs_diffusion", FUSED)["encoder"] == "resnet18+dp3"
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


@pytest.fixture
def rgb_depth(monkeypatch):
    """A fused space the package does not ship, registered for one test (the vocabulary is restored after)."""
    monkeypatch.setattr(schema, "_SPACES", dict(schema._SPACES))
    return register_space(fused_space("rgb", "depth")).name


def test_a_fused_space_registered_in_one_place_is_taken_by_every_consumer(rgb_depth, synthetic_module):
    """rgb+depth, one line in this test: its record comes from its parts, and presets (the paper's depth
    normalisation included), augmentation checks, the encoder pairs and their options, configs, grids and the
    adapter all follow it with no other edit."""
    from lerobot_obsbench.augmentations import AugmentationError, available_augmentations, parse_augment
    from lerobot_obsbench.bench.grid import parse_grid
    from lerobot_obsbench.policies import ObsACTConfig
    from lerobot_obsbench.presets import preset_encoder, preset_overrides, space_kinds

    space = space_info(rgb_depth)
    assert space.parts == ("rgb", "depth") and space.image and space.colour and space.depth
    assert not (space.points or space.positions or space.control)
    assert set(sensor_keys(rgb_depth, [CAM])) == set(sensor_keys("rgbd", [CAM]))
    assert space_kinds(rgb_depth) == ("all", "image", "depth")
    # augmentations: image, colour and depth transforms apply, point transforms do not
    assert set(available_augmentations(rgb_depth)) == {
        "random_shift",
        "random_crop",
        "colour_jitter",
        "depth_noise_1",
        "depth_noise_2",
    }
    with pytest.raises(AugmentationError, match="'point_jitter' does not apply to obs_space='rgb\\+depth'"):
        parse_augment("point_jitter", rgb_depth)
    # the encoder pairs of its parts, with their options (each option the pair's parts share sets both)
    assert preset_encoder("paper", rgb_depth) == "resnet50+resnet50" in available_encoders(rgb_depth)
    assert {"pretrained", "input_size", "zero_extra_channels"} <= set(encoder_info("resnet50+resnet50").options)
    # the paper preset (official depth normalisation, zero-initialised extra channels) makes a valid config
    fields = preset_overrides("paper", "obs_act", rgb_depth)
    assert fields["depth_normalization"] == "official" and fields["zero_init_extra_channels"] is True
    assert fields["encoder"] == "resnet50+resnet50"
    config = ObsACTConfig(device="cpu", obs_space=rgb_depth, **fields)
    assert config.encoder == "resnet50+resnet50"
    grid = parse_grid(
        {"tasks": ["PushCubeWide-v1"], "obs_spaces": [rgb_depth], "augmentations": {rgb_depth: ["random_shift"]}}
        | {"steps": 10, "preset": "cpu"}
    )
    assert [(r.obs_space, r.augment) for r in grid.expand()] == [(rgb_depth, "random_shift")]
    assert "workspace" not in dict(grid.expand()[0].policy_overrides)  # no cloud, no crop box
    # the adapter gives each part's input as the part's own space does
    batch = frame_batch(synthetic_module, batch_size=2, size=32)
    images, depth = ObservationAdapter(AdapterConfig(rgb_depth, [CAM])).eval()(batch)
    assert torch.equal(images, ObservationAdapter(AdapterConfig("rgb", [CAM])).eval()(batch))
    assert torch.equal(depth, ObservationAdapter(AdapterConfig("depth", [CAM])).eval()(batch))
