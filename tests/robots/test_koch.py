"""The plugin's Koch robots through LeRobot's own classes and stock tools, over a fake Dynamixel bus."""

from __future__ import annotations

import builtins

import numpy as np
import pytest
from lerobot.processor import make_default_processors
from lerobot.robots.utils import make_robot_from_config
from lerobot.teleoperators.koch_leader import KochLeaderConfig
from lerobot.teleoperators.utils import make_teleoperator_from_config

from lerobot_obsbench.commands.record import connect
from lerobot_obsbench.robots import BiKochLeaderConfig, BiKochRGBDFollowerConfig, KochRGBDFollowerConfig
from lerobot_obsbench.robots.checks import RobotSetupError
from lerobot_obsbench.robots.koch.config_koch_arm import KochFollowerArmConfig, KochLeaderArmConfig
from tests.support import fake_hardware
from tests.support.fake_hardware import KOCH_MOTORS, calibrate_arm, motor_state

PORTS = {
    "follower_left": "/dev/fake0",
    "follower_right": "/dev/fake1",
    "leader_left": "/dev/fake2",
    "leader_right": "/dev/fake3",
}


@pytest.fixture
def fake_bus(monkeypatch):
    fake_hardware.install(monkeypatch)


def bimanual(tmp_path, cameras=None):
    robot = BiKochRGBDFollowerConfig(
        id="follower",
        calibration_dir=tmp_path / "calibration" / "robot",
        left_arm_config=KochFollowerArmConfig(port=PORTS["follower_left"]),
        right_arm_config=KochFollowerArmConfig(port=PORTS["follower_right"]),
        cameras=cameras or {},
    )
    teleop = BiKochLeaderConfig(
        id="leader",
        calibration_dir=tmp_path / "calibration" / "teleop",
        left_arm_config=KochLeaderArmConfig(port=PORTS["leader_left"]),
        right_arm_config=KochLeaderArmConfig(port=PORTS["leader_right"]),
    )
    return robot, teleop


def calibrate_all(tmp_path) -> None:
    for side in ("left", "right"):
        calibrate_arm(tmp_path / "calibration" / "robot", f"follower_{side}", PORTS[f"follower_{side}"])
        calibrate_arm(tmp_path / "calibration" / "teleop", f"leader_{side}", PORTS[f"leader_{side}"])


def leader_script(offset: float):
    """A smooth scripted leader trajectory: each joint a sine of its own phase."""
    return lambda i: {m: 20 * np.sin(0.3 * i + k + offset) for k, m in enumerate(KOCH_MOTORS)}


def test_stock_calibrate_writes_one_calibration_file_per_arm(fake_bus, tmp_path, monkeypatch):
    from lerobot.scripts.lerobot_calibrate import CalibrateConfig, calibrate

    monkeypatch.setattr(builtins, "input", lambda *_: "")  # the operator presses ENTER at every prompt
    robot, teleop = bimanual(tmp_path)
    calibrate(CalibrateConfig(robot=robot))
    calibrate(CalibrateConfig(teleop=teleop))
    for kind, arm in (("robot", "follower"), ("teleop", "leader")):
        for side in ("left", "right"):
            assert (tmp_path / "calibration" / kind / f"{arm}_{side}.json").is_file()
    # a second connection finds the arms calibrated (the files match what the servos hold)
    device = make_robot_from_config(robot)
    device.connect(calibrate=False)
    assert device.is_calibrated
    device.disconnect()


def test_stock_teleoperation_drives_the_bimanual_follower(fake_bus, tmp_path):
    from lerobot.scripts.lerobot_teleoperate import teleop_loop

    calibrate_all(tmp_path)
    fake_hardware.script(PORTS["leader_left"], leader_script(0.0))
    fake_hardware.script(PORTS["leader_right"], leader_script(1.5))
    robot_cfg, teleop_cfg = bimanual(tmp_path)
    robot, teleop = make_robot_from_config(robot_cfg), make_teleoperator_from_config(teleop_cfg)
    assert type(robot).__name__ == "BiKochRGBDFollower" and type(teleop).__name__ == "BiKochLeader"
    robot.connect()
    teleop.connect()
    teleop_action, robot_action, robot_observation = make_default_processors()
    try:
        teleop_loop(teleop, robot, 60, teleop_action, robot_action, robot_observation, duration=0.3)
    finally:
        robot.disconnect()
        teleop.disconnect()
    for side, offset in (("left", 0.0), ("right", 1.5)):
        goals = motor_state(PORTS[f"follower_{side}"]).goals
        assert len(goals) >= 5
        for i, goal in enumerate(goals):  # read i of the leader became goal i of the follower, joint by joint
            expected = leader_script(offset)(i)
            assert goal.keys() == expected.keys()
            np.testing.assert_allclose([goal[m] for m in KOCH_MOTORS], [expected[m] for m in KOCH_MOTORS])
    assert robot.observation_features.keys() == {f"{s}_{m}.pos" for s in ("left", "right") for m in KOCH_MOTORS}


def test_uncalibrated_arms_and_mismatched_leaders_are_refused(fake_bus, tmp_path):
    robot_cfg, teleop_cfg = bimanual(tmp_path)
    robot, teleop = make_robot_from_config(robot_cfg), make_teleoperator_from_config(teleop_cfg)
    with pytest.raises(RobotSetupError, match="lerobot-calibrate --robot.type=obsbench_bi_koch_follower"):
        connect(robot, teleop)
    robot.disconnect()
    teleop.disconnect()

    calibrate_all(tmp_path)
    calibrate_arm(tmp_path / "calibration" / "teleop", "single", "/dev/fake9")
    single = KochLeaderConfig(id="single", calibration_dir=tmp_path / "calibration" / "teleop", port="/dev/fake9")
    robot, teleop = make_robot_from_config(robot_cfg), make_teleoperator_from_config(single)
    with pytest.raises(RobotSetupError, match="obsbench_bi_koch_follower with obsbench_bi_koch_leader"):
        connect(robot, teleop)
    with pytest.raises(RobotSetupError, match="action keys do not match"):
        robot.send_action(teleop.get_action())
    robot.disconnect()
    teleop.disconnect()


def test_single_arm_follower_takes_a_stock_koch_leader(fake_bus, tmp_path):
    directory = tmp_path / "calibration"
    calibrate_arm(directory, "arm", "/dev/fake5")
    calibrate_arm(directory, "lead", "/dev/fake6")
    fake_hardware.script("/dev/fake6", leader_script(0.5))
    robot = make_robot_from_config(KochRGBDFollowerConfig(id="arm", calibration_dir=directory, port="/dev/fake5"))
    teleop = make_teleoperator_from_config(KochLeaderConfig(id="lead", calibration_dir=directory, port="/dev/fake6"))
    assert type(robot).__name__ == "KochRGBDFollower"
    connect(robot, teleop)
    sent = robot.send_action(teleop.get_action())
    robot.disconnect()
    teleop.disconnect()
    assert sent == {f"{m}.pos": pytest.approx(v) for m, v in leader_script(0.5)(0).items()}


def test_one_source_of_depth_per_camera(fake_bus, tmp_path):
    """LeRobot 0.6's Koch follower adds `<cam>_depth` for a camera with use_depth; the plugin's follower records
    depth through its RGB-D camera type only (registered, with K and pose) and says so for a stock one."""
    from lerobot.cameras.realsense import RealSenseCameraConfig

    from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig

    rgbd = RealSenseRGBDCameraConfig(serial_number="1", width=80, height=60, downsample=1)
    robot = make_robot_from_config(KochRGBDFollowerConfig(port="/dev/fake5", cameras={"front": rgbd}))
    assert {k for k in robot.observation_features if k.startswith("front")} == {
        "front",
        "front.depth",
        "front.intrinsics",
        "front.cam2world",
    }
    stock = RealSenseCameraConfig(serial_number_or_name="1", width=80, height=60, fps=30, use_depth=True)
    robot = make_robot_from_config(KochRGBDFollowerConfig(port="/dev/fake5", cameras={"front": stock}))
    with pytest.raises(ValueError, match="obsbench_realsense_rgbd .*obsbench attach-calibration"):
        robot.observation_features  # noqa: B018


def test_robot_cameras_must_be_calibrated(fake_bus, tmp_path, synthetic_module):
    from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig
    from tests.robots.test_real_robot import write_scene_bag

    pytest.importorskip("pyrealsense2")
    bag = write_scene_bag(tmp_path / "scene.bag", synthetic_module, seconds=1.0)
    camera = RealSenseRGBDCameraConfig(playback_file=str(bag), width=80, height=60, downsample=1, warmup_s=0)
    calibrate_all(tmp_path)
    robot_cfg, _ = bimanual(tmp_path, cameras={"top": camera})
    robot_cfg.extrinsics_dir = str(tmp_path / "extrinsics")
    robot = make_robot_from_config(robot_cfg)
    robot.connect(calibrate=False)
    try:
        with pytest.raises(FileNotFoundError, match="obsbench calibrate-cameras --serial 111122223333"):
            robot.get_observation()
    finally:
        robot.disconnect()


def test_stock_command_lines_parse_the_plugin_types(tmp_path):
    """What lerobot-teleoperate / -calibrate / -replay and obsbench record / rollout parse (draccus over every
    registered type: a config field typed with a registered config would recurse here)."""
    import draccus
    from lerobot.scripts.lerobot_calibrate import CalibrateConfig
    from lerobot.scripts.lerobot_teleoperate import TeleoperateConfig

    from lerobot_obsbench.cli import build_parser
    from lerobot_obsbench.commands import common, record, rollout

    robot = [
        "--robot.type=obsbench_bi_koch_follower",
        "--robot.id=follower",
        "--robot.left_arm_config.port=/dev/ttyACM0",
        "--robot.right_arm_config.port=/dev/ttyACM1",
        "--robot.cameras={top: {type: obsbench_realsense_rgbd, serial_number: '843112073228', downsample: 2}}",
    ]
    teleop = [
        "--teleop.type=obsbench_bi_koch_leader",
        "--teleop.left_arm_config.port=/dev/ttyACM2",
        "--teleop.right_arm_config.port=/dev/ttyACM3",
    ]
    parsed = draccus.parse(TeleoperateConfig, args=robot + teleop)
    assert parsed.robot.left_arm_config.port == "/dev/ttyACM0" and parsed.robot.cameras["top"].stored_size == (240, 320)
    assert draccus.parse(CalibrateConfig, args=teleop).teleop.right_arm_config.port == "/dev/ttyACM3"
    dataset = [f"--dataset.root={tmp_path}", "--dataset.task=fold the cloth", "--dataset.num_episodes=50"]
    # obsbench's own commands: argparse options, the device options handed to LeRobot's configs
    devices, recording = record.configs(common.parse(build_parser(), ["record", *robot, *teleop, *dataset]))
    assert recording.num_episodes == 50 and recording.task == "fold the cloth"
    assert devices.robot.right_arm_config.port == "/dev/ttyACM1"
    assert devices.teleop.left_arm_config.port == "/dev/ttyACM2"
    args = common.parse(build_parser(), ["rollout", *robot, "--policy_path=ckpt", "--task=fold_cloth"])
    config = common.config_from_args(rollout.RolloutConfig, args)
    assert config.episodes == 20 and config.episode_time_s == 30.0 and args.device_options == robot
    single = ["--robot.type=obsbench_koch_follower", "--robot.port=/dev/ttyACM0", "--robot.max_relative_target=5"]
    assert draccus.parse(TeleoperateConfig, args=single + ["--teleop.type=koch_leader", "--teleop.port=/dev/x"])


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: KochFollowerArmConfig(port="p", max_relative_target=float("nan")), "max_relative_target must be"),
        (
            lambda: KochFollowerArmConfig(port="p", max_relative_target={"gripper": -1.0}),
            r"max_relative_target\[gripper\]",
        ),
        (lambda: KochLeaderArmConfig(port="p", gripper_open_pos=float("inf")), "gripper_open_pos must be"),
    ],
)
def test_arm_numbers_are_refused_when_not_finite_or_out_of_range(make, message):
    with pytest.raises(ValueError, match=message):
        make()
