"""Evaluate a checkpoint in RLBench, following the paper's protocol as its code runs it (`obsbench eval-rlbench`).

Needs CoppeliaSim 4.1, PyRep and RLBench's PerAct fork (none is on PyPI) and an X display; `require_rlbench`
names whatever is missing. Protocol:
- test episodes 0..N-1 (25 in the paper) of the raw `test` split, in order: each is loaded from disk, its
  recorded variation set and the scene reset to the demo (`reset_to_demo`, which restores its random seed);
- the arm moves by end-effector pose planning (`EndEffectorPoseViaPlanning`, absolute, world frame) with a
  discrete gripper; at most `max_steps` (200) steps;
- at step 0 a planning failure (IKError, ConfigurationPathError, InvalidActionError) is retried with the next
  entries of the predicted chunk, up to 20; later it ends the episode as a failure;
- success is reward 1 at any step; the rate is successes / episodes;
- camera-view perturbation: the front camera's pose is left-multiplied by a rotation about world y or z
  (the y rotations also move it by `shift` metres in x and z).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.outputs import write_json_atomic
from lerobot_obsbench.policies.env_passthrough import frame_to_policy_batch
from lerobot_obsbench.policies.loading import load_policy, predict_chunk
from lerobot_obsbench.rlbench.format import camera_views, decode_action, encode_pose, low_dim
from lerobot_obsbench.rlbench.paper_tasks import RLBenchTask, RLBenchTaskError
from lerobot_obsbench.schema import (
    ENV_STATE_KEY,
    STATE_KEY,
    cam2world_key,
    depth_key,
    image_key,
    intrinsics_key,
)
from lerobot_obsbench.stats import per_seed, success_summary

STEP0_RETRIES = 20
MAX_STEPS = 200
PAPER_EPISODES = 25


class RLBenchUnavailable(ObsBenchError, RuntimeError):
    """The simulator stack (CoppeliaSim, PyRep, RLBench's fork, a display) is missing: the message says what."""


def require_rlbench() -> None:
    """Raise RLBenchUnavailable naming every missing piece of the simulator stack."""
    problems = []
    root = os.environ.get("COPPELIASIM_ROOT")
    if not root or not Path(root).is_dir():
        problems.append(
            "COPPELIASIM_ROOT is not set to a CoppeliaSim 4.1 folder (CoppeliaSim_Edu_V4_1_0_Ubuntu20_04; export "
            "COPPELIASIM_ROOT, and add it to LD_LIBRARY_PATH and QT_QPA_PLATFORM_PLUGIN_PATH)"
        )
    try:
        import pyrep.backend  # noqa: F401  (PyPI's unrelated `pyrep` has no backend)
    except ImportError:
        problems.append(
            "PyRep is not installed (git clone https://github.com/stepjam/PyRep; pip install .; PyPI's `pyrep` is an "
            "unrelated package)"
        )
    try:
        import rlbench  # noqa: F401
    except ImportError:
        problems.append(
            "RLBench is not installed (the PerAct fork the paper uses: git clone -b peract "
            "https://github.com/MohitShridhar/RLBench; pip install .; it is not on PyPI)"
        )
    if not os.environ.get("DISPLAY"):
        problems.append(
            "no X display: CoppeliaSim renders through one even headless (e.g. Xvfb :99 -screen 0 1024x768x24 "
            "+extension GLX +render -noreset & export DISPLAY=:99)"
        )
    if problems:
        raise RLBenchUnavailable("RLBench evaluation needs " + "; ".join(problems) + ".")


@dataclass(frozen=True)
class CameraView:
    """A camera-view perturbation: rotate the front camera about world `axis` (y or z) by `degrees`."""

    axis: str
    degrees: float
    shift: float = 0.0  # metres added to the camera's x and z (the paper moves it with the y rotations)

    def apply(self, matrix: np.ndarray) -> np.ndarray:
        from scipy.spatial.transform import Rotation

        if self.axis not in ("y", "z"):
            raise RLBenchTaskError(f"camera view axis must be y or z; got {self.axis!r}")
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_euler(self.axis, self.degrees, degrees=True).as_matrix()
        moved = turn @ matrix
        moved[[0, 2], 3] += self.shift
        return moved


class CheckpointPolicy:
    """A LeRobot policy (pre/post processors included) driven by RLBench observations: schema frame -> 11-d
    action -> RLBench's 9-d action. At step 0 it also returns the rest of the predicted chunk, for retries."""

    def __init__(self, policy, pre, post, task: RLBenchTask, cameras, quaternion: str, text_encoder=None):
        self.policy, self.pre, self.post, self.task = policy, pre, post, task
        self.cameras, self.quaternion, self.text_encoder = list(cameras), quaternion, text_encoder
        self.goal: np.ndarray | None = None
        self.steps = 0

    def reset(self, description: str) -> None:
        self.policy.reset()
        self.steps = 0
        self.goal = self.text_encoder.encode([description])[0] if self.text_encoder is not None else None

    def frame(self, obs) -> dict[str, np.ndarray]:
        frame = {}
        for camera in self.cameras:
            view = camera_views(getattr(obs, f"{camera}_rgb"), getattr(obs, f"{camera}_depth"), obs.misc, camera)
            frame[image_key(camera)] = view["rgb"]
            frame[depth_key(camera)] = view["depth"]
            frame[intrinsics_key(camera)] = view["K"].astype(np.float32)
            frame[cam2world_key(camera)] = view["cam2world"].astype(np.float32)
        pose, gripper, ignore = low_dim(obs)
        frame[STATE_KEY] = encode_pose(
            pose, gripper, ignore, self.task.location_low, self.task.location_high, self.quaternion
        )
        if self.goal is not None:
            frame[ENV_STATE_KEY] = self.goal
        return frame

    def act(self, obs) -> np.ndarray:
        """RLBench actions (n, 9): the one to take first, then (step 0 only) the alternatives for retries."""
        import torch

        batch = self.pre(frame_to_policy_batch(self.frame(obs)))
        with torch.inference_mode():
            actions = [self.post(self.policy.select_action(batch))[0].cpu().numpy()]
        if self.steps == 0 and hasattr(self.policy, "predict_action_chunk"):
            actions += list(predict_chunk(self.policy, self.post, batch)[1:])
        self.steps += 1
        return decode_action(np.stack(actions), self.task.location_low, self.task.location_high, self.quaternion)


def evaluate_rlbench(
    policy,
    task: RLBenchTask,
    data_root: Path,
    episodes: int = PAPER_EPISODES,
    max_steps: int = MAX_STEPS,
    step0_retries: int = STEP0_RETRIES,
    camera_view: CameraView | None = None,
    headless: bool = True,
    progress_file: Path | None = None,
) -> dict:
    """Run the protocol (module docstring) with `policy` (`reset(description)`, `act(obs) -> (n, 9)`);
    `progress_file`: {"done", "episodes", "successes"} rewritten after each episode (a grid's progress lines)."""
    require_rlbench()
    start = time.time()
    from pyrep.errors import ConfigurationPathError, IKError
    from rlbench.action_modes.action_mode import MoveArmThenGripper
    from rlbench.action_modes.arm_action_modes import EndEffectorPoseViaPlanning
    from rlbench.action_modes.gripper_action_modes import Discrete
    from rlbench.backend.exceptions import InvalidActionError
    from rlbench.backend.utils import task_file_to_task_class
    from rlbench.environment import Environment
    from rlbench.observation_config import ObservationConfig

    planning_errors = (IKError, ConfigurationPathError, InvalidActionError)
    env = Environment(
        action_mode=MoveArmThenGripper(EndEffectorPoseViaPlanning(), Discrete()),
        dataset_root=str(data_root),
        obs_config=ObservationConfig(),
        headless=headless,
    )
    env.launch()
    records = []
    try:
        task_env = env.get_task(task_file_to_task_class(task.name))
        if camera_view is not None:
            camera = task_env._scene._cam_front  # RLBench exposes the scene's cameras only privately
            camera.set_matrix(camera_view.apply(camera.get_matrix()))
        for episode in range(episodes):
            records.append(_run_episode(task_env, policy, episode, max_steps, step0_retries, planning_errors))
            if progress_file is not None:
                wins = sum(r["success"] for r in records)
                write_json_atomic(progress_file, {"done": len(records), "episodes": episodes, "successes": wins})
    finally:
        env.shutdown()
    return {
        "task": task.name,
        **success_summary([r["success"] for r in records]),
        "sub_success": {},  # RLBench scores success only
        "episode_length_mean": round(float(np.mean([r["steps"] for r in records])), 2) if records else None,
        "max_steps": max_steps,
        "camera_view": None if camera_view is None else camera_view.__dict__,
        "per_episode": records,
        # the episode numbers of the split stand for the seeds: each restores its recorded scene and random state
        "per_seed": per_seed(
            [r["episode"] for r in records], [r["success"] for r in records], [r["steps"] for r in records]
        ),
        "wall_s": round(time.time() - start, 1),
    }


def _run_episode(task_env, policy, episode: int, max_steps: int, step0_retries: int, planning_errors) -> dict:
    """The test split's `episode`: its recorded scene restored, the policy stepped until success, `max_steps`, the
    task's own end or a motion the planner cannot make (at the first step the policy's next candidates are tried,
    up to `step0_retries`)."""
    task_env.set_variation(-1)
    (demo,) = task_env.get_demos(1, live_demos=False, random_selection=False, from_episode_number=episode)
    task_env.set_variation(demo.variation_number)
    descriptions, obs = task_env.reset_to_demo(demo)
    policy.reset(descriptions[0])
    success, steps, failure = False, 0, None
    while steps < max_steps and not success:
        candidates = policy.act(obs)
        tries = candidates[:step0_retries] if steps == 0 else candidates[:1]
        for action in tries:
            try:
                obs, reward, terminate = task_env.step(action)
                failure = None
                break
            except planning_errors as error:
                failure = f"{type(error).__name__} at step {steps}: {error}"
        if failure is not None:
            break
        steps += 1
        success = reward == 1
        if terminate:
            break
    record = {"episode": episode, "variation": int(demo.variation_number), "success": success, "steps": steps}
    return record | ({"failure": failure} if failure else {})


# The paper's camera-view changes, spelled camera_pitch / camera_yaw as the ManiSkill half spells them
# (docs/simulation.md, "Zero-shot perturbations"): vertical = about world y with the camera moved 0.1 m per 5 degrees
# in x and z, horizontal = about world z; the paper's values are 5 and 10 degrees, applied as negative rotations.
CAMERA_VIEWS = {
    "camera_pitch:5": CameraView("y", -5.0, 0.1),
    "camera_pitch:10": CameraView("y", -10.0, 0.2),
    "camera_yaw:5": CameraView("z", -5.0),
    "camera_yaw:10": CameraView("z", -10.0),
}


def camera_view_for(perturbation: str) -> CameraView | None:
    """The camera-view change a grid's perturbation names on RLBench ("none": None)."""
    if perturbation == "none":
        return None
    if perturbation not in CAMERA_VIEWS:
        raise RLBenchTaskError(
            f"perturbation {perturbation!r} has no RLBench counterpart; RLBench grids take the paper's camera "
            f"views: {', '.join(CAMERA_VIEWS)}"
        )
    return CAMERA_VIEWS[perturbation]


def evaluate_checkpoint(
    policy_path: str | Path,
    task: RLBenchTask,
    data_root: Path,
    episodes: int = PAPER_EPISODES,
    max_steps: int = MAX_STEPS,
    camera_view: CameraView | None = None,
    clip_weights: str | None = None,
    quaternion: str = "pcm_compat",
    device: str = "cpu",
    progress_file: Path | None = None,
) -> dict:
    """The protocol run with a trained checkpoint (`obsbench eval-rlbench` and a grid's RLBench evaluations):
    its cameras, the language goal from `clip_weights` when given (as the importer computed it)."""
    from lerobot_obsbench.rlbench.text import load_clip_text_encoder

    require_rlbench()  # before anything loads
    policy, pre, post = load_policy(policy_path, device)
    text_encoder = load_clip_text_encoder(clip_weights) if clip_weights else None
    runner = CheckpointPolicy(policy, pre, post, task, policy.config.cameras, quaternion, text_encoder)
    result = evaluate_rlbench(
        runner, task, data_root, episodes, max_steps, camera_view=camera_view, progress_file=progress_file
    )
    return {**result, "policy_path": str(policy_path), "obs_space": getattr(policy.config, "obs_space", None)}
