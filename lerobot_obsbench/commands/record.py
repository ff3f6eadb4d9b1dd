"""`obsbench record`: teleoperated demonstrations on a real robot -> a LeRobotDataset in the same schema simulation
writes.

Built from LeRobot's pieces (robot / teleoperator factories, its keyboard controls, `LeRobotDataset.create` /
`add_frame` / `save_episode`, video encoding, `aggregate_datasets`). LeRobot's own `lerobot-record` cannot write
the schema: it turns every tuple feature into a video, so depth (H, W, 1) uint16, K (3, 3) and cam2world (4, 4)
fail.

Resumable like `obsbench demos` (`datasets.staging`): each episode becomes its own finalized one-episode dataset in
`ROOT/.episodes/episode_NNNN` (LeRobot v3 keeps a parquet writer open until `finalize()`, so a kill would lose an
open multi-episode dataset), written under a temporary name and renamed once complete. A rerun skips the
episodes already there; when all exist they are aggregated into ROOT. A kill loses at most the episode in flight.

Keys (LeRobot's): right arrow ends the episode or the reset early, left arrow re-records the episode, Escape stops
after saving what was recorded.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from lerobot.robots import RobotConfig
from lerobot.teleoperators import TeleoperatorConfig

from lerobot_obsbench.commands import common
from lerobot_obsbench.datasets.staging import STAGING, commit, drop_unfinished, temporary
from lerobot_obsbench.errors import OutputExistsError, UsageError
from lerobot_obsbench.locks import exclusive_output
from lerobot_obsbench.robots.checks import RobotSetupError, require_calibrated
from lerobot_obsbench.robots.frames import action_values, dataset_features, motor_keys, observation_frame
from lerobot_obsbench.schema import ACTION_KEY

NAME = "record"
HELP = "teleoperated demonstrations on a real robot, with depth, into the schema (resumable)"
EXAMPLE = """obsbench record --robot.type=obsbench_koch_follower --robot.port=/dev/ttyACM0 --robot.id=follower \\
    --teleop.type=koch_leader --teleop.port=/dev/ttyACM1 --teleop.id=leader \\
    --dataset.root=data/koch_pick_cube --dataset.task="pick up the cube" --dataset.num_episodes=50"""
INTERRUPTED = "every saved episode is kept in --dataset.root; run the same command to go on"
DEVICE_OPTIONS = ("robot", "teleop")
# LeRobot's device factories wrap what stops them (a missing SDK, a bad port) in ValueError
EXPECTED_ERRORS = (ValueError,)
SIDECAR = "obsbench_recording.json"


@dataclass
class RecordingConfig:
    """Where and what to record (`--dataset.*`)."""

    # Output directory of the dataset (created; an interrupted recording resumes here).
    root: str
    # The task in words, stored with every frame (e.g. "pick up the cube").
    task: str
    # Dataset id (used for the Hub with --dataset.push_to_hub).
    repo_id: str = "local/obsbench_real"
    # Demonstrations to record (the paper: 45 per real task).
    num_episodes: int = 45
    # Seconds of one demonstration.
    episode_time_s: float = 30.0
    # Seconds of the reset between two demonstrations (teleoperated, not recorded).
    reset_time_s: float = 10.0
    # Control and recording rate (Hz).
    fps: int = 30
    # PNG writer threads per camera while recording (LeRobot's default); videos are encoded between episodes.
    image_writer_threads_per_camera: int = 4
    # Video codec for the colour streams (LeRobot's default; h264 encodes faster on small CPUs).
    vcodec: str = "libsvtav1"
    # Upload the dataset to the Hub as --dataset.repo_id once every episode is recorded, privately or not.
    push_to_hub: bool = False
    private: bool = False
    # Keep the per-episode datasets after aggregation.
    keep_episodes: bool = False

    def __post_init__(self) -> None:
        if self.num_episodes < 1 or self.fps < 1 or self.episode_time_s <= 0:
            raise UsageError("--dataset.num_episodes, --dataset.fps and --dataset.episode_time_s must be positive.")


@dataclass
class Devices:
    """`--robot.*` and `--teleop.*`: LeRobot's own device configs."""

    robot: RobotConfig
    teleop: TeleoperatorConfig


@dataclass
class EpisodeTiming:
    frames: int
    seconds: float
    overruns: int  # steps that took longer than 1/fps
    camera_frames_dropped: int  # camera framesets replaced before the loop read them
    step_ms_p50: float
    step_ms_p99: float

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds else 0.0


def _camera_drops(robot) -> int:
    return sum(getattr(cam, "frames_dropped", 0) for cam in getattr(robot, "cameras", {}).values())


def control_loop(robot, teleop, seconds: float, fps: int, events: dict, dataset=None, task: str = "") -> EpisodeTiming:
    """Teleoperate for `seconds` at `fps` (until a key ends it); with `dataset`, add every step as a frame of the
    observation before the action and the action actually sent (after `max_relative_target` clipping)."""
    from lerobot.utils.robot_utils import precise_sleep

    motors = motor_keys(robot)
    period = 1.0 / fps
    drops_before = _camera_drops(robot)
    steps, overruns, frames = [], 0, 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds and not events["exit_early"]:
        t0 = time.perf_counter()
        observation = robot.get_observation()
        sent = robot.send_action(teleop.get_action())
        if dataset is not None:
            frame = observation_frame(observation, motors)
            frame[ACTION_KEY] = action_values(sent, motors)
            dataset.add_frame({**frame, "task": task})
            frames += 1
        elapsed = time.perf_counter() - t0
        steps.append(elapsed * 1000)
        overruns += elapsed > period
        precise_sleep(max(period - elapsed, 0.0))
    events["exit_early"] = False
    return EpisodeTiming(
        frames=frames,
        seconds=time.perf_counter() - start,
        overruns=int(overruns),
        camera_frames_dropped=_camera_drops(robot) - drops_before,
        step_ms_p50=float(np.percentile(steps, 50)) if steps else 0.0,
        step_ms_p99=float(np.percentile(steps, 99)) if steps else 0.0,
    )


def _complete_episodes(staging: Path) -> list[Path]:
    return sorted(p for p in staging.glob("episode_[0-9][0-9][0-9][0-9]") if (p / "meta" / "info.json").is_file())


def connect(robot, teleop) -> None:
    """Connect both without LeRobot's interactive calibration, then refuse what cannot record."""
    robot.connect(calibrate=False)
    teleop.connect(calibrate=False)
    require_calibrated(robot, "robot")
    require_calibrated(teleop, "teleop")
    if set(teleop.action_features) != set(robot.action_features):
        raise RobotSetupError(
            f"{teleop} gives actions {sorted(teleop.action_features)[:4]}..., {robot} takes "
            f"{sorted(robot.action_features)[:4]}...: pair obsbench_koch_follower with koch_leader and "
            "obsbench_bi_koch_follower with obsbench_bi_koch_leader."
        )


def record(robot, teleop, config: RecordingConfig, events: dict | None = None) -> dict:
    """Record `config.num_episodes` demonstrations (resuming), aggregate them into `config.root`; returns the
    sidecar summary. `robot` and `teleop` are LeRobot devices, connected here. One recorder per root: a second
    one is refused (`OutputLockedError`) before it touches the robot."""
    with exclusive_output(config.root, "obsbench record"):
        return _record_locked(robot, teleop, config, events)


def _record_locked(robot, teleop, config: RecordingConfig, events: dict | None) -> dict:
    from lerobot.configs.video import RGBEncoderConfig
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = Path(config.root)
    if (root / SIDECAR).is_file():
        info = json.loads((root / SIDECAR).read_text())
        if info["episodes"] >= config.num_episodes:
            print(f"{root}: {info['episodes']} episodes already recorded")
            return info
        raise OutputExistsError(
            f"{root} already holds an aggregated dataset of {info['episodes']} episodes; record more episodes into "
            "another --dataset.root and merge them with lerobot-edit-dataset."
        )
    staging = root / STAGING
    staging.mkdir(parents=True, exist_ok=True)
    events = events if events is not None else common.keyboard_events()
    connect(robot, teleop)
    try:
        features = dataset_features(robot)
        robot.get_observation()  # fails now, not mid-episode, on a missing camera calibration
        done = _complete_episodes(staging)
        drop_unfinished(staging)
        _check_same_features(done, features)
        cameras = sum(1 for f in features.values() if f["dtype"] == "video")
        timings = json.loads((staging / "timings.json").read_text()) if (staging / "timings.json").is_file() else []
        index = len(done)
        while index < config.num_episodes and not events["stop_recording"]:
            if index > 0:  # a reset before every episode but the dataset's first
                print(f"reset the scene ({config.reset_time_s:.0f} s, right arrow to skip)")
                control_loop(robot, teleop, config.reset_time_s, config.fps, events)
                if events["stop_recording"]:  # Escape during the reset: no further episode
                    break
                events["rerecord_episode"] = False  # a left arrow during the reset concerns no recorded episode
            print(f"recording episode {index + 1}/{config.num_episodes}")
            episode = staging / f"episode_{index:04d}"
            tmp = temporary(episode)
            dataset = LeRobotDataset.create(
                repo_id=config.repo_id,
                fps=config.fps,
                features=features,
                root=tmp,
                robot_type=robot.name,
                use_videos=True,
                image_writer_threads=config.image_writer_threads_per_camera * cameras,
                rgb_encoder=RGBEncoderConfig(vcodec=config.vcodec),
            )
            timing = control_loop(robot, teleop, config.episode_time_s, config.fps, events, dataset, config.task)
            if events["rerecord_episode"] or timing.frames == 0:
                events["rerecord_episode"] = False
                dataset.writer.stop_image_writer()
                shutil.rmtree(tmp)
                print("episode discarded; recording it again")
                continue
            dataset.save_episode()
            dataset.finalize()  # also waits for and stops the image writer
            commit(episode)
            timings.append({"episode": index, **asdict(timing), "fps": round(timing.fps, 2)})
            (staging / "timings.json").write_text(json.dumps(timings, indent=1))
            logging.info(f"episode {index}: {timing.frames} frames at {timing.fps:.1f} fps, {timing.overruns} late")
            index += 1
    finally:
        robot.disconnect()
        teleop.disconnect()
    episodes = _complete_episodes(staging)
    if len(episodes) < config.num_episodes:
        print(f"{root}: {len(episodes)}/{config.num_episodes} episodes recorded; rerun the command to continue")
        return {"episodes": len(episodes), "complete": False}
    return _aggregate(root, episodes[: config.num_episodes], config, timings)


def _check_same_features(episodes: list[Path], features: dict) -> None:
    if not episodes:
        return
    recorded = json.loads((episodes[0] / "meta" / "info.json").read_text())["features"]
    for key, feature in features.items():
        if key not in recorded or list(recorded[key]["shape"]) != list(feature["shape"]):
            raise RobotSetupError(
                f"{episodes[0].parent} holds episodes recorded with other cameras or resolution ({key}: "
                f"{recorded.get(key, {}).get('shape')} vs now {list(feature['shape'])}); use another --dataset.root."
            )


def _aggregate(root: Path, episodes: list[Path], config: RecordingConfig, timings: list[dict]) -> dict:
    from lerobot.datasets.aggregate import aggregate_datasets

    from lerobot_obsbench.patches import array_safe_aggregation

    assembling = root / ".assembling"
    if assembling.exists():
        shutil.rmtree(assembling)
    with array_safe_aggregation():
        aggregate_datasets(
            repo_ids=[f"{config.repo_id}_{p.name}" for p in episodes],
            aggr_repo_id=config.repo_id,
            roots=episodes,
            aggr_root=assembling,
            # one data file per episode: appending to a file concatenates data frames, which pandas cannot do
            # with the depth columns' extension type
            concatenate_data=False,
        )
    for entry in assembling.iterdir():
        target = root / entry.name
        if target.exists():
            shutil.rmtree(target)
        entry.rename(target)
    assembling.rmdir()
    info = {
        "episodes": len(episodes),
        "complete": True,
        "task": config.task,
        "fps": config.fps,
        "timings": timings,
        "mean_fps": round(float(np.mean([t["fps"] for t in timings])), 2) if timings else None,
    }
    (root / SIDECAR).write_text(json.dumps(info, indent=2) + "\n")
    if not config.keep_episodes:
        shutil.rmtree(root / STAGING)
    if config.push_to_hub:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        LeRobotDataset(config.repo_id, root=root).push_to_hub(private=config.private)
    print(f"{root}: {len(episodes)} episodes, mean {info['mean_fps']} fps")
    return info


def add_arguments(p: argparse.ArgumentParser) -> None:
    common.add_config_options(p, RecordingConfig, "dataset")


def configs(args: argparse.Namespace) -> tuple[Devices, RecordingConfig]:
    """The robot and teleoperator configs (LeRobot's parser) and the recording's, from the parsed arguments."""
    from lerobot.teleoperators import koch_leader  # noqa: F401  (registers --teleop.type=koch_leader, one arm)

    return common.device_configs(Devices, args.device_options, NAME), common.config_from_args(
        RecordingConfig, args, "dataset"
    )


def run(args: argparse.Namespace) -> int:
    from lerobot.robots.utils import make_robot_from_config
    from lerobot.teleoperators.utils import make_teleoperator_from_config

    devices, config = configs(args)
    record(make_robot_from_config(devices.robot), make_teleoperator_from_config(devices.teleop), config)
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
