"""RLBench support without the simulator: format conventions against independent references, the importer on
synthetic demonstrations in both layouts, language goals with a tiny offline CLIP, and the evaluation protocol
against a fake `rlbench` module."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lerobot_obsbench import geometry
from lerobot_obsbench.rlbench import format as rlformat
from lerobot_obsbench.rlbench.paper_tasks import PAPER_TASKS, RLBenchTaskError, rlbench_task
from tests.support import rlbench_fixtures
from tests.support.paths import FAKE_RLBENCH

BIN = Path(sys.executable).parent


# ---- conventions ----------------------------------------------------------------------------------------------


def test_depth_codec_round_trips_and_matches_the_generator_packing():
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 1, (20, 30))
    packed = rlformat.encode_depth(d)
    assert np.array_equal(packed, rlbench_fixtures.encode_depth(d))
    assert np.abs(rlformat.decode_depth(packed) - d).max() <= 0.5 / (2**24 - 1) + 1e-12
    mm = rlformat.depth_millimetres(rlformat.decode_depth(packed), 0.01, 4.5)
    assert mm.dtype == np.uint16 and mm.shape == (20, 30, 1)
    assert np.abs(mm[..., 0] / 1000 - (0.01 + d * 4.49)).max() <= 0.0005 + 1e-6
    with pytest.raises(rlformat.RLBenchFormatError, match=r"\(H, W, 3\) uint8"):
        rlformat.decode_depth(np.zeros((4, 4), np.uint16))


def test_rlbench_camera_becomes_opencv():
    """RLBench's own projection (negative focal lengths, camera -> world extrinsics inverted) and OpenCV's with the
    converted K and cam2world send every world point to the same pixel."""
    rng = np.random.default_rng(1)
    rlbench_K = np.array([[-110.8, 0, 64], [0, -110.8, 64], [0, 0, 1]])
    extrinsics = np.eye(4)
    extrinsics[:3, :3] = Rotation.from_euler("xyz", rng.uniform(-1, 1, 3)).as_matrix()
    extrinsics[:3, 3] = rng.uniform(-1, 1, 3)
    K, cam2world = rlformat.rlbench_to_opencv(rlbench_K, extrinsics)
    assert K[0, 0] > 0 and K[1, 1] > 0 and geometry.rigidity_error(torch.tensor(cam2world)) < 1e-12
    cam_rl = np.linalg.inv(extrinsics)[:3] @ np.c_[rng.uniform(-1, 1, (50, 3)), np.ones(50)].T
    cam_rl[2] = np.abs(cam_rl[2]) + 0.5  # in front of the camera
    world = (extrinsics @ np.r_[cam_rl, np.ones((1, 50))])[:3].T
    pixels_rl = (rlbench_K @ cam_rl)[:2] / cam_rl[2]
    cam_cv = (np.linalg.inv(cam2world) @ np.c_[world, np.ones(50)].T)[:3]
    pixels_cv = (K @ cam_cv)[:2] / cam_cv[2]
    np.testing.assert_allclose(pixels_cv, pixels_rl, atol=1e-9)


@pytest.mark.parametrize("near, far", [(0.5, 0.5), (-0.1, 4.5), (0.01, 100.0), (0.01, float("nan"))])
def test_depth_planes_that_would_rescale_every_point_are_refused(near, far):
    misc = {"front_camera_extrinsics": np.eye(4), "front_camera_intrinsics": np.diag([-1.0, -1.0, 1.0])}
    misc.update(front_camera_near=near, front_camera_far=far)
    with pytest.raises(rlformat.RLBenchFormatError, match=r"front_camera_near = .* and front_camera_far = .* in the"):
        rlformat.camera_views(np.zeros((4, 4, 3), np.uint8), np.full((4, 4), 0.5), misc, "front")
    misc.update(front_camera_near=0.01, front_camera_far=4.5)
    views = rlformat.camera_views(np.zeros((4, 4, 3), np.uint8), np.full((4, 4), 0.5), misc, "front")
    assert views["depth"].max() == 2255  # 0.01 + 0.5 * 4.49 m


@pytest.mark.parametrize("mode", ["pcm_compat", "xyzw"])
def test_rotation_6d_and_position_scaling_round_trip(mode):
    rng = np.random.default_rng(2)
    quat = rng.normal(size=(100, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    six = rlformat.quaternion_to_6d(quat, mode)
    np.testing.assert_allclose(rlformat.quaternion_to_6d(-quat, mode), six, atol=1e-12)  # q and -q: one rotation
    back = rlformat.rotation_6d_to_quaternion(six, mode)
    np.testing.assert_allclose(np.abs((back * quat).sum(1)), 1.0, atol=1e-9)  # the same quaternion up to sign
    task = rlbench_task("open_drawer")
    pose = np.c_[rng.uniform(task.location_low, task.location_high, (100, 3)), quat]
    encoded = rlformat.encode_pose(pose, np.ones(100), np.zeros(100), task.location_low, task.location_high, mode)
    assert encoded.shape == (100, 11) and np.abs(encoded[:, :3]).max() <= 1.0
    action = rlformat.decode_action(encoded, task.location_low, task.location_high, mode)
    np.testing.assert_allclose(action[:, :3], pose[:, :3], atol=1e-6)
    np.testing.assert_allclose(np.abs((action[:, 3:7] * quat).sum(1)), 1.0, atol=1e-5)
    assert (action[:, 7] == 1).all() and (action[:, 8] == 0).all()
    if mode == "xyzw":  # the true rotation: the 6-D rows are the matrix's first two rows
        np.testing.assert_allclose(six[:, :3], Rotation.from_quat(quat).as_matrix()[:, 0], atol=1e-12)


def test_task_table():
    assert len(PAPER_TASKS) == 9 and all(rlbench_task(t).in_paper for t in PAPER_TASKS)
    assert not rlbench_task("stack_blocks").in_paper
    task = rlbench_task("turn_tap")
    assert task.location_low[2] == pytest.approx(0.884225606918335, abs=1e-15)
    with pytest.raises(RLBenchTaskError, match="unknown RLBench task 'open_drawers'.*open_drawer.*stack_cups"):
        rlbench_task("open_drawers")


# ---- the pickles ----------------------------------------------------------------------------------------------


class Exploit:
    def __reduce__(self):
        return (os.system, ("echo owned",))


def test_malicious_and_truncated_pickles_are_refused(tmp_path):
    bad = tmp_path / "low_dim_obs.pkl"
    bad.write_bytes(pickle.dumps({"payload": Exploit()}))
    with pytest.raises(rlformat.RLBenchFormatError, match=r"refusing to load global (posix|os)\.system"):
        rlformat.load_pickle(bad)
    cut = tmp_path / "cut.pkl"
    with rlbench_fixtures.rlbench_classes() as (demo_cls, _):
        demo = demo_cls()
        demo.__dict__.update(_observations=[np.arange(1000.0)])
        cut.write_bytes(pickle.dumps(demo)[:200])
    with pytest.raises(rlformat.RLBenchFormatError, match=f"{cut}: cannot read"):
        rlformat.load_pickle(cut)


def test_stand_in_pickles_load_without_rlbench(tmp_path, synthetic_module):
    """Both the numpy-2 protocol-4 file and the numpy-1-style protocol-2 file load in a process where no
    `rlbench` module exists."""
    placed = rlbench_fixtures.write_task(tmp_path / "open_drawer", synthetic_module, "all_variations")
    assert "rlbench" not in sys.modules
    assert (
        b"numpy.core.multiarray"
        in (tmp_path / "open_drawer/all_variations/episodes/episode1/low_dim_obs.pkl").read_bytes()
    )
    for ref in rlformat.find_episodes(tmp_path / "open_drawer"):
        episode = rlformat.read_episode(ref)
        want = placed[str(ref.path)]
        assert episode.variation == want["variation"] and episode.descriptions[0] == want["description"]
        got = np.stack([o.gripper_pose for o in episode.observations])
        np.testing.assert_array_equal(got, want["poses"])
        assert episode.random_seed[0] == "MT19937" and episode.random_seed[1].shape == (624,)
        assert float(episode.observations[1].ignore_collisions) == 1.0


# ---- language -------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_clip():
    """A tiny random CLIP (512-d text features, CLIP's tokenizer) built offline."""
    open_clip = pytest.importorskip("open_clip")
    from lerobot_obsbench.rlbench.text import CLIP_MODEL, OpenClipTextEncoder

    torch.manual_seed(0)
    model = open_clip.CLIP(
        embed_dim=512,
        vision_cfg=dict(image_size=32, layers=1, width=64, patch_size=16),
        text_cfg=dict(context_length=77, vocab_size=49408, width=64, heads=2, layers=1),
        quick_gelu=True,
    )
    return OpenClipTextEncoder(model, open_clip.get_tokenizer(CLIP_MODEL), "tiny-random-clip")


def test_text_encoder_features_and_cache(tiny_clip, monkeypatch):
    texts = ["open the top drawer", "open the bottom drawer", "open the top drawer"]
    features = tiny_clip.encode(texts)
    assert features.shape == (3, 512) and features.dtype == np.float32
    np.testing.assert_array_equal(features[0], features[2])
    assert not np.allclose(features[0], features[1])
    calls = []
    original = tiny_clip.model.encode_text
    monkeypatch.setattr(tiny_clip.model, "encode_text", lambda *a, **k: calls.append(1) or original(*a, **k))
    np.testing.assert_array_equal(tiny_clip.encode(["open the bottom drawer"])[0], features[1])
    assert calls == []  # cached per description


def test_clip_weights_are_never_fetched_implicitly(tmp_path):
    pytest.importorskip("open_clip")
    from lerobot_obsbench.rlbench.text import TextEncoderError, load_clip_text_encoder

    with pytest.raises(TextEncoderError, match="not found: pass a local ViT-B/16 checkpoint"):
        load_clip_text_encoder(str(tmp_path / "missing.pt"))
    junk = tmp_path / "junk.pt"
    torch.save({"not": torch.zeros(1)}, junk)
    with pytest.raises(TextEncoderError, match="cannot load CLIP ViT-B-16-quickgelu weights"):
        load_clip_text_encoder(str(junk))


# ---- the importer ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def imported(tmp_path_factory, synthetic_module, tiny_clip):
    """Two tasks, one per layout, imported with the language goal; one episode is corrupt."""
    from lerobot_obsbench.datasets.rlbench_import import import_rlbench

    root = tmp_path_factory.mktemp("rlbench")
    out = {}
    for task, layout in (("open_drawer", "all_variations"), ("close_jar", "variations")):
        placed = rlbench_fixtures.write_task(root / "train" / task, synthetic_module, layout)
        out[task] = {"placed": placed, "dir": root / "data" / task}
    # a truncated pickle in a third episode of close_jar
    broken = root / "train" / "close_jar" / "variation0" / "episodes" / "episode7"
    rlbench_fixtures.write_episode(broken, synthetic_module, 3, seed=7)
    (broken / "low_dim_obs.pkl").write_bytes((broken / "low_dim_obs.pkl").read_bytes()[:100])
    for task in out:
        out[task]["info"] = import_rlbench(root / "train" / task, out[task]["dir"], text_encoder=tiny_clip)
    out["root"] = root
    return out


def test_import_writes_the_schema_with_language_and_skips_the_corrupt_episode(imported, tiny_clip):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    for task in ("open_drawer", "close_jar"):
        info = imported[task]["info"]
        assert len(info["episodes"]) == 3 and info["quaternion"] == "pcm_compat"
        ds = LeRobotDataset(f"local/{task}", root=imported[task]["dir"])
        assert ds.meta.total_episodes == 3 and ds.meta.total_frames == 9 and ds.fps == 20
        frame = ds[0]
        assert frame["observation.state"].shape == (11,) and frame["action"].shape == (11,)
        assert frame["observation.depth.front"].dtype in (torch.uint16, torch.int32, torch.int64)
        want = tiny_clip.encode([imported[task]["placed"][info["episodes"][0]["path"]]["description"]])[0]
        np.testing.assert_allclose(frame["observation.environment_state"].numpy(), want, rtol=1e-6)
        # action[t] is state[t + 1]
        np.testing.assert_allclose(ds[0]["action"].numpy(), ds[1]["observation.state"].numpy(), atol=1e-6)
    skipped = imported["close_jar"]["info"]["skipped"]
    assert len(skipped) == 1 and skipped[0]["path"].endswith("variation0/episodes/episode7")
    assert "cannot read this RLBench pickle" in skipped[0]["error"]


def test_imported_points_are_the_placed_world_points(imported):
    """Unprojecting the imported depth with the imported K and cam2world gives back the ray-cast world points:
    sub-millimetre, the millimetre depth quantisation included."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    task = imported["open_drawer"]
    ds = LeRobotDataset("local/open_drawer", root=task["dir"])
    for index, meta in enumerate(task["info"]["episodes"]):
        placed = task["placed"][meta["path"]]
        frame = ds[int(ds.meta.episodes["dataset_from_index"][index])]
        depth_m = frame["observation.depth.front"][..., 0].double()[None] / 1000
        K = frame["observation.intrinsics.front"].double()[None]
        cam2world = frame["observation.cam2world.front"].double()[None]
        points = geometry.transform_points(geometry.unproject_depth(depth_m, K), cam2world)[0].numpy()
        error = np.linalg.norm(points[placed["hit"]] - placed["points"][placed["hit"]], axis=-1)
        assert placed["hit"].sum() > 200 and error.max() < 1e-3, error.max()


def test_imported_dataset_passes_validate_for_every_space(imported):
    proc = subprocess.run(
        [str(BIN / "obsbench"), "validate", "--root", str(imported["open_drawer"]["dir"])],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for space in ("rgb", "depth", "rgbd", "pointmap", "pointcloud"):
        assert space in proc.stdout


def test_import_resumes_and_refuses_another_source(imported, tiny_clip, capsys):
    from lerobot_obsbench.datasets.rlbench_import import import_rlbench

    root = imported["root"]
    again = import_rlbench(root / "train" / "open_drawer", imported["open_drawer"]["dir"], text_encoder=tiny_clip)
    assert again == imported["open_drawer"]["info"] and "already imported" in capsys.readouterr().out
    with pytest.raises(FileExistsError, match="already holds a dataset made with other settings \\(source"):
        import_rlbench(root / "train" / "close_jar", imported["open_drawer"]["dir"], task="close_jar")
    # the same source with other cameras, or without the language goal, is another dataset: refused, not returned
    source, done = root / "train" / "open_drawer", imported["open_drawer"]["dir"]
    with pytest.raises(FileExistsError, match="cameras \\['front'\\] there, \\['wrist'\\] asked"):
        import_rlbench(source, done, cameras=("wrist",), text_encoder=tiny_clip)
    with pytest.raises(FileExistsError, match=f"language {tiny_clip.name!r} there, None asked"):
        import_rlbench(source, done)


def test_import_resumes_after_an_interruption(tmp_path, synthetic_module, monkeypatch):
    """A run killed while converting its second episode keeps the first: the rerun converts only the others
    (episodes go by variation, then number: episode0, episode2, episode1)."""
    from lerobot_obsbench.datasets import rlbench_import

    rlbench_fixtures.write_task(tmp_path / "turn_tap", synthetic_module, "variations", episodes=3, frames=3)
    converted = []
    original = rlbench_import.convert_episode

    def convert_then_die(ref, *args):
        converted.append(ref.path.name)
        if len(converted) == 2:
            raise KeyboardInterrupt
        return original(ref, *args)

    monkeypatch.setattr(rlbench_import, "convert_episode", convert_then_die)
    with pytest.raises(KeyboardInterrupt):
        rlbench_import.import_rlbench(tmp_path / "turn_tap", tmp_path / "out")
    monkeypatch.setattr(
        rlbench_import, "convert_episode", lambda ref, *a: converted.append(ref.path.name) or original(ref, *a)
    )
    info = rlbench_import.import_rlbench(tmp_path / "turn_tap", tmp_path / "out")
    assert len(info["episodes"]) == 3 and converted == ["episode0", "episode2", "episode2", "episode1"]
    assert info["language"] is None


def test_cli_refuses_unknown_tasks_and_a_missing_simulator(tmp_path):
    proc = subprocess.run(
        [str(BIN / "obsbench"), "import-rlbench", "--data", str(tmp_path), "--out", str(tmp_path / "o"), "--task", "x"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "unknown RLBench task 'x'" in proc.stderr and "open_drawer" in proc.stderr
    env = {k: v for k, v in os.environ.items() if k not in ("COPPELIASIM_ROOT", "DISPLAY")}
    proc = subprocess.run(
        [
            str(BIN / "obsbench"),
            "eval-rlbench",
            "--policy.path",
            str(tmp_path),
            "--task",
            "open_drawer",
            "--data",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    assert proc.returncode == 2
    for needed in ("CoppeliaSim 4.1", "COPPELIASIM_ROOT", "PyRep", "MohitShridhar/RLBench", "X display"):
        assert needed in proc.stderr, needed
    proc = subprocess.run(
        [
            str(BIN / "obsbench"),
            "eval-rlbench",
            "--policy.path",
            "p",
            "--task",
            "open_drawer",
            "--data",
            "d",
            "--camera-view",
            "x:five",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "expected AXIS:DEGREES[,SHIFT_M] with AXIS y or z" in proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("space", ["pointcloud", "rgb"])
def test_lerobot_train_on_the_imported_dataset_with_the_language_goal(
    imported, tmp_path, space, tiny_clip, monkeypatch
):
    from lerobot_obsbench.presets import preset_args

    out = tmp_path / "train"
    command = [
        str(BIN / "lerobot-train"),
        "--policy.type=obs_act",
        f"--policy.obs_space={space}",
        "--policy.cameras=[front]",
        "--policy.workspace=[-0.3,0.7,-0.5,0.5,0.76,1.6]",
        "--dataset.repo_id=local/open_drawer",
        f"--dataset.root={imported['open_drawer']['dir']}",
        "--batch_size=2",
        "--steps=2",
        "--save_freq=2",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--output_dir={out}",
        *preset_args("tiny", "obs_act", space),
    ]
    proc = subprocess.run(command, capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr[-3000:]
    config = json.loads((out / "checkpoints/last/pretrained_model/config.json").read_text())
    assert config["input_features"]["observation.environment_state"]["shape"] == [512]
    assert config["output_features"]["action"]["shape"] == [11]
    _evaluate_with_the_language_goal(out / "checkpoints/last/pretrained_model", imported, tiny_clip, monkeypatch)


def _evaluate_with_the_language_goal(checkpoint: Path, imported, tiny_clip, monkeypatch) -> None:
    """The checkpoint through RLBench's protocol, against the stand-in that replays the recorded episodes
    (tests/support/fake_rlbench): the goal is the description's CLIP feature, as the importer computed it."""
    from lerobot_obsbench.rlbench import evaluate as rlevaluate
    from lerobot_obsbench.rlbench import text

    before = set(sys.modules)
    monkeypatch.syspath_prepend(str(FAKE_RLBENCH))
    monkeypatch.setenv("COPPELIASIM_ROOT", str(checkpoint))
    monkeypatch.setenv("DISPLAY", ":99")
    encoded = []
    monkeypatch.setattr(text, "load_clip_text_encoder", lambda weights: tiny_clip)
    monkeypatch.setattr(
        tiny_clip, "encode", lambda texts, encode=tiny_clip.encode: encoded.extend(texts) or encode(texts)
    )
    try:
        result = rlevaluate.evaluate_checkpoint(
            checkpoint,
            rlbench_task("open_drawer"),
            imported["root"] / "train",
            episodes=2,
            max_steps=2,
            clip_weights="ViT-B-16.pt",
        )
    finally:
        for name in set(sys.modules) - before:
            if name.split(".")[0] in ("rlbench", "pyrep"):
                del sys.modules[name]
    assert result["episodes"] == 2 and result["per_seed"]["seeds"] == [0, 1]
    assert all(1 <= steps <= 2 for steps in result["per_seed"]["length"])
    # each episode's first variation description, in the order of the split's episodes
    descriptions = [e["description"] for e in imported["open_drawer"]["info"]["episodes"][:2]]
    assert encoded == descriptions


# ---- evaluation protocol against a fake rlbench ----------------------------------------------------------------


class FakeTaskEnv:
    """Records the protocol's calls; the episode succeeds at `success_step` unless the arm is sent to x < 0;
    the first `step0_failures` attempts of an episode raise a planning error."""

    def __init__(self, log, success_step, step0_failures):
        self.log, self.success_step, self.step0_failures = log, success_step, step0_failures
        self.variation, self.steps, self.attempts = None, 0, 0
        camera = types.SimpleNamespace(matrix=np.eye(4))
        camera.get_matrix = lambda: camera.matrix
        camera.set_matrix = lambda m: setattr(camera, "matrix", m)
        self._scene = types.SimpleNamespace(_cam_front=camera)

    def set_variation(self, v):
        self.log.append(("set_variation", v))

    def get_demos(self, amount, live_demos, random_selection, from_episode_number):
        assert amount == 1 and not live_demos and not random_selection
        self.log.append(("get_demos", from_episode_number))
        return [types.SimpleNamespace(variation_number=from_episode_number % 3)]

    def reset_to_demo(self, demo):
        self.log.append(("reset_to_demo", demo.variation_number))
        self.steps, self.attempts = 0, 0
        return [f"variation {demo.variation_number}"], "obs0"

    def step(self, action):
        from pyrep.errors import ConfigurationPathError, IKError
        from rlbench.backend.exceptions import InvalidActionError

        if self.steps == 0 and self.attempts < self.step0_failures:
            self.attempts += 1
            raise (IKError, ConfigurationPathError, InvalidActionError)[self.attempts % 3]("no path")
        if action[0] < 0:
            raise IKError("unreachable")
        self.steps += 1
        return f"obs{self.steps}", float(self.steps == self.success_step), False


@pytest.fixture
def fake_rlbench(monkeypatch, tmp_path):
    """The stand-in `rlbench` and `pyrep` packages (tests/support/fake_rlbench) with a scripted environment recording
    the protocol's calls, plus the environment variables `require_rlbench` checks."""
    log = []
    state = {"success_step": 3, "step0_failures": 0}

    class Environment:
        def __init__(self, action_mode, dataset_root, obs_config, headless):
            log.append(("environment", dataset_root, type(action_mode).__name__, headless))

        def launch(self):
            log.append(("launch",))

        def get_task(self, task_class):
            log.append(("get_task", task_class))
            self.task_env = FakeTaskEnv(log, state["success_step"], state["step0_failures"])
            state["task_env"] = self.task_env
            return self.task_env

        def shutdown(self):
            log.append(("shutdown",))

    before = set(sys.modules)
    monkeypatch.syspath_prepend(str(FAKE_RLBENCH))
    import rlbench.environment

    monkeypatch.setattr(rlbench.environment, "Environment", Environment)
    monkeypatch.setenv("COPPELIASIM_ROOT", str(tmp_path))
    monkeypatch.setenv("DISPLAY", ":99")
    yield log, state
    for name in set(sys.modules) - before:  # later tests see no rlbench, as on a machine without it
        if name.split(".")[0] in ("rlbench", "pyrep"):
            del sys.modules[name]


class ScriptedPolicy:
    """Returns 25 candidate actions per step; the first `bad_first` candidates at step 0 are unreachable."""

    def __init__(self, bad_first=0):
        self.bad_first, self.descriptions, self.calls = bad_first, [], 0

    def reset(self, description):
        self.descriptions.append(description)

    def act(self, obs):
        self.calls += 1
        actions = np.ones((25, 9))
        if obs == "obs0":
            actions[: self.bad_first, 0] = -1
        return actions


def test_eval_protocol_order_budget_and_success(fake_rlbench):
    from lerobot_obsbench.rlbench.evaluate import CameraView, evaluate_rlbench

    log, state = fake_rlbench
    policy = ScriptedPolicy()
    result = evaluate_rlbench(policy, rlbench_task("open_drawer"), Path("data/test"), episodes=4, max_steps=2)
    assert result["successes"] == 0 and all(r["steps"] == 2 for r in result["per_episode"])  # success at 3 > 2
    log.clear()
    result = evaluate_rlbench(
        policy, rlbench_task("open_drawer"), Path("data/test"), episodes=4, camera_view=CameraView("y", -5, 0.1)
    )
    assert (
        result["successes"] == 4
        and result["success_rate"] == 1.0
        and [r["steps"] for r in result["per_episode"]] == [3] * 4
    )
    episodes = [entry for entry in log if entry[0] in ("set_variation", "get_demos", "reset_to_demo")]
    assert episodes[:6] == [
        ("set_variation", -1),
        ("get_demos", 0),
        ("set_variation", 0),
        ("reset_to_demo", 0),
        ("set_variation", -1),
        ("get_demos", 1),
    ]
    assert [e[1] for e in log if e[0] == "get_demos"] == [0, 1, 2, 3]
    assert log[0] == ("environment", "data/test", "MoveArmThenGripper", True) and log[-1] == ("shutdown",)
    assert policy.descriptions[-4:] == ["variation 0", "variation 1", "variation 2", "variation 0"]
    moved = state["task_env"]._scene._cam_front.matrix
    np.testing.assert_allclose(moved[:3, :3], Rotation.from_euler("y", -5, degrees=True).as_matrix())
    np.testing.assert_allclose(moved[[0, 2], 3], [0.1, 0.1])


def test_eval_retries_planning_errors_only_at_step_0(fake_rlbench):
    from lerobot_obsbench.rlbench.evaluate import evaluate_rlbench

    _, state = fake_rlbench
    state["step0_failures"] = 5  # five planning errors, then the sixth candidate goes through
    result = evaluate_rlbench(ScriptedPolicy(), rlbench_task("open_drawer"), Path("t"), episodes=2)
    assert result["successes"] == 2
    state["step0_failures"] = 25  # more than the 20 retries: the episode fails at step 0
    result = evaluate_rlbench(ScriptedPolicy(), rlbench_task("open_drawer"), Path("t"), episodes=2)
    assert result["successes"] == 0 and all("at step 0" in r["failure"] for r in result["per_episode"])
    assert all(r["steps"] == 0 for r in result["per_episode"])
    state["step0_failures"] = 0  # a planning error after step 0 ends the episode without retrying

    class FailsLater(ScriptedPolicy):
        def act(self, obs):
            actions = super().act(obs)
            if obs == "obs1":
                actions[:, 0] = -1
            return actions

    result = evaluate_rlbench(FailsLater(), rlbench_task("open_drawer"), Path("t"), episodes=1)
    assert result["per_episode"][0]["steps"] == 1 and "IKError at step 1" in result["per_episode"][0]["failure"]
