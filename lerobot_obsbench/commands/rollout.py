"""`obsbench rollout`: a trained checkpoint on a real robot for N episodes, the operator judging each
(docs/real-robot.md).

Per episode: the operator starts it, the policy acts at `fps` for at most `episode_time_s` (ACT checkpoints keep
their temporal ensembling: one new chunk per step, averaged; or, with `async_inference`, the next chunk is
computed while the arm follows the current one — `robots.realtime`), the arm returns to its rest pose (the joint
positions at connection), and the operator marks success or failure. The robot's own `max_relative_target`
limits every commanded step. Keys: right arrow ends the episode early, Escape aborts it (the arm returns to rest
and no further episode starts). Writes one video per episode and the same results JSON as `obsbench eval`
(success rate with its Wilson 95% interval), with each episode's measured step and policy times; a warning
names the options when the policy could not keep the rate.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.robots import RobotConfig

from lerobot_obsbench.commands import common
from lerobot_obsbench.policies.env_passthrough import frame_to_policy_batch
from lerobot_obsbench.policies.loading import check_policy_path, load_policy, predict_chunk
from lerobot_obsbench.robots.checks import RobotSetupError, require_calibrated
from lerobot_obsbench.robots.frames import action_dict, dataset_features, motor_keys, observation_frame
from lerobot_obsbench.robots.real_tasks import real_task
from lerobot_obsbench.robots.realtime import AsyncChunks, StepTimer
from lerobot_obsbench.schema import ACTION_KEY, DEPTH_PREFIX, IMAGE_PREFIX, STATE_KEY
from lerobot_obsbench.stats import success_summary

logger = logging.getLogger(__name__)

NAME = "rollout"
HELP = "run a checkpoint on a real robot, the operator judging each episode (success rate with its 95% interval)"
EXAMPLE = """obsbench rollout --robot.type=obsbench_koch_follower --robot.port=/dev/ttyACM0 --robot.id=follower \\
    --policy_path=outputs/train/koch_pick/checkpoints/last/pretrained_model --task=pick_cube"""
INTERRUPTED = "the episodes' videos are kept in --out; results.json is written once every episode is judged"
DEVICE_OPTIONS = ("robot",)
# LeRobot's device factories wrap what stops them (a missing SDK, a bad port) in ValueError
EXPECTED_ERRORS = (ValueError,)


@dataclass
class RolloutConfig:
    """What `obsbench rollout` runs (the robot comes from `--robot.*`)."""

    # The checkpoint's pretrained_model directory (from lerobot-train).
    policy_path: str
    # One of the paper's real tasks (sets episodes and episode time), or None to set them here.
    task: str | None = None
    # Episodes to run (a --task sets it).
    episodes: int = 20
    # The longest an episode runs, in seconds (a --task sets it).
    episode_time_s: float = 30.0
    # Control rate (Hz): one observation and one action per step.
    fps: int = 30
    # Seconds to move back to the rest pose after each episode.
    rest_time_s: float = 3.0
    # Torch device of the policy (cpu, cuda, mps).
    device: str = "cpu"
    # Compute the next action chunk in a background thread while the arm executes the current one (ACT
    # checkpoints; replaces temporal ensembling): a policy slower than 1 / fps then acts on a slightly older plan
    # instead of stalling the arm. Each episode's record reports the step times either way.
    async_inference: bool = False
    # Where the results JSON and the per-episode videos go.
    out: str = "outputs/rollouts"

    def __post_init__(self) -> None:
        if self.task is not None:
            task = real_task(self.task)
            self.episodes, self.episode_time_s = task.rollouts, task.episode_time_s


@dataclass
class Operator:
    """How episodes start and are judged: the keyboard by default, a script in tests."""

    start: Callable[[int], bool] = field(default=lambda i: input(f"ENTER starts episode {i + 1} (q quits): ") != "q")
    judge: Callable[[int], bool] = field(default=lambda i: input("success? [y/N]: ").strip().lower() == "y")
    events: dict = field(
        default_factory=lambda: {"exit_early": False, "rerecord_episode": False, "stop_recording": False}
    )


def policy_keys(policy_config) -> list[str]:
    """Every observation key the policy reads: its sensors (the plugin's policies keep them out of
    `input_features`, away from LeRobot's normaliser) and the rest."""
    sensors = policy_config.observation_keys() if hasattr(policy_config, "observation_keys") else []
    return [*sensors, *policy_config.input_features]


def check_policy_fits_robot(policy_config, robot) -> None:
    """Refuse a checkpoint whose cameras, resolution, state or action size differ from the robot's."""
    features = dataset_features(robot)
    resolution = list(getattr(policy_config, "camera_resolution", []) or [])
    problems = []
    for key in policy_keys(policy_config):
        if key not in features:
            problems.append(f"the policy reads {key}, the robot gives no such key (cameras: {sorted(robot.cameras)})")
        elif key == STATE_KEY:
            want, have = policy_config.input_features[key].shape[0], features[key]["shape"][0]
            if want != have:
                problems.append(f"the policy expects a {want}-value {key}, the robot has {have} joints")
        elif key.startswith((IMAGE_PREFIX, DEPTH_PREFIX)) and resolution:
            have = list(features[key]["shape"][:2])
            if have != resolution:
                problems.append(
                    f"{key}: the policy was trained on {resolution[0]}x{resolution[1]}, the robot gives "
                    f"{have[0]}x{have[1]}"
                )
    action = policy_config.output_features.get(ACTION_KEY)
    if action is not None and action.shape[0] != len(robot.action_features):
        problems.append(
            f"the policy outputs {action.shape[0]} actions, the robot has {len(robot.action_features)} motors"
        )
    if problems:
        raise RobotSetupError(
            "Checkpoint and robot do not match: " + "; ".join(problems) + ". Roll out on the set-up the dataset was "
            "recorded with (same cameras, --robot.cameras.*.width/height/downsample, same arms)."
        )


def return_to_rest(robot, rest: dict, seconds: float, fps: int) -> None:
    """Move the joints linearly from where they are to `rest` over `seconds` (max_relative_target still applies)."""
    from lerobot.utils.robot_utils import precise_sleep

    motors = motor_keys(robot)
    now = robot.get_observation()
    start = np.array([now[m] for m in motors])
    goal = np.array([rest[m] for m in motors])
    steps = max(int(seconds * fps), 1)
    for i in range(1, steps + 1):
        robot.send_action(action_dict(start + (goal - start) * i / steps, motors))
        precise_sleep(1.0 / fps)


def rollout(robot, config: RolloutConfig, operator: Operator | None = None) -> dict:
    """Run `config.episodes` episodes; returns (and writes to config.out) the results."""
    from lerobot.utils.io_utils import write_video

    operator = operator or Operator(events=common.keyboard_events())
    events = operator.events
    policy, pre, post = load_policy(config.policy_path, config.device)
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    robot.connect(calibrate=False)
    records = []
    try:
        require_calibrated(robot, "robot")
        check_policy_fits_robot(policy.config, robot)
        if config.async_inference and not isinstance(policy, ACTPolicy):
            raise RobotSetupError(
                f"--async_inference=true needs an ACT checkpoint (obs_act, act_*); {config.policy_path} is a "
                f"{policy.config.type} policy, whose action queue already spans {policy.config.n_action_steps} steps."
            )
        motors = motor_keys(robot)
        first = robot.get_observation()
        rest = {m: first[m] for m in motors}
        keys = policy_keys(policy.config)
        video_camera = next((k for k in keys if k.startswith(IMAGE_PREFIX)), None)
        for episode in range(config.episodes):
            if events["stop_recording"] or not operator.start(episode):
                break
            policy.reset()
            timer = StepTimer(config.fps)
            chunks = AsyncChunks(lambda batch: predict_chunk(policy, post, batch)) if config.async_inference else None
            start = time.perf_counter()
            try:
                frames, steps = _drive(
                    robot, policy, pre, post, config, events, motors, keys, video_camera, timer, chunks
                )
            finally:
                if chunks is not None:
                    chunks.close()
            aborted = events["stop_recording"]
            events["exit_early"] = False
            seconds = time.perf_counter() - start
            return_to_rest(robot, rest, config.rest_time_s, config.fps)
            video = None
            if frames:
                video = out / f"episode_{episode:03d}.mp4"
                write_video(str(video), np.stack(frames), fps=config.fps)
            success = False if aborted else bool(operator.judge(episode))
            records.append(
                {
                    "episode": episode,
                    "success": success,
                    "steps": steps,
                    "seconds": round(seconds, 2),
                    "aborted": aborted,
                    "video": str(video) if video else None,
                    **timer.summary(),
                    **({"starved_steps": chunks.starved_steps, "chunks": chunks.chunks_done} if chunks else {}),
                }
            )
            if message := timer.warning(config.async_inference):
                logger.warning(f"episode {episode + 1}: {message}")
            if aborted:
                break
    finally:
        robot.disconnect()
    result = summarize(records, config, policy.config, robot.config.type)
    (out / "results.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


def _drive(robot, policy, pre, post, config, events, motors, keys, video_camera, timer, chunks) -> tuple[list, int]:
    """One episode's control loop at `config.fps` until its time is up or the operator ends it: (the frames of the
    policy's first camera, the steps taken)."""
    from lerobot.utils.robot_utils import precise_sleep

    frames, steps = [], 0
    start = time.perf_counter()
    while time.perf_counter() - start < config.episode_time_s and not events["exit_early"]:
        t0 = time.perf_counter()
        frame = observation_frame(robot.get_observation(), motors)
        if video_camera is not None:
            frames.append(frame[video_camera])
        t_policy = time.perf_counter()
        batch = pre(frame_to_policy_batch({k: frame[k] for k in keys}))
        if chunks is not None:
            action = chunks.action(steps, batch)
        else:
            with torch.inference_mode():
                action = post(policy.select_action(batch))[0].cpu().numpy()
        policy_s = time.perf_counter() - t_policy
        robot.send_action(action_dict(action, motors))
        steps += 1
        timer.record(time.perf_counter() - t0, policy_s)
        precise_sleep(max(1.0 / config.fps - (time.perf_counter() - t0), 0.0))
    return frames, steps


def summarize(records: list[dict], config: RolloutConfig, policy_config, robot_type: str) -> dict:
    return {
        "task": config.task,
        "policy_path": str(config.policy_path),
        "obs_space": getattr(policy_config, "obs_space", None),
        "policy_type": policy_config.type,
        **success_summary([r["success"] for r in records]),
        "per_episode": records,
        "robot": robot_type,
        "fps": config.fps,
    }


@dataclass
class RobotDevice:
    """`--robot.*`: LeRobot's own robot config."""

    robot: RobotConfig


def add_arguments(p: argparse.ArgumentParser) -> None:
    common.add_config_options(p, RolloutConfig)


def run(args: argparse.Namespace) -> int:
    from lerobot.robots.utils import make_robot_from_config

    robot = common.device_configs(RobotDevice, args.device_options, NAME).robot
    config = common.config_from_args(RolloutConfig, args)
    check_policy_path(config.policy_path)  # before the robot's ports and cameras are touched
    result = rollout(make_robot_from_config(robot), config)
    print(f"{result['successes']}/{result['episodes']} successes, 95% CI {result['ci95']}; {config.out}/results.json")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
