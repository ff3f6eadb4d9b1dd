"""Synthetic RLBench demonstrations written the way RLBench's (PerAct fork's) dataset generator writes them:
pickled `rlbench.demo.Demo` / `rlbench.backend.observation.Observation` objects (stand-in classes registered
under those module names only while pickling), RGB-packed depth PNGs with per-frame near / far planes, and
RLBench's camera convention (negative focal lengths, x-left / y-up frame). The scene is the analytic ray-cast
one of scripts/make_synthetic_dataset.py, so the exact world point of every pixel is known."""

from __future__ import annotations

import pickle
import sys
import types
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from PIL import Image

NEAR, FAR = 0.01, 4.5
FLIP_XY = np.diag([-1.0, -1.0, 1.0, 1.0])


@contextmanager
def rlbench_classes():
    """Demo / Observation classes importable as rlbench.demo.Demo and rlbench.backend.observation.Observation."""
    names = ["rlbench", "rlbench.demo", "rlbench.backend", "rlbench.backend.observation"]
    saved = {n: sys.modules.get(n) for n in names}
    modules = {n: types.ModuleType(n) for n in names}
    demo_cls = type("Demo", (), {"__module__": "rlbench.demo"})
    obs_cls = type("Observation", (), {"__module__": "rlbench.backend.observation"})
    modules["rlbench.demo"].Demo = demo_cls
    modules["rlbench.backend.observation"].Observation = obs_cls
    sys.modules.update(modules)
    try:
        yield demo_cls, obs_cls
    finally:
        for n, m in saved.items():
            if m is None:
                sys.modules.pop(n, None)
            else:
                sys.modules[n] = m


def dump(obj, path: Path, numpy1: bool = False) -> None:
    """Pickle `obj`; `numpy1=True` writes a protocol-2 file naming numpy.core, as numpy-1 writers did."""
    data = pickle.dumps(obj, protocol=2 if numpy1 else 4)
    if numpy1:
        data = data.replace(b"numpy._core.multiarray", b"numpy.core.multiarray")
    path.write_bytes(data)


def encode_depth(normalised: np.ndarray) -> np.ndarray:
    """RLBench's packing, written independently of the plugin's codec."""
    n = np.floor(np.clip(normalised, 0, 1) * (2**24 - 1) + 0.5).astype(np.int64)
    return np.stack([n // 65536, (n // 256) % 256, n % 256], axis=-1).astype(np.uint8)


def scene(synthetic, size: int, seed: int):
    """Camera (OpenCV K, cam2world), colour, exact z-depth (metres; FAR where nothing is hit) and world points."""
    rng = np.random.default_rng(seed)
    K = synthetic.intrinsics(size)
    cam2world = synthetic.look_at(eye=(1.1, 0.0, 1.6), target=(0.2, 0.0, 0.75))
    # the table top at z = 0.75 m (RLBench's), two boxes on it
    boxes = [
        (np.array([rng.uniform(0.1, 0.3), rng.uniform(-0.15, 0.15), 0.78]), 0.03, synthetic.CUBE_RGB),
        (np.array([0.3, 0.2, 0.80]), 0.02, synthetic.GRIPPER_RGB),
        (np.array([0.2, 0.0, 0.375]), 0.375, (120, 90, 60)),  # the table, a 75 cm cube
    ]
    rgb, depth_mm, points = synthetic.render(K, cam2world, size, boxes)
    world_to_cam = np.linalg.inv(cam2world)
    z = (points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3])[..., 2]
    hit = depth_mm[..., 0] > 0
    return K, cam2world, rgb, np.where(hit, z, FAR), points, hit


def write_episode(folder: Path, synthetic, frames: int, seed: int, numpy1: bool = False, size: int = 32) -> dict:
    """One episode folder (low_dim_obs.pkl + front_rgb / front_depth PNGs); returns what was placed."""
    rng = np.random.default_rng(seed)
    K, cam2world, rgb, z, points, hit = scene(synthetic, size, seed)
    rlbench_K = K.copy()
    rlbench_K[0, 0], rlbench_K[1, 1] = -K[0, 0], -K[1, 1]
    extrinsics = cam2world @ FLIP_XY
    (folder / "front_rgb").mkdir(parents=True)
    (folder / "front_depth").mkdir()
    with rlbench_classes() as (demo_cls, obs_cls):
        observations = []
        for t in range(frames):
            Image.fromarray(rgb).save(folder / "front_rgb" / f"{t}.png")
            Image.fromarray(encode_depth((z - NEAR) / (FAR - NEAR))).save(folder / "front_depth" / f"{t}.png")
            obs = obs_cls()
            quat = rng.normal(size=4)
            obs.__dict__.update(
                gripper_pose=np.concatenate(
                    [rng.uniform([0.1, -0.3, 0.8], [0.4, 0.3, 1.2]), quat / np.linalg.norm(quat)]
                ),
                gripper_open=float(t < frames // 2),
                ignore_collisions=np.array(float(t % 2)),
                joint_positions=rng.normal(size=7),
                front_rgb=None,
                front_depth=None,
                misc={
                    "front_camera_extrinsics": extrinsics,
                    "front_camera_intrinsics": rlbench_K,
                    "front_camera_near": NEAR,
                    "front_camera_far": FAR,
                },
            )
            observations.append(obs)
        demo = demo_cls()
        demo.__dict__.update(_observations=observations, random_seed=np.random.get_state(), variation_number=None)
        dump(demo, folder / "low_dim_obs.pkl", numpy1=numpy1)
    return {"points": points, "hit": hit, "poses": np.stack([o.gripper_pose for o in observations])}


def write_task(root: Path, synthetic, layout: str, episodes: int = 3, frames: int = 4) -> dict[str, dict]:
    """A task folder in `layout` ("all_variations" or "variations"); returns what each episode folder holds."""
    placed = {}
    for i in range(episodes):
        variation = i % 2
        descriptions = [f"open the {'top' if variation == 0 else 'bottom'} drawer", "grip the drawer handle"]
        if layout == "all_variations":
            folder = root / "all_variations" / "episodes" / f"episode{i}"
            placed[str(folder)] = write_episode(folder, synthetic, frames, seed=i, numpy1=i == 1)
            dump(variation, folder / "variation_number.pkl")
            dump(descriptions, folder / "variation_descriptions.pkl")
        else:
            folder = root / f"variation{variation}" / "episodes" / f"episode{i}"
            placed[str(folder)] = write_episode(folder, synthetic, frames, seed=i, numpy1=i == 1)
            dump(descriptions, root / f"variation{variation}" / "variation_descriptions.pkl")
        placed[str(folder)].update(variation=variation, description=descriptions[0])
    return placed
