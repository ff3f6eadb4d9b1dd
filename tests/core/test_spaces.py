"""ObservationAdapter: every space's output, and clear errors on bad sensor input."""

from __future__ import annotations

import pytest
import torch

from lerobot_obsbench import geometry
from lerobot_obsbench.schema import SchemaError
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
from tests.support.helpers import CAM, frame_batch

WORKSPACE = (-0.5, 0.5, -0.5, 0.5, 0.005, 0.5)


@pytest.fixture(scope="module")
def batch(synthetic_module):
    return frame_batch(synthetic_module, batch_size=3, size=40)


@pytest.mark.parametrize("space,channels", [("rgb", 3), ("depth", 1), ("rgbd", 4), ("pointmap", 6)])
def test_image_spaces_shapes_and_content(batch, space, channels):
    out = ObservationAdapter(AdapterConfig(space, [CAM])).eval()(batch)
    assert out.shape == (3, 1, channels, 40, 40)
    assert torch.isfinite(out).all()
    if space == "rgbd":
        rgb = ObservationAdapter(AdapterConfig("rgb", [CAM]))(batch)
        depth = ObservationAdapter(AdapterConfig("depth", [CAM]))(batch)
        assert torch.equal(out, torch.cat([rgb, depth], dim=2))
    if space == "depth":
        assert out.min() >= -1 and out.max() <= 1


def test_pointmap_xyz_channels_are_world_points(batch):
    out = ObservationAdapter(AdapterConfig("pointmap", [CAM]))(batch)
    xyz = out[:, 0, 3:].permute(0, 2, 3, 1)
    valid = batch[f"observation.depth.{CAM}"][..., 0] > 0
    # the table is at z = 0 and nothing is below it
    assert xyz[valid][:, 2].min() > -2e-3
    assert (xyz[~valid] == 0).all()


def test_pointcloud_is_cropped_voxelised_and_finds_the_cube(batch):
    adapter = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=WORKSPACE, voxel_size=0.005)).eval()
    cloud = adapter(batch)
    assert cloud.xyz.shape[:2] == cloud.mask.shape and cloud.features.shape[-1] == 6
    for b in range(3):
        pts = cloud.xyz[b][cloud.mask[b]]
        assert len(pts) > 10
        assert (pts[:, 2] > 0.005).all(), "ground must be removed"
        cells = torch.floor(pts / 0.005).long()
        assert len(torch.unique(cells, dim=0)) == len(cells), "one point per voxel"
        # red points (rgb feature ~ (0.73, -0.76, -0.76)) lie on the cube
        red = cloud.features[b][cloud.mask[b]][:, 0] > 0.5
        cube = batch["cube"][b].float()
        assert red.any() and (pts[red] - cube).abs().max() < 0.026 + 2e-3
    assert (cloud.features[~cloud.mask] == 0).all()


def test_workspace_jitter_moves_the_crop_in_training_only(batch):
    """The official real-robot code jitters its crop box by ±1 cm in training; evaluation crops exactly."""
    tight = (-0.5, 0.5, -0.5, 0.5, 0.008, 0.5)  # zmin near the table: a centimetre down keeps table points
    adapter = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=tight, workspace_jitter=0.01))
    counts = {int(adapter.train()(batch).mask.sum()) for _ in range(6)}
    assert len(counts) > 1
    exact = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=tight)).eval()(batch).mask.sum()
    assert all(int(adapter.eval()(batch).mask.sum()) == int(exact) for _ in range(3))
    with pytest.raises(ValueError, match="workspace_jitter must be a finite number >= 0"):
        ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace_jitter=-0.01))


@pytest.mark.parametrize("features,channels", [("xyz", 3), ("rgb", 3), ("rgb+xyz", 6)])
def test_point_feature_choices(batch, features, channels):
    cloud = ObservationAdapter(AdapterConfig("pointcloud", [CAM], point_features=features, workspace=WORKSPACE)).eval()(
        batch
    )
    assert cloud.features.shape[-1] == channels
    if features == "xyz":
        assert torch.equal(cloud.features, cloud.xyz)


def test_a_cloud_without_colour_features_reads_no_colour_frame(batch):
    """point_features="xyz": the adapter never reads the colour frame (the env need not render it, nor the reader
    decode it), and the cloud is the one it builds with the frame there."""
    config = AdapterConfig("pointcloud", [CAM], point_features="xyz", workspace=WORKSPACE)
    with_colour = ObservationAdapter(config).eval()(batch)
    colourless = {key: value for key, value in batch.items() if not key.startswith("observation.images.")}
    assert len(colourless) < len(batch)
    without = ObservationAdapter(config).eval()(colourless)
    for name in ("xyz", "features", "mask"):
        assert torch.equal(getattr(without, name), getattr(with_colour, name)), name
    assert with_colour.mask.sum() > 0
    with pytest.raises(SchemaError, match="observation.images"):  # colour features do read it
        ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=WORKSPACE)).eval()(colourless)


def test_box_normalised_point_features_span_the_crop_box(batch):
    """point_normalization="box": the xyz features are the points' coordinates mapped to [-1, 1] over the box (as
    DP3 scales its clouds); positions, colours and the sampled points stay those of the metric cloud."""
    box = (-0.2, 0.2, -0.3, 0.3, 0.005, 0.105)
    metric = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=box)).eval()(batch)
    scaled = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=box, point_normalization="box")).eval()(
        batch
    )
    torch.testing.assert_close(scaled.xyz, metric.xyz)
    torch.testing.assert_close(scaled.features[..., :3], metric.features[..., :3])  # colour unchanged
    centre, half = torch.tensor([0.0, 0.0, 0.055]), torch.tensor([0.2, 0.3, 0.05])
    expected = (metric.xyz - centre) / half * metric.mask[..., None]
    torch.testing.assert_close(scaled.features[..., 3:], expected)
    inside = scaled.features[..., 3:][scaled.mask]
    assert inside.abs().max() <= 1 + 1e-6 and inside.abs().max() > 0.3  # the cube fills part of the box
    with pytest.raises(ValueError, match="point_normalization='box'.*frame='camera'"):
        ObservationAdapter(AdapterConfig("pointcloud", [CAM], frame="camera", point_normalization="box"))
    with pytest.raises(ValueError, match="point_normalization"):
        ObservationAdapter(AdapterConfig("pointcloud", [CAM], point_normalization="unit"))
    from lerobot_obsbench.policies.obs_act.configuration_obs_act import ObsACTConfig

    with pytest.raises(ValueError, match="point_normalization='box'.*obs_space='rgb'"):
        ObsACTConfig(obs_space="rgb", point_normalization="box")


def test_camera_and_ee_frames(batch):
    cam2world = batch[f"observation.cam2world.{CAM}"]
    # pointmap in the camera frame: z is exactly the stored depth
    pointmap = ObservationAdapter(AdapterConfig("pointmap", [CAM], frame="camera"))(batch)
    z = pointmap[:, 0, 5]
    assert torch.allclose(z, batch[f"observation.depth.{CAM}"][..., 0].float() / 1000, atol=1e-5)
    # point cloud in the camera frame: mapped back to the world, every point lies in the workspace crop
    cam = ObservationAdapter(AdapterConfig("pointcloud", [CAM], frame="camera", workspace=WORKSPACE)).eval()(batch)
    back = geometry.transform_points(cam.xyz, cam2world)
    assert (
        geometry.crop_mask(back, cam.mask, [w + d for w, d in zip(WORKSPACE, [-1e-4, 1e-4] * 3, strict=True)]).sum()
        == cam.mask.sum()
    )
    assert (cam.xyz[cam.mask][:, 2] > 0.3).all(), "camera z is the distance in front of the camera"
    # end-effector frame: the gripper box is centred on the ee origin; undo the ee yaw to get its faces back
    state = batch["observation.state"]
    ee_pose = geometry.pose_to_matrix(state[:, -7:-4], state[:, -4:])
    ee = ObservationAdapter(AdapterConfig("pointcloud", [CAM], frame="ee", workspace=WORKSPACE)).eval()(
        batch, ee_pose=ee_pose
    )
    blue = (ee.features[..., 2] > 0.5) & ee.mask
    aligned = geometry.transform_points(ee.xyz, ee_pose) - ee_pose[:, None, :3, 3]
    assert blue.any() and aligned[blue].abs().max() < 0.015 + 2e-3
    with pytest.raises(SchemaError, match="end-effector pose"):
        ObservationAdapter(AdapterConfig("pointcloud", [CAM], frame="ee", workspace=WORKSPACE))(batch)


def _bad(batch, key, value):
    return {**batch, key: value}


def test_bad_depth_dtype_and_shape(batch):
    adapter = ObservationAdapter(AdapterConfig("rgbd", [CAM]))
    key = f"observation.depth.{CAM}"
    with pytest.raises(SchemaError, match="integer millimetres"):
        adapter(_bad(batch, key, batch[key].float() / 1000))
    with pytest.raises(SchemaError, match=r"\(B, H, W, 1\)"):
        adapter(_bad(batch, key, batch[key][..., 0]))


def test_an_all_invalid_depth_frame_becomes_the_empty_cloud_point(batch, caplog):
    key = f"observation.depth.{CAM}"
    depth = batch[key].clone()
    depth[1] = 0
    adapter = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=WORKSPACE)).eval()
    cloud = adapter(_bad(batch, key, depth))
    intact = adapter(batch)
    # the empty frame: exactly one point, at the workspace box centre, colour 0 (xyz features = its position)
    assert cloud.mask[1].sum() == 1 and cloud.mask[1, 0]
    assert torch.allclose(cloud.xyz[1, 0], torch.tensor([0.0, 0.0, 0.2525]))
    assert torch.equal(cloud.features[1, 0, :3], torch.zeros(3))
    # the other frames are what they would be without it
    for i in (0, 2):
        n = int(intact.mask[i].sum())
        assert int(cloud.mask[i].sum()) == n and torch.equal(cloud.xyz[i, :n], intact.xyz[i, :n])
    assert (adapter.frames_empty, adapter.frames_seen) == (1, 6)
    assert "1 of 3 frames so far had no valid point" in caplog.text


def test_training_on_mostly_empty_frames_stops_after_its_first_batches(batch):
    key = f"observation.depth.{CAM}"
    depth = batch[key].clone()
    depth[:2] = 0  # 2 of every 3 frames empty
    adapter = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=WORKSPACE)).train()
    bad = _bad(batch, key, depth)
    for _ in range(21):  # 63 frames: below the 64 frames the check waits for
        adapter(bad)
    with pytest.raises(SchemaError, match="44 of the first 66 training frames have no valid point"):
        adapter(bad)
    # evaluation never stops on it (a robot keeps acting; the frames are logged)
    adapter.eval()
    for _ in range(30):
        adapter(bad)


def test_non_rigid_cam2world_is_refused(batch):
    key = f"observation.cam2world.{CAM}"
    scaled = batch[key].clone()
    scaled[1, :3, :3] *= 1.05
    for space in ("pointcloud", "pointmap"):
        with pytest.raises(SchemaError, match=r"not a rigid transform.*deviation 0\.158"):
            ObservationAdapter(AdapterConfig(space, [CAM], workspace=WORKSPACE))(_bad(batch, key, scaled))
    bottom = batch[key].clone()
    bottom[0, 3, 0] = 0.5
    with pytest.raises(SchemaError, match="not a rigid transform"):
        ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=WORKSPACE))(_bad(batch, key, bottom))


def test_non_finite_intrinsics_and_missing_keys(batch):
    key = f"observation.intrinsics.{CAM}"
    K = batch[key].clone()
    K[0, 0, 0] = float("nan")
    with pytest.raises(SchemaError, match="intrinsics must be finite"):
        ObservationAdapter(AdapterConfig("pointcloud", [CAM]))(_bad(batch, key, K))
    missing = {k: v for k, v in batch.items() if not k.startswith("observation.cam2world")}
    with pytest.raises(SchemaError, match="Missing 'observation.cam2world.base_camera'"):
        ObservationAdapter(AdapterConfig("pointmap", [CAM]))(missing)


def test_bad_configuration_values():
    with pytest.raises(ValueError, match="obs_space"):
        ObservationAdapter(AdapterConfig("lidar", [CAM]))
    with pytest.raises(ValueError, match="frame"):
        ObservationAdapter(AdapterConfig("pointcloud", [CAM], frame="table"))
    with pytest.raises(ValueError, match="workspace"):
        ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=(1, -1, 0, 1, 0, 1)))


def test_a_policy_config_gives_the_adapter_its_fields():
    """The adapter's settings are the policy config's fields of the same names, with the same defaults."""
    from lerobot_obsbench.policies.obs_act.configuration_obs_act import ObsACTConfig

    assert ObsACTConfig(device="cpu").adapter_config() == AdapterConfig("pointcloud")
    config = ObsACTConfig(device="cpu", obs_space="pointmap", cameras=[CAM], frame="camera", depth_clip=[0.1, 1])
    assert config.adapter_config() == AdapterConfig("pointmap", (CAM,), frame="camera", depth_clip=(0.1, 1.0))


def test_the_point_cloud_stages_run_alone_and_chain_to_the_adapters_cloud(batch):
    adapter = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=WORKSPACE, voxel_size=0.02)).eval()
    everywhere = (-10.0, 10.0, -10.0, 10.0, -10.0, 10.0)  # reaches behind the camera: every pixel
    xyz, rgb, valid = adapter.fuse_cameras(batch, everywhere)
    assert xyz.shape == rgb.shape == (3, 40 * 40, 3) and rgb.min() >= -1 and rgb.max() <= 1
    assert torch.equal(valid, batch[f"observation.depth.{CAM}"].flatten(1) > 0)
    box = torch.tensor(WORKSPACE)
    cropped, colours, mask = adapter.crop_to_workspace(*adapter.fuse_cameras(batch, WORKSPACE), box)
    assert 0 < int(mask.sum()) == int(geometry.crop_mask(cropped, mask, box).sum()) < int(valid.sum())
    sampled, sampled_colours, kept = adapter.sample_points(cropped, colours, mask)
    assert 0 < int(kept.sum()) < int(mask.sum())
    cloud, whole = adapter.point_features(sampled, sampled_colours, kept, box), adapter(batch)
    assert all(torch.equal(getattr(cloud, name), getattr(whole, name)) for name in ("xyz", "features", "mask"))
