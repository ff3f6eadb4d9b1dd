"""An RLBench `Environment` that replays recorded episodes instead of simulating.

`reset_to_demo` returns the episode's first observation; each `step` advances to the episode's next recorded
observation (the last one repeats), whatever the action; the reward is 1 once the commanded gripper position is
within `SUCCESS_RADIUS_M` of the episode's last recorded one. Observations carry what a live RLBench one does for
the front camera: colour, normalised depth, `misc` (intrinsics, extrinsics, near / far) and the gripper state.
"""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
from PIL import Image

from lerobot_obsbench.rlbench.format import decode_depth, find_episodes, read_episode

SUCCESS_RADIUS_M = 0.05
CAMERA = "front"


class Environment:
    def __init__(self, action_mode, dataset_root, obs_config, headless=True):
        self.dataset_root = Path(dataset_root)

    def launch(self):
        pass

    def get_task(self, task_class):
        return TaskEnvironment(find_episodes(self.dataset_root / task_class))

    def shutdown(self):
        pass


class TaskEnvironment:
    def __init__(self, episodes):
        self.episodes, self.frames, self.t = episodes, [], 0
        self._scene = types.SimpleNamespace(_cam_front=Camera())

    def set_variation(self, variation: int) -> None:
        pass

    def get_demos(self, amount, live_demos=False, random_selection=False, from_episode_number=0):
        assert amount == 1 and not live_demos and not random_selection
        episode = read_episode(self.episodes[from_episode_number])
        return [types.SimpleNamespace(variation_number=episode.variation, episode=episode)]

    def reset_to_demo(self, demo):
        episode = demo.episode
        self.frames = [_observation(episode.ref.path, o, t) for t, o in enumerate(episode.observations)]
        self.goal, self.t = np.asarray(episode.observations[-1].gripper_pose[:3]), 0
        return episode.descriptions, self.frames[0]

    def step(self, action):
        self.t = min(self.t + 1, len(self.frames) - 1)
        reached = np.linalg.norm(np.asarray(action[:3]) - self.goal) < SUCCESS_RADIUS_M
        return self.frames[self.t], float(reached), False


class Camera:
    def __init__(self):
        self.matrix = np.eye(4)

    def get_matrix(self):
        return self.matrix

    def set_matrix(self, matrix):
        self.matrix = matrix


def _observation(folder: Path, recorded, t: int):
    rgb = np.asarray(Image.open(folder / f"{CAMERA}_rgb" / f"{t}.png").convert("RGB"))
    depth = decode_depth(np.asarray(Image.open(folder / f"{CAMERA}_depth" / f"{t}.png").convert("RGB")))
    return types.SimpleNamespace(
        **{f"{CAMERA}_rgb": rgb, f"{CAMERA}_depth": depth},
        misc=recorded.misc,
        gripper_pose=np.asarray(recorded.gripper_pose),
        gripper_open=recorded.gripper_open,
        ignore_collisions=getattr(recorded, "ignore_collisions", 0.0),
    )
