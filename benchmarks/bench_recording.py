"""Does the real-robot recording loop keep 30 Hz? Two 640x480 RGB-D cameras (librealsense playing recordings of
a rendered table scene in real time, aligned, converted to mm, downsampled to 320x240) and two Koch arms on a fake
Dynamixel bus, teleoperated by two fake leaders, through `obsbench record`'s own loop and LeRobot's dataset writer.

    .venv/bin/python -m benchmarks.bench_recording [--seconds 8] [--fps 30] [--out FILE]

Writes the achieved frame rate, late steps (longer than 1/fps), camera framesets dropped (replaced before the loop
read them), step-time percentiles and the time spent outside the loop (connecting, saving the episode: video
encoding, aggregation), as JSON; and, side by side on one recording, the time the camera's depth registration takes
per frameset (in each camera's reader thread) against librealsense's `rs.align`, which it replaces.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import load_synthetic, write


def leader_trajectory(i: int) -> dict[str, float]:
    return {
        motor: float(np.sin(0.1 * i + k))
        for k, motor in enumerate(
            ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
        )
    }


class _MonkeyPatch:
    """pytest's monkeypatch.setattr, enough for tests.support.fake_hardware.install outside pytest."""

    def setattr(self, target, name, value):
        setattr(target, name, value)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--fps", type=int, default=30)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--downsample", type=int, default=2)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()

    from lerobot.robots.utils import make_robot_from_config
    from lerobot.teleoperators.utils import make_teleoperator_from_config

    from lerobot_obsbench.commands.record import RecordingConfig, record
    from lerobot_obsbench.robots import BiKochLeaderConfig, BiKochRGBDFollowerConfig
    from lerobot_obsbench.robots.extrinsics import CameraExtrinsics, save_extrinsics
    from lerobot_obsbench.robots.koch.config_koch_arm import KochFollowerArmConfig, KochLeaderArmConfig
    from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig
    from tests.support import fake_hardware
    from tests.support.realsense_synthetic import StreamSpec, SyntheticRGBD, write_bag

    synthetic = load_synthetic()
    fake_hardware.install(_MonkeyPatch())
    work = Path(tempfile.mkdtemp(prefix="bench_recording_"))
    w, h = args.width, args.height
    spec = StreamSpec(w, h, 0.8 * w, 0.8 * w, (w - 1) / 2, (h - 1) / 2)
    poses = {
        "left": synthetic.look_at(eye=(0.4, -0.3, 0.5), target=(0.0, 0.0, 0.0)),
        "right": synthetic.look_at(eye=(0.4, 0.3, 0.5), target=(0.0, 0.0, 0.0)),
    }
    cube = (np.array([0.0, 0.0, 0.025]), 0.025, synthetic.CUBE_RGB)
    cameras = {}
    seconds_of_frames = args.seconds + 3.0  # warm-up and the first observation come before the episode
    for i, (name, pose) in enumerate(poses.items()):
        serial = f"00000000000{i + 1}"
        rgb, depth_mm, _ = synthetic.render(spec.K(), pose, (h, w), [cube])
        print(f"writing {seconds_of_frames:.0f} s of {w}x{h} RGB-D for camera {name} ...")
        frames = ((rgb, depth_mm[..., 0]) for _ in range(int(seconds_of_frames * 30)))
        write_bag(work / f"{name}.bag", SyntheticRGBD(spec, spec, serial_number=serial), frames)
        save_extrinsics(CameraExtrinsics(serial, pose.tolist(), {}, np.eye(4).tolist(), 1, 0, 0, 0, "bench"), work)
        cameras[name] = RealSenseRGBDCameraConfig(
            playback_file=str(work / f"{name}.bag"), width=w, height=h, fps=30, downsample=args.downsample, warmup_s=0
        )
    ports = {f"{kind}_{side}": f"/dev/bench_{kind}_{side}" for kind in ("follower", "leader") for side in ("l", "r")}
    for kind in ("follower", "leader"):
        for side, name in (("l", "left"), ("r", "right")):
            fake_hardware.calibrate_arm(work / kind, f"{kind}_{name}", ports[f"{kind}_{side}"])
            if kind == "leader":
                fake_hardware.script(ports[f"leader_{side}"], leader_trajectory)
    robot = BiKochRGBDFollowerConfig(
        id="follower",
        calibration_dir=work / "follower",
        left_arm_config=KochFollowerArmConfig(port=ports["follower_l"]),
        right_arm_config=KochFollowerArmConfig(port=ports["follower_r"]),
        cameras=cameras,
        extrinsics_dir=str(work),
    )
    teleop = BiKochLeaderConfig(
        id="leader",
        calibration_dir=work / "leader",
        left_arm_config=KochLeaderArmConfig(port=ports["leader_l"]),
        right_arm_config=KochLeaderArmConfig(port=ports["leader_r"]),
    )
    config = RecordingConfig(
        root=str(work / "dataset"),
        task="benchmark",
        num_episodes=1,
        episode_time_s=args.seconds,
        reset_time_s=0.0,
        fps=args.fps,
        keep_episodes=True,
    )
    events = dict.fromkeys(("exit_early", "rerecord_episode", "stop_recording"), False)
    start = time.perf_counter()
    info = record(make_robot_from_config(robot), make_teleoperator_from_config(teleop), config, events)
    total = time.perf_counter() - start
    timing = info["timings"][0]
    result = {
        "cameras": 2,
        "capture": f"{w}x{h}",
        "stored": f"{w // args.downsample}x{h // args.downsample}",
        "target_fps": args.fps,
        "episode_seconds": args.seconds,
        "achieved_fps": timing["fps"],
        "frames": timing["frames"],
        "late_steps": timing["overruns"],
        "camera_framesets_dropped": timing["camera_frames_dropped"],
        "step_ms_p50": round(timing["step_ms_p50"], 2),
        "step_ms_p99": round(timing["step_ms_p99"], 2),
        "outside_the_loop_s": round(total - timing["seconds"], 1),  # connect, save (video encoding), aggregate
        "dataset": str(work / "dataset"),
    }
    print(
        f"{result['achieved_fps']:.1f} fps of {args.fps} over {args.seconds:.0f} s: {result['late_steps']} late "
        f"steps, {result['camera_framesets_dropped']} camera framesets dropped, step p50 {result['step_ms_p50']} ms, "
        f"p99 {result['step_ms_p99']} ms"
    )
    result.update(registration_ms(work / "left.bag", cameras["left"]))
    print(
        f"registration {result['registration_ms_p50']} ms per {w}x{h} frameset (p90 {result['registration_ms_p90']}), "
        f"rs.align {result['rs_align_ms_p50']} ms"
    )
    write("recording", result, args.out)


def registration_ms(bag: Path, config, repeats: int = 30) -> dict:
    """Median / p90 ms of the camera's registration of one frameset's depth, and of rs.align on the same frames."""
    from dataclasses import replace

    import pyrealsense2 as rs

    from lerobot_obsbench.robots.realsense.realsense_rgbd import RealSenseRGBDCamera

    pipeline, rs_config = rs.pipeline(), rs.config()
    rs_config.enable_device_from_file(str(bag), repeat_playback=False)
    pipeline.start(rs_config).get_device().as_playback().set_real_time(False)
    align, align_ms, raws = rs.align(rs.stream.color), [], []
    for _ in range(repeats):
        frames = pipeline.wait_for_frames(5000)
        raws.append(np.asanyarray(frames.get_depth_frame().get_data()).copy())
        start = time.perf_counter()
        align.process(frames)
        align_ms.append((time.perf_counter() - start) * 1000)
    pipeline.stop()
    camera = RealSenseRGBDCamera(replace(config, playback_real_time=False))
    camera.connect(warmup=False)
    register_ms = []
    for raw in raws:
        start = time.perf_counter()
        camera.register(raw)
        register_ms.append((time.perf_counter() - start) * 1000)
    camera.disconnect()
    return {
        "registration_ms_p50": round(float(np.median(register_ms)), 2),
        "registration_ms_p90": round(float(np.percentile(register_ms, 90)), 2),
        "rs_align_ms_p50": round(float(np.median(align_ms)), 2),
    }


if __name__ == "__main__":
    main()
