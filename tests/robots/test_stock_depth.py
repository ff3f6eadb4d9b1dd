"""Datasets recorded by stock LeRobot 0.6.1 (a RealSense with `use_depth: true`: depth in the depth camera's own
pixels, no intrinsics, no pose) train the plugin's depth and point-cloud policies once the camera's calibration is
attached; the clouds land on a scene whose geometry the test knows (tests/support/stock_depth_scene.py), in both of
LeRobot's depth storage modes (12-bit log-quantised HEVC video, 16-bit TIFF)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lerobot_obsbench.camera_calibration import read_calibration
from lerobot_obsbench.cli import main
from lerobot_obsbench.geometry import register_depth
from lerobot_obsbench.schema import SchemaError, depth_key, stock_depth_key
from tests.support import stock_depth_scene as scene
from tests.support.helpers import training_setup
from tests.support.paths import REPO_ROOT
from tests.support.realsense_synthetic import StreamSpec, SyntheticRGBD, write_bag

WORKSPACE = [-0.3, 0.3, -0.3, 0.3, -0.02, 0.3]  # the table top included: every point has a surface to land on


@pytest.fixture(scope="module", params=["video", "image"])
def stock_dataset(request, tmp_path_factory):
    root = tmp_path_factory.mktemp(f"stock_{request.param}") / "koch_pick"
    return scene.write_stock_dataset(root, video=request.param == "video")


@pytest.fixture(scope="module")
def calibrated(stock_dataset, tmp_path_factory):
    calib = scene.write_calibration_json(tmp_path_factory.mktemp("calib") / "front.json")
    assert (
        main(["attach-calibration", "--root", str(stock_dataset), "--camera", "front", "--from-json", str(calib)]) == 0
    )
    return stock_dataset


def test_registration_gives_colour_frame_depth():
    """Depth from a rotated, offset depth camera re-expressed in the colour camera: within 1 mm of the ray-cast
    colour-frame depth wherever a value is given, and most of the view covered (the rest: occlusion edges and the
    part of the colour view the depth camera does not see)."""
    _, depth_mm, truth = scene.render()
    f32 = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)[None]
    registered = register_depth(
        f32(depth_mm[..., 0] / 1000.0),
        f32(scene.K_DEPTH),
        f32(scene.DEPTH_TO_COLOR),
        f32(scene.K_COLOR),
        scene.COLOR_SIZE,
    )[0].numpy()
    given = registered > 0
    error_mm = np.abs(registered - truth)[given] * 1000
    assert np.median(error_mm) < 0.5 and (error_mm < 1.0).mean() >= 0.99, np.percentile(error_mm, [50, 99])
    assert given.sum() >= 0.85 * (truth > 0).sum()
    # the test sees a wrong extrinsic: the rotation left out moves the registered depth by millimetres
    translation_only = np.eye(4)
    translation_only[:3, 3] = scene.DEPTH_TO_COLOR[:3, 3]
    wrong = register_depth(
        f32(depth_mm[..., 0] / 1000.0), f32(scene.K_DEPTH), f32(translation_only), f32(scene.K_COLOR), scene.COLOR_SIZE
    )[0].numpy()
    both = (wrong > 0) & (truth > 0)
    assert np.median(np.abs(wrong - truth)[both]) > 0.002


def test_clouds_from_a_stock_dataset_land_on_the_scene(calibrated):
    policy, _, _, dataset = training_setup("obs_act", "pointcloud", calibrated, named="act_pcd", workspace=WORKSPACE)
    policy.eval()
    assert policy.config.cameras == ["front"] and policy.config.camera_resolution == list(scene.COLOR_SIZE)
    assert set(policy.config.depth_calibration) == {"front"}
    sample = dataset[0]
    assert stock_depth_key("front") in sample and depth_key("front") not in sample
    batch = policy.calibrated_depth({k: v[None] for k, v in sample.items() if isinstance(v, torch.Tensor)})
    cloud = policy.model.observation.adapter(batch)
    points = cloud.xyz[0][cloud.mask[0]].numpy()
    assert len(points) > 200
    distance_mm = scene.scene_distance(points) * 1000
    assert np.median(distance_mm) < 2.0 and np.percentile(distance_mm, 90) < 5.0, np.percentile(distance_mm, [50, 90])
    # colour comes from the colour camera's pixel of each point: the sphere's points are red
    red = cloud.features[0][cloud.mask[0]][:, :3].numpy()  # rgb in [-1, 1]
    on_sphere = scene.sphere_points(points)
    assert on_sphere.sum() > 20 and (red[on_sphere, 0] > 0.5).mean() > 0.95


def test_training_step_on_a_stock_dataset(calibrated):
    """act_pcd and dp_pcd train on it (Diffusion reads two observation steps of the stock depth)."""
    from tests.support.helpers import first_batch

    for base, named in (("obs_act", "act_pcd"), ("obs_diffusion", "dp_pcd")):
        policy, pre, _, dataset = training_setup(base, "pointcloud", calibrated, named=named, workspace=WORKSPACE)
        batch = first_batch(dataset, pre, batch_size=2)
        loss, _ = policy.forward(batch)
        assert torch.isfinite(loss)
        loss.backward()


@pytest.mark.parametrize(
    ("obs_space", "sensors"),
    [("rgb", {"front"}), ("depth", {"front_depth"}), ("pointcloud", {"front", "front_depth"})],
)
def test_training_reads_the_stock_depth_map_only_where_the_space_needs_depth(
    calibrated, monkeypatch, obs_space, sensors
):
    """lerobot-train's dataset serves the stock depth map (video or 16-bit images) only to a space that needs depth,
    exactly as LeRobot's reader serves it."""
    from lerobot.datasets import factory
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    from lerobot_obsbench import dataset_reads
    from lerobot_obsbench.policies import ObsDiffusionConfig

    config = ObsDiffusionConfig(obs_space=obs_space, device="cpu")
    meta = LeRobotDatasetMetadata("local/stock_depth", root=calibrated)
    assert {k.removeprefix("observation.images.") for k in config.dataset_reads(meta) if "images" in k} == sensors
    served = {}
    for reader in ("memory", "stock"):
        monkeypatch.setenv(dataset_reads.READER_ENV, reader)
        delta_timestamps = factory.resolve_delta_timestamps(config, meta)
        dataset = LeRobotDataset("local/stock_depth", root=calibrated, delta_timestamps=delta_timestamps)
        served[reader] = [dataset[i] for i in (0, 11, 12, len(dataset) - 1)]
    for sample, expected in zip(served["memory"], served["stock"], strict=True):
        assert {k.removeprefix("observation.images.") for k in sample if k.startswith("observation.images.")} == {
            *sensors,
            *(f"{s}_is_pad" for s in sensors),
        }
        for key, value in sample.items():
            assert torch.equal(value, expected[key]) if isinstance(value, torch.Tensor) else value == expected[key]


def test_without_calibration_the_error_names_the_command(stock_dataset, tmp_path, capsys):
    import shutil

    root = tmp_path / "uncalibrated"
    shutil.copytree(stock_dataset, root)
    (root / "meta" / "obsbench_cameras.json").unlink(missing_ok=True)
    with pytest.raises(SchemaError, match="obsbench attach-calibration --root DATASET --camera front"):
        training_setup("obs_act", "pointcloud", root, named="act_pcd", workspace=WORKSPACE)
    # the colour stream alone still trains rgb (the depth map is not taken for a colour camera)
    policy, *_ = training_setup("obs_act", "rgb", root, named="act_rgb", encoder="resnet18")
    assert policy.config.cameras == ["front"]
    assert main(["validate", "--root", str(root), "--quick"]) == 1
    out = capsys.readouterr().out
    assert "FAILED  pointcloud" in out and "obsbench attach-calibration" in out and "ok      rgb" in out


def test_validate_passes_a_calibrated_dataset(calibrated, capsys):
    assert main(["validate", "--root", str(calibrated)]) == 0
    out = capsys.readouterr().out
    assert "ok      pointcloud" in out and "LeRobot's own depth recording" in out


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("color_size", [480, 640], "color_size [480, 640] is not the dataset's observation.images.front"),
        ("depth_intrinsics", [[600, 0, 320], [0, 600, 240], [0, 0, 1]], "depth_intrinsics (fx 600, fy 600, princip"),
    ],
)
def test_validate_fails_a_calibration_that_does_not_fit_the_frames(calibrated, tmp_path, capsys, field, value, message):
    """A calibration edited or attached for another stream size used to pass while validate said it checked
    every frame's intrinsics."""
    import shutil

    from lerobot_obsbench.camera_calibration import calibration_path

    root = tmp_path / "copy"
    shutil.copytree(calibrated, root)
    stored = json.loads(calibration_path(root).read_text())
    stored["cameras"]["front"][field] = value
    calibration_path(root).write_text(json.dumps(stored))
    assert main(["validate", "--root", str(root)]) == 1
    out = capsys.readouterr().out
    assert message in out and "FAILED  pointcloud" in out and "ok      rgb" in out


def test_attach_from_a_realsense_recording(stock_dataset, tmp_path):
    """Intrinsics, depth->colour extrinsic and depth unit read by librealsense from a .bag of the camera's streams
    (the same code reads a connected camera by serial)."""
    import shutil

    root = tmp_path / "from_bag"
    shutil.copytree(stock_dataset, root)
    (h, w), (hd, wd) = scene.COLOR_SIZE, scene.DEPTH_SIZE
    kc, kd = scene.K_COLOR, scene.K_DEPTH
    camera = SyntheticRGBD(
        colour=StreamSpec(w, h, kc[0, 0], kc[1, 1], kc[0, 2], kc[1, 2]),
        depth=StreamSpec(wd, hd, kd[0, 0], kd[1, 1], kd[0, 2], kd[1, 2]),
        depth_to_colour=scene.DEPTH_TO_COLOR,
    )
    colour, depth_mm, _ = scene.render()
    bag = tmp_path / "front.bag"
    write_bag(bag, camera, [(colour, depth_mm[..., 0])] * 3)
    pose = tmp_path / "extrinsics.json"
    pose.write_text(json.dumps({"serial_number": "1", "cam2world": scene.CAM2WORLD.tolist()}))
    args = ["attach-calibration", "--root", str(root), "--camera", "front", "--from-recording", str(bag)]
    assert main([*args, "--cam2world", str(pose)]) == 0
    calib = read_calibration(root)["front"]
    np.testing.assert_allclose(calib.color_intrinsics, kc, atol=1e-4)
    np.testing.assert_allclose(calib.depth_intrinsics, kd, atol=1e-4)
    np.testing.assert_allclose(calib.depth_to_color, scene.DEPTH_TO_COLOR, atol=1e-6)
    assert calib.depth_unit_mm == pytest.approx(1.0)
    assert calib.depth_min_mm == (10.0 if (root / "videos").exists() else 0.0)


def test_a_camera_is_asked_for_the_dataset_stream_sizes(tmp_path):
    """`--serial` picks the camera's rgb8 colour and z16 depth profiles at the dataset's sizes, read without
    streaming; here the device is a recording's (librealsense's playback device), the same profiles API."""
    from lerobot_obsbench.datasets.calibration import _stream_profiles
    from lerobot_obsbench.robots.realsense.realsense_rgbd import import_realsense

    rs = import_realsense()
    (h, w), (hd, wd) = scene.COLOR_SIZE, scene.DEPTH_SIZE
    kc, kd = scene.K_COLOR, scene.K_DEPTH
    camera = SyntheticRGBD(
        colour=StreamSpec(w, h, kc[0, 0], kc[1, 1], kc[0, 2], kc[1, 2]),
        depth=StreamSpec(wd, hd, kd[0, 0], kd[1, 1], kd[0, 2], kd[1, 2]),
    )
    colour, depth_mm, _ = scene.render()
    bag = tmp_path / "front.bag"
    write_bag(bag, camera, [(colour, depth_mm[..., 0])])
    context = rs.context()
    device = context.load_device(str(bag))
    try:
        color, depth = _stream_profiles(rs, device, [[h, w], [hd, wd]], "RealSense 1")
        assert (color.height(), color.width(), depth.height(), depth.width()) == (h, w, hd, wd)
        assert (color.format(), depth.format()) == (rs.format.rgb8, rs.format.z16)
        with pytest.raises(
            SchemaError, match=rf"RealSense 1 has no 480x640 \(HxW\) rgb8 colour stream \(it has: {h}x{w}\)"
        ):
            _stream_profiles(rs, device, [[480, 640], [hd, wd]], "RealSense 1")
    finally:
        context.unload_device(str(bag))


@pytest.mark.parametrize(
    "args,message",
    [
        (["--camera", "side", "--from-json", "{calib}"], "no LeRobot depth feature observation.images.side_depth"),
        (["--camera", "front", "--from-json", "{nopose}"], "the camera pose is missing: --cam2world"),
        (["--camera", "front", "--from-json", "{calib}", "--cam2world", "{missing}"], "--cam2world"),
        # these ended in tracebacks
        (["--camera", "front", "--from-json", "{broken}"], "--from-json {broken}: not valid JSON"),
        (["--camera", "front", "--from-json", "{calib}", "--cam2world", "{broken}"], "--cam2world {broken}: not valid"),
        (["--camera", "front", "--from-json", "{calib}", "--cam2world", "{words}"], "a 4x4 matrix of numbers"),
    ],
)
def test_attach_refuses_bad_input_in_one_line(stock_dataset, tmp_path, capsys, args, message):
    paths = {
        "calib": scene.write_calibration_json(tmp_path / "c.json"),
        "nopose": scene.write_calibration_json(tmp_path / "n.json", with_pose=False),
        "missing": tmp_path / "nothing.json",
        "broken": tmp_path / "broken.json",
        "words": tmp_path / "words.json",
    }
    paths["broken"].write_text('{"color_intrinsics": [[1, 0')
    paths["words"].write_text(json.dumps([["one", 0, 0, 0]] * 4))
    message = message.format(**paths)
    args = [a.format(**paths) for a in args]
    assert main(["attach-calibration", "--root", str(stock_dataset), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.parametrize("policy_type", ["act_pcd", "dp_pcd"])
def test_stock_lerobot_train_on_a_stock_depth_dataset(calibrated, tmp_path, policy_type, request):
    """Each policy on one of the two storages (ACT on depth video, Diffusion Policy on 16-bit images): both policies
    and both storages trained, in two trainings rather than four."""
    from tests.commands.test_train_cli import lerobot_train

    storage = request.node.callspec.params["stock_dataset"]
    if (policy_type, storage) not in (("act_pcd", "video"), ("dp_pcd", "image")):
        pytest.skip("the other storage trains this policy (paired, not crossed)")

    base = "obs_act" if policy_type.startswith("act") else "obs_diffusion"
    proc = lerobot_train(calibrated, tmp_path / "run", policy_type, None, preset_for=(base, "pointcloud"))
    assert proc.returncode == 0, proc.stderr[-4000:]
    config = json.loads((tmp_path / "run/checkpoints/last/pretrained_model/config.json").read_text())
    assert config["type"] == policy_type and config["cameras"] == ["front"]
    assert config["depth_calibration"]["front"]["depth_to_color"] == scene.DEPTH_TO_COLOR.tolist()


def test_a_checkpoint_keeps_the_calibration_it_was_trained_with(calibrated, tmp_path):
    """Saved in config.json and read back by LeRobot's loader: a loaded policy registers depth with no dataset."""
    from lerobot_obsbench.policies.loading import load_policy

    policy, pre, post, dataset = training_setup(
        "obs_act", "pointcloud", calibrated, named="act_pcd", workspace=WORKSPACE
    )
    for part in (policy, pre, post):
        part.save_pretrained(tmp_path / "ckpt")
    loaded, loaded_pre, _ = load_policy(tmp_path / "ckpt")
    assert loaded.config.depth_calibration == policy.config.depth_calibration
    for p in (policy, loaded):
        p.eval()
        p.reset()
    sample = {k: v[None] for k, v in dataset[0].items() if isinstance(v, torch.Tensor) and k.startswith("observation.")}
    with torch.no_grad():
        torch.testing.assert_close(
            loaded.select_action(loaded_pre(dict(sample))), policy.select_action(pre(dict(sample)))
        )


def test_view_shows_a_calibrated_stock_dataset_on_the_scene(calibrated, tmp_path, capsys):
    """`obsbench view` registers LeRobot's own depth with the attached calibration, as training does: the cloud
    it writes lands on the scene's surfaces."""
    import open3d as o3d

    ply = tmp_path / "cloud.ply"
    args = ["view", "--root", str(calibrated), "--out", str(tmp_path / "v.rrd"), "--ply", str(ply), "--workspace"]
    assert main([*args, *map(str, WORKSPACE), "--voxel-size", "0.002"]) == 0, capsys.readouterr().err
    cloud = o3d.io.read_point_cloud(str(ply))
    points, colours = np.asarray(cloud.points), np.asarray(cloud.colors) * 255
    assert len(points) > 200
    distance_mm = scene.scene_distance(points) * 1000
    assert np.median(distance_mm) <= 2.0, np.percentile(distance_mm, [50, 90])
    on_sphere = scene.sphere_points(points)
    assert on_sphere.sum() > 20 and (colours[on_sphere][:, 0] > 150).mean() > 0.9  # the sphere is red


def test_view_of_an_uncalibrated_stock_dataset_names_the_command(tmp_path, capsys):
    fresh = scene.write_stock_dataset(tmp_path / "raw", video=False, episodes=1, frames=2)
    assert main(["view", "--root", str(fresh), "--out", str(tmp_path / "v.rrd")]) == 2
    err = capsys.readouterr().err
    assert "has no calibration" in err and "obsbench attach-calibration --root DATASET --camera front" in err


def test_the_documented_calibration_example_is_what_attach_calibration_reads():
    """docs/real-robot.md's --from-json example holds exactly the fields the code reads, each valid for its frame."""
    import re

    from lerobot_obsbench.camera_calibration import CameraCalibration
    from lerobot_obsbench.datasets.validation import intrinsics_off

    doc = (REPO_ROOT / "docs" / "real-robot.md").read_text()
    section = doc.split("### The calibration files, field by field", 1)[1]
    example = json.loads(re.search(r"```json\n(.*?)```", section, re.S).group(1))
    documented = set(re.findall(r"^\| `(\w+)` \|", section, re.M))
    assert set(example) <= documented
    assert documented | {"color_size", "depth_size"} == set(CameraCalibration.__dataclass_fields__)
    calibration = CameraCalibration.from_dict({**example, "color_size": [480, 640], "depth_size": [480, 640]})
    for K in (calibration.color_intrinsics, calibration.depth_intrinsics):
        assert not intrinsics_off(np.array(K), (480, 640)).any()


@pytest.fixture(scope="module")
def uncalibrated_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("uncalibrated") / "koch_pick"
    return scene.write_stock_dataset(root, video=False, episodes=1, frames=2)


def _attach_front(root, tmp_path, *options: str) -> int:
    calibration = scene.write_calibration_json(tmp_path / "front.json")
    args = ["attach-calibration", "--root", str(root), "--camera", "front", "--from-json", str(calibration)]
    return main([*args, *options])


@pytest.mark.parametrize(
    "content",
    ['{"version": 1, "cameras": {"fro', "", "[]", '{"front": 5}', '{"version": 2, "cameras": {}}'],
    ids=["truncated", "empty", "list", "another-layout", "another-version"],
)
def test_attach_overwrite_replaces_a_calibration_file_that_cannot_be_read(
    uncalibrated_dataset, tmp_path, capsys, content
):
    """The way out the refusal names works: --overwrite writes a fresh file, which validate then accepts."""
    import shutil

    from lerobot_obsbench.camera_calibration import calibration_path

    root = tmp_path / "koch_pick"
    shutil.copytree(uncalibrated_dataset, root)
    calibration_path(root).write_text(content)
    assert _attach_front(root, tmp_path) == 2
    assert "add --overwrite to replace the file" in capsys.readouterr().err
    assert calibration_path(root).read_text() == content
    assert _attach_front(root, tmp_path, "--overwrite") == 0
    assert json.loads(calibration_path(root).read_text())["version"] == 1
    np.testing.assert_allclose(read_calibration(root)["front"].depth_intrinsics, scene.K_DEPTH)
    assert main(["validate", "--root", str(root), "--quick"]) == 0
    assert "ok      pointcloud" in capsys.readouterr().out


@pytest.mark.parametrize("options", [(), ("--overwrite",)])
def test_attach_replaces_its_cameras_broken_entry_and_keeps_the_others(uncalibrated_dataset, tmp_path, options):
    """A readable file keeps its other cameras as stored (--overwrite or not); the attached camera's own entry is
    replaced even when it cannot be read (it used to end in a TypeError traceback)."""
    import shutil

    from lerobot_obsbench.camera_calibration import calibration_path

    root = tmp_path / "koch_pick"
    shutil.copytree(uncalibrated_dataset, root)
    side = {"color_size": [480, 640], "note": "another camera's entry, kept as it is"}
    calibration_path(root).write_text(json.dumps({"version": 1, "cameras": {"front": 5, "side": side}}))
    assert _attach_front(root, tmp_path, *options) == 0
    stored = json.loads(calibration_path(root).read_text())["cameras"]
    assert stored["side"] == side
    assert stored["front"]["depth_to_color"] == scene.DEPTH_TO_COLOR.tolist()


def test_training_without_calibration_names_the_command_where_lerobot_train_stops(uncalibrated_dataset):
    """lerobot-train asks the policy what it reads before it builds the policy; that refusal used to say 'Record
    depth, intrinsics and cam2world' and never name attach-calibration."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets import factory
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    from lerobot_obsbench.presets import preset_overrides

    fields = {**preset_overrides("tiny", "obs_act", "pointcloud", None), "workspace": WORKSPACE}
    config = PreTrainedConfig.get_choice_class("act_pcd")(obs_space="pointcloud", device="cpu", **fields)
    meta = LeRobotDatasetMetadata("local/test", root=uncalibrated_dataset)
    with pytest.raises(SchemaError, match=r"obsbench attach-calibration --root DATASET --camera (CAM|front) "):
        factory.resolve_delta_timestamps(config, meta)  # the plugin's patched resolver, as lerobot-train calls it


def test_a_refusal_lists_the_datasets_depth_map_among_its_keys(uncalibrated_dataset):
    """The keys a refusal lists are the dataset's own, LeRobot's depth map included (it used to be left out)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    from lerobot_obsbench.schema import validate_features

    features = dict(LeRobotDatasetMetadata("local/test", root=uncalibrated_dataset).features)
    del features["observation.images.front"]  # the colour stream left out: rgb has no camera
    with pytest.raises(SchemaError, match=r"the dataset has \['observation.images.front_depth', 'observation.state'\]"):
        validate_features(features, "rgb")
