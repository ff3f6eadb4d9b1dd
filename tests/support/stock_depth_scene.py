"""A scene whose geometry the stock-depth tests know exactly: a table plane (z = 0) and a red sphere on it, seen by
an RGB-D camera whose depth sensor is rotated and offset from its colour sensor (as a real RealSense's is).
Images are ray cast independently of the plugin's geometry code, and a dataset is written by LeRobot 0.6.1's own
writer, as stock `lerobot-record` writes a RealSense with `use_depth: true`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from scripts import make_synthetic_dataset as synthetic

SPHERE_CENTRE = np.array([0.0, 0.02, 0.06])
SPHERE_RADIUS = 0.06
SPHERE_RGB = (230, 20, 20)
TABLE_RGB = (40, 60, 200)
COLOR_SIZE, DEPTH_SIZE = (96, 128), (90, 120)
K_COLOR = np.array([[112.0, 0, 63.2], [0, 111.0, 47.9], [0, 0, 1]])
K_DEPTH = np.array([[101.0, 0, 60.4], [0, 100.5, 44.1], [0, 0, 1]])


CAM2WORLD = synthetic.look_at([0.42, -0.05, 0.40], [0.0, 0.02, 0.03])
DEPTH_TO_COLOR = np.eye(4)  # a RealSense-like extrinsic with a rotation and an offset, not a pure x-baseline
DEPTH_TO_COLOR[:3, :3] = Rotation.from_euler("xyz", [0.5, -1.0, 0.3], degrees=True).as_matrix()
DEPTH_TO_COLOR[:3, 3] = [0.015, 0.001, 0.002]


def ray_cast(K: np.ndarray, cam2world: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(z metres along this camera's axis (H, W), 0 where nothing is hit; hit object (H, W): 0 none, 1 table,
    2 sphere) of the scene seen through pixel centres."""
    h, w = size
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)  # z = 1
    origin, dirs = cam2world[:3, 3], rays @ cam2world[:3, :3].T
    t_table = np.where(dirs[..., 2] < 0, -origin[2] / np.where(dirs[..., 2] < 0, dirs[..., 2], -1), np.inf)
    oc = origin - SPHERE_CENTRE
    a, b, c = (dirs**2).sum(-1), 2 * (dirs @ oc), oc @ oc - SPHERE_RADIUS**2
    disc = b**2 - 4 * a * c
    t_sphere = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.inf)
    t_sphere = np.where(t_sphere > 0, t_sphere, np.inf)
    t = np.minimum(t_table, t_sphere)
    hit = np.where(np.isinf(t), 0, np.where(t_sphere <= t_table, 2, 1))
    return np.where(np.isinf(t), 0.0, t), hit  # rays have z = 1 in the camera frame, so t is the depth


def render() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(colour (H, W, 3) uint8, depth-camera z16 depth in mm (Hd, Wd, 1) uint16, true colour-frame depth (H, W) m)."""
    color_z, hit = ray_cast(K_COLOR, CAM2WORLD, COLOR_SIZE)
    colour = np.zeros((*COLOR_SIZE, 3), np.uint8)
    colour[hit == 1], colour[hit == 2] = TABLE_RGB, SPHERE_RGB
    depth_z, _ = ray_cast(K_DEPTH, CAM2WORLD @ DEPTH_TO_COLOR, DEPTH_SIZE)
    depth_mm = np.round(depth_z * 1000).astype(np.uint16)[..., None]
    return colour, depth_mm, color_z


def scene_distance(points: np.ndarray) -> np.ndarray:
    """Distance (m) of world points (N, 3) to the nearest scene surface."""
    table = np.abs(points[:, 2])
    sphere = np.abs(np.linalg.norm(points - SPHERE_CENTRE, axis=1) - SPHERE_RADIUS)
    return np.minimum(table, sphere)


def sphere_points(points: np.ndarray, within: float = 0.003) -> np.ndarray:
    """Which points lie on the sphere and clearly off the table."""
    on_sphere = np.abs(np.linalg.norm(points - SPHERE_CENTRE, axis=1) - SPHERE_RADIUS) < within
    return on_sphere & (points[:, 2] > 0.01)


def write_stock_dataset(root: Path, video: bool, episodes: int = 2, frames: int = 12) -> Path:
    """A Koch-style dataset with one RealSense (`front`, use_depth) as LeRobot 0.6.1's writer stores it."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.feature_utils import hw_to_dataset_features

    motors = {f"{m}.pos": float for m in ("shoulder_pan", "shoulder_lift", "elbow_flex", "gripper")}
    hardware = {**motors, "front": (*COLOR_SIZE, 3), "front_depth": (*DEPTH_SIZE, 1)}
    features = {
        **hw_to_dataset_features(hardware, "observation", video),
        **hw_to_dataset_features(motors, "action", video),
    }
    dataset = LeRobotDataset.create(
        "local/stock_depth", fps=30, features=features, root=root, robot_type="koch_follower", use_videos=video
    )
    colour, depth_mm, _ = render()
    rng = np.random.default_rng(0)
    for _ in range(episodes):
        for _ in range(frames):
            dataset.add_frame(
                {
                    "observation.state": rng.normal(size=len(motors)).astype(np.float32),
                    "action": rng.normal(size=len(motors)).astype(np.float32),
                    "observation.images.front": colour,
                    "observation.images.front_depth": depth_mm,
                    "task": "pick the red ball",
                }
            )
        dataset.save_episode()
    dataset.finalize()
    return root


def write_calibration_json(path: Path, with_pose: bool = True) -> Path:
    values = {
        "color_intrinsics": K_COLOR.tolist(),
        "depth_intrinsics": K_DEPTH.tolist(),
        "depth_to_color": DEPTH_TO_COLOR.tolist(),
    }
    if with_pose:
        values["cam2world"] = CAM2WORLD.tolist()
    path.write_text(json.dumps(values))
    return path
