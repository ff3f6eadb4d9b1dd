#!/usr/bin/env python
"""Write a small LeRobotDataset in the OBSBench schema from an analytic scene, using stock LeRobot only.

The scene is ray-cast exactly: a table plane at z = 0, a red cube (5 cm) lying on it at a random place, and a
blue "gripper" box (3 cm) floating above it. Each episode moves the gripper towards the cube with a
proportional controller; the action is the (scaled) position error, so it depends on where the cube is.

This file deliberately imports nothing from `lerobot_obsbench`: it plays the part of "someone else's code
writing the schema" (lerobot_obsbench/schema.py), and its ray-caster is the independent reference the geometry
tests compare the plugin's unprojection against.

    python scripts/make_synthetic_dataset.py --out data/synthetic --episodes 20 --frames 20 --size 64
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

CUBE_HALF = 0.025
GRIPPER_HALF = 0.015
TABLE_RGB = (150, 150, 150)
CUBE_RGB = (220, 30, 30)
GRIPPER_RGB = (30, 60, 220)
MAX_RANGE_M = 2.0
STATE_DIM = 15  # 7 joints + gripper + ee xyz + ee quaternion (w, x, y, z)
ACTION_DIM = 7  # delta xyz, delta axis-angle, gripper


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """4x4 OpenCV camera (x right, y down, z forward) -> world transform."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


def intrinsics(size: int, fov_deg: float = 60.0) -> np.ndarray:
    f = 0.5 * size / np.tan(np.deg2rad(fov_deg) / 2)
    return np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]], dtype=np.float64)


def ray_box(origin, dirs, lo, hi):
    """Slab test: distance along each ray (N,3) to an axis-aligned box, inf where it misses."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - origin) / dirs
        t2 = (hi - origin) / dirs
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (tmax >= np.maximum(tmin, 0.0)) & (tmin > 0)
    return np.where(hit, tmin, np.inf)


def render(K, cam2world, size, boxes):
    """Ray-cast the table plane and boxes [(center, half, rgb)].

    `size`: H = W, or (H, W). Returns rgb (H,W,3) uint8, depth (H,W,1) uint16 mm (0 = no return), and the exact
    world hit points (H,W,3) (NaN where there is no return). Pixel (u, v) = (column, row); K maps camera points to
    pixel centres.
    """
    height, width = (size, size) if isinstance(size, int) else size
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    dirs = d_cam @ cam2world[:3, :3].T  # unnormalised: t is then the depth along the optical axis
    origin = cam2world[:3, 3]
    with np.errstate(divide="ignore"):
        t_plane = np.where(dirs[:, 2] < 0, -origin[2] / dirs[:, 2], np.inf)
    ts = [t_plane] + [ray_box(origin, dirs, c - h, c + h) for c, h, _ in boxes]
    colours = [TABLE_RGB] + [rgb for _, _, rgb in boxes]
    ts = np.stack(ts, 0)
    nearest = ts.argmin(0)
    t = ts.min(0)
    valid = np.isfinite(t) & (t < MAX_RANGE_M)
    rgb = np.asarray(colours, dtype=np.uint8)[nearest]
    rgb[~valid] = 0
    depth = np.where(valid, np.round(t * 1000.0), 0).astype(np.uint16)
    points = origin + dirs * np.where(valid, t, np.nan)[:, None]
    return rgb.reshape(height, width, 3), depth.reshape(height, width, 1), points.reshape(height, width, 3)


def quat_z(angle: float) -> np.ndarray:
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def features(
    size: int,
    camera: str,
    use_video: bool,
    with_goal: bool = True,
    depth_size: int | None = None,
    privileged: bool = False,
) -> dict:
    feats = {
        f"observation.images.{camera}": {
            "dtype": "video" if use_video else "image",
            "shape": (size, size, 3),
            "names": ["height", "width", "channels"],
        },
        f"observation.depth.{camera}": {
            "dtype": "uint16",
            "shape": (depth_size or size, depth_size or size, 1),
            "names": ["height", "width", "channels"],
        },
        f"observation.intrinsics.{camera}": {"dtype": "float32", "shape": (3, 3), "names": None},
        f"observation.cam2world.{camera}": {"dtype": "float32", "shape": (4, 4), "names": None},
        "observation.state": {"dtype": "float32", "shape": (STATE_DIM,), "names": None},
        "observation.environment_state": {"dtype": "float32", "shape": (3,), "names": None},
        "action": {"dtype": "float32", "shape": (ACTION_DIM,), "names": None},
    }
    if not with_goal:
        del feats["observation.environment_state"]
    if privileged:
        feats["observation.privileged_state"] = {
            "dtype": "float32",
            "shape": (7,),
            "names": [f"cube.{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")],
        }
    return feats


def episode(rng, frames: int):
    """A cube position and a gripper trajectory moving towards it; yields (cube, ee_pos, ee_yaw, action)."""
    cube = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), CUBE_HALF])
    ee = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.15, 0.25)])
    yaw = rng.uniform(-np.pi, np.pi)
    for _ in range(frames):
        target = cube + np.array([0, 0, CUBE_HALF + GRIPPER_HALF])
        error = target - ee
        action = np.zeros(ACTION_DIM)
        action[:3] = np.clip(error / 0.1, -1, 1)
        action[6] = 1.0 if np.linalg.norm(error) > 0.02 else -1.0
        yield cube, ee.copy(), yaw, action
        ee = ee + 0.3 * error + rng.normal(0, 0.002, 3)


def write_dataset(
    out: Path,
    episodes: int,
    frames: int,
    size: int,
    seed: int,
    camera: str = "base_camera",
    use_video: bool = True,
    with_goal: bool = True,
    repo_id: str = "local/obsbench_synthetic",
    frame_hook=None,
    depth_size: int | None = None,
    privileged: bool = False,
) -> Path:
    """Write the dataset; `with_goal=False` leaves out the cube position (environment_state), so that a policy
    can only find the cube in its observations. `frame_hook(episode, index, frame)` may change a frame before it
    is written (tests use it to plant bad sensor values); `depth_size` stores depth at another resolution than
    colour (a recording error: depth not aligned to colour); `privileged` also records the cube's pose as a
    simulator would (observation.privileged_state, xyz + quaternion wxyz: the oracle control's input)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    rng = np.random.default_rng(seed)
    K = intrinsics(size)
    cam2world = look_at(eye=(0.45, 0.0, 0.55), target=(0.0, 0.0, 0.0))
    ds = LeRobotDataset.create(
        repo_id=repo_id,
        fps=10,
        features=features(size, camera, use_video, with_goal, depth_size, privileged),
        root=out,
        robot_type="synthetic",
        use_videos=use_video,
    )
    for episode_index in range(episodes):
        for index, (cube, ee, yaw, action) in enumerate(episode(rng, frames)):
            boxes = [(cube, CUBE_HALF, CUBE_RGB), (ee, GRIPPER_HALF, GRIPPER_RGB)]
            rgb, depth, _ = render(K, cam2world, size, boxes)
            if depth_size:
                depth = depth[:: size // depth_size, :: size // depth_size][:depth_size, :depth_size]
            state = np.concatenate([rng.normal(0, 0.1, 7), [1.0], ee, quat_z(yaw)]).astype(np.float32)
            frame = {
                f"observation.images.{camera}": rgb,
                f"observation.depth.{camera}": depth,
                f"observation.intrinsics.{camera}": K.astype(np.float32),
                f"observation.cam2world.{camera}": cam2world.astype(np.float32),
                "observation.state": state,
                "action": action.astype(np.float32),
                "task": "move the gripper above the red cube",
            }
            if with_goal:
                frame["observation.environment_state"] = cube.astype(np.float32)
            if privileged:
                frame["observation.privileged_state"] = np.concatenate([cube, [1.0, 0, 0, 0]]).astype(np.float32)
            if frame_hook is not None:
                frame = frame_hook(episode_index, index, frame)
            ds.add_frame(frame)
        ds.save_episode()
    ds.finalize()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--images", action="store_true", help="store RGB as PNG images instead of video")
    parser.add_argument("--no-goal", action="store_true", help="leave out observation.environment_state")
    args = parser.parse_args()
    write_dataset(
        args.out,
        args.episodes,
        args.frames,
        args.size,
        args.seed,
        use_video=not args.images,
        with_goal=not args.no_goal,
    )
    print(f"wrote {args.episodes} episodes x {args.frames} frames to {args.out}")


if __name__ == "__main__":
    main()
