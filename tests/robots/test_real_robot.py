"""End to end on the fake bimanual Koch with an RGB-D camera playing an analytic scene (table + cube, known K and
cam2world) through real librealsense: record (killed, then resumed) -> stock LeRobotDataset -> `obsbench validate`
for every space -> the recorded point cloud against the scene -> stock lerobot-train -> rollouts."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.support.realsense_synthetic import StreamSpec, SyntheticRGBD, write_bag

SERIAL = "111122223333"
H, W = 60, 80
SPEC = StreamSpec(W, H, 70.0, 70.0, 39.5, 29.5)
UNITS = 0.0001  # a D400 high-accuracy depth unit: the camera must convert to millimetres
CUBE = (np.array([0.03, -0.02, 0.025]), 0.025, (220, 30, 30))
WORKSPACE = [-0.3, 0.3, -0.3, 0.3, 0.005, 0.3]


def scene_pose(synthetic) -> np.ndarray:
    return synthetic.look_at(eye=(0.35, -0.25, 0.45), target=(0.0, 0.0, 0.03))


def write_scene_bag(path, synthetic, seconds: float):
    """A RealSense recording of the table + cube scene seen from `scene_pose` (colour and depth co-located)."""
    rgb, depth_mm, _ = synthetic.render(SPEC.K(), scene_pose(synthetic), (H, W), [CUBE])
    depth = np.rint(depth_mm[..., 0] * (0.001 / UNITS)).astype(np.uint16)
    camera = SyntheticRGBD(SPEC, SPEC, depth_units=UNITS, serial_number=SERIAL)
    write_bag(path, camera, ((rgb, depth) for _ in range(int(seconds * camera.fps))))
    return path


@pytest.mark.slow
def test_record_train_and_roll_out_on_the_fake_bimanual_robot(tmp_path, synthetic_module, monkeypatch):
    pytest.importorskip("pyrealsense2")
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.robots.utils import make_robot_from_config
    from lerobot.teleoperators.utils import make_teleoperator_from_config

    from lerobot_obsbench import geometry
    from lerobot_obsbench.cli import main as obsbench
    from lerobot_obsbench.commands.record import RecordingConfig, record
    from lerobot_obsbench.commands.rollout import Operator, RolloutConfig, rollout
    from lerobot_obsbench.presets import preset_args
    from lerobot_obsbench.robots.checks import RobotSetupError
    from lerobot_obsbench.robots.extrinsics import CameraExtrinsics, save_extrinsics
    from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig
    from tests.robots.test_koch import PORTS, bimanual, calibrate_all, leader_script
    from tests.support import fake_hardware

    fake_hardware.install(monkeypatch)
    bag = write_scene_bag(tmp_path / "scene.bag", synthetic_module, seconds=8.0)
    extrinsics = tmp_path / "extrinsics"
    save_extrinsics(
        CameraExtrinsics(SERIAL, scene_pose(synthetic_module).tolist(), {}, np.eye(4).tolist(), 1, 0, 0.0, 0.0, "test"),
        extrinsics,
    )
    calibrate_all(tmp_path)
    # played as fast as the loop reads it: the sessions never outrun the recording, however loaded the machine
    camera = RealSenseRGBDCameraConfig(
        playback_file=str(bag), width=W, height=H, downsample=1, warmup_s=0, playback_real_time=False
    )
    robot_cfg, teleop_cfg = bimanual(tmp_path, cameras={"top": camera})
    robot_cfg.extrinsics_dir = str(extrinsics)
    root = tmp_path / "dataset"
    config = RecordingConfig(
        root=str(root), task="fold the cloth", num_episodes=2, episode_time_s=0.6, reset_time_s=0.1, fps=15
    )

    # the first session dies during the second episode (the leader's USB cable is pulled): at the first leader read
    # once that episode's staging folder exists, however fast this machine runs the loop
    def dying(i):
        if (root / ".episodes" / "episode_0001.tmp").is_dir():
            raise KeyboardInterrupt
        return leader_script(0.0)(i)

    fake_hardware.script(PORTS["leader_left"], dying)
    fake_hardware.script(PORTS["leader_right"], leader_script(1.0))
    events = dict.fromkeys(("exit_early", "rerecord_episode", "stop_recording"), False)
    with pytest.raises(KeyboardInterrupt):
        record(make_robot_from_config(robot_cfg), make_teleoperator_from_config(teleop_cfg), config, events)
    staged = sorted(p.name for p in (root / ".episodes").iterdir() if p.is_dir())
    assert staged == ["episode_0000", "episode_0001.tmp"]

    fake_hardware.script(PORTS["leader_left"], leader_script(0.0))
    info = record(make_robot_from_config(robot_cfg), make_teleoperator_from_config(teleop_cfg), config, events)
    assert info["episodes"] == 2 and not (root / ".episodes").exists()
    assert all(0 <= t["overruns"] <= t["frames"] and t["frames"] > 0 for t in info["timings"])  # (speed: a benchmark)

    dataset = LeRobotDataset("local/obsbench_real", root=root)
    assert dataset.meta.total_episodes == 2
    features = dataset.meta.features
    assert features["observation.depth.top"]["dtype"] == "uint16"
    assert tuple(features["observation.depth.top"]["shape"]) == (H, W, 1)
    assert features["observation.state"]["names"][0] == "left_shoulder_pan.pos"
    assert "observation.privileged_state" not in features  # no oracle on a real robot
    assert obsbench(["validate", "--root", str(root), "--repo-id", "local/obsbench_real"]) == 0  # state: n/a

    # the recorded depth, K and cam2world put every pixel on the analytic scene
    frame = dataset[0]
    depth_m = frame["observation.depth.top"][..., 0].double()[None] / 1000
    K = frame["observation.intrinsics.top"].double()[None]
    cam2world = frame["observation.cam2world.top"].double()[None]
    points = geometry.transform_points(geometry.unproject_depth(depth_m, K), cam2world)[0].numpy()
    _, _, truth = synthetic_module.render(SPEC.K(), scene_pose(synthetic_module), (H, W), [CUBE])
    valid = depth_m[0].numpy() > 0
    error_mm = np.linalg.norm(points[valid] - truth[valid], axis=-1) * 1000
    print(f"recorded cloud vs scene: median {np.median(error_mm):.2f} mm, max {error_mm.max():.2f} mm")
    assert valid.mean() > 0.95 and error_mm.max() < 3.0

    out = tmp_path / "train"
    command = [
        str(__import__("pathlib").Path(sys.executable).parent / "lerobot-train"),
        "--policy.type=obs_act",
        "--policy.obs_space=pointcloud",
        "--policy.device=cpu",
        "--dataset.repo_id=local/obsbench_real",
        f"--dataset.root={root}",
        f"--policy.workspace=[{','.join(str(v) for v in WORKSPACE)}]",
        "--batch_size=2",
        "--steps=3",
        "--save_freq=3",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--output_dir={out}",
        *preset_args("tiny", "obs_act", "pointcloud"),
    ]
    proc = subprocess.run(command, capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr[-3000:]
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"

    # each episode ends after the policy's third action (the operator's early-exit key), however slow this machine
    # runs the policy; episode_time_s only bounds a loop that never stops
    goals_before = len(fake_hardware.motor_state(PORTS["follower_left"]).goals)
    policy_actions = {"left": 0}

    def three_step_robot():
        robot = make_robot_from_config(robot_cfg)
        send_action = robot.send_action

        def counted(action):
            policy_actions["left"] -= 1
            if policy_actions["left"] == 0:
                events["exit_early"] = True
            return send_action(action)

        robot.send_action = counted
        return robot

    def start(i):
        policy_actions["left"] = 3
        return True

    operator = Operator(start=start, judge=lambda i: i == 0, events=events)
    rollout_cfg = RolloutConfig(
        policy_path=str(checkpoint),
        episodes=2,
        episode_time_s=120,
        fps=10,
        rest_time_s=0.1,
        out=str(tmp_path / "rollouts"),
    )
    result = rollout(three_step_robot(), rollout_cfg, operator)
    assert result["episodes"] == 2 and result["successes"] == 1 and result["ci95"][0] < 0.5 < result["ci95"][1]
    saved = json.loads((tmp_path / "rollouts" / "results.json").read_text())
    assert saved["successes"] == 1 and saved["robot"] == robot_cfg.type
    assert all(
        r["steps"] == 3 and (tmp_path / "rollouts" / f"episode_{r['episode']:03d}.mp4").is_file()
        for r in result["per_episode"]
    )
    assert len(fake_hardware.motor_state(PORTS["follower_left"]).goals) > goals_before + 4
    assert all(r["step_ms_median"] > 0 and r["achieved_hz"] > 0 for r in result["per_episode"])
    # asynchronous inference: chunks computed off the loop, the arm acting on every step
    rollout_cfg.async_inference = True
    rollout_cfg.out = str(tmp_path / "rollouts_async")
    result = rollout(three_step_robot(), rollout_cfg, operator)
    assert all(r["chunks"] >= 1 and r["steps"] == 3 for r in result["per_episode"])
    rollout_cfg.async_inference = False

    # a checkpoint trained on 80x60 frames refuses a camera that now gives 40x30
    robot_cfg.cameras = {"top": RealSenseRGBDCameraConfig(playback_file=str(bag), width=W, height=H, downsample=2)}
    with pytest.raises(RobotSetupError, match="trained on 60x80, the robot gives 30x40"):
        rollout(make_robot_from_config(robot_cfg), rollout_cfg, operator)
