"""How should the plugin's own recordings store depth? The same frames written three ways, side by side:

- `plugin_array`: the plugin's schema, `observation.depth.<cam>` uint16 mm as a parquet array column (+ K, pose);
- `lerobot_video`: LeRobot 0.6's own depth feature `observation.images.<cam>_depth` (`is_depth_map`), HEVC
  12-bit log-quantised lossless video (LeRobot's default depth encoder);
- `lerobot_tiff`: the same feature as 16-bit images in the parquet files (`--dataset.video=false` for depth).

Colour is the same AV1 video in all three. Two versions of the scene: `clean` (the ray-cast depth, as a simulator
gives it) and `sensor` (RealSense-like noise, sigma = `--noise-mm` x z² with z in metres, and `--dropout` of the
pixels as holes: what compresses like real recordings). Measured per storage: bytes on disk of the depth alone
(the dataset minus an identical one without depth), read time of one training sample (ACT: 100-action chunk;
Diffusion: two observation steps) through `LeRobotDataset` with the plugin's loading fix, the registration step
that LeRobot's layout needs before a policy can use it (`spaces.CalibratedDepth`), the codec's error (decoded vs
the millimetres written) and the error against the scene's exact (float) depth, over the pixels with a return;
plus whether returns and holes survive.

    .venv/bin/python -m benchmarks.bench_depth_storage [--size 128] [--episodes 4] [--frames 50]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset

import lerobot_obsbench  # noqa: F401  (applies the loading fix)
from benchmarks.common import load_synthetic, timed, write
from lerobot_obsbench.spaces import CalibratedDepth

CAM = "base_camera"
STORAGES = ("plugin_array", "lerobot_video", "lerobot_tiff", "no_depth")


def features(storage: str, size: int, base: dict) -> dict:
    feats = {k: v for k, v in base.items() if not k.startswith("observation.depth.")}
    if storage == "plugin_array":
        feats[f"observation.depth.{CAM}"] = base[f"observation.depth.{CAM}"]
    elif storage in ("lerobot_video", "lerobot_tiff"):
        feats[f"observation.images.{CAM}_depth"] = {
            "dtype": "video" if storage == "lerobot_video" else "image",
            "shape": (size, size, 1),
            "names": ["height", "width", "channels"],
            "info": {"is_depth_map": True},
        }
    return feats


def scenes(synthetic, episodes: int, frames: int, size: int, noise_mm: float = 0.0, dropout: float = 0.0, seed=0):
    """Per frame: the stored fields (colour, uint16 mm depth, K, pose, state, action) and the exact depth (m)."""
    rng = np.random.default_rng(seed)
    K = synthetic.intrinsics(size)
    cam2world = synthetic.look_at(eye=(0.45, 0.0, 0.55), target=(0.0, 0.0, 0.0))
    world2cam = np.linalg.inv(cam2world)
    for _ in range(episodes):
        out = []
        for cube, ee, yaw, action in synthetic.episode(rng, frames):
            boxes = [
                (cube, synthetic.CUBE_HALF, synthetic.CUBE_RGB),
                (ee, synthetic.GRIPPER_HALF, synthetic.GRIPPER_RGB),
            ]
            rgb, depth, points = synthetic.render(K, cam2world, size, boxes)
            exact = np.nan_to_num((points @ world2cam[:3, :3].T + world2cam[:3, 3])[..., 2], nan=0.0)
            if noise_mm or dropout:
                noisy = exact * 1000 + rng.normal(0.0, 1.0, exact.shape) * noise_mm * exact**2
                noisy[rng.random(exact.shape) < dropout] = 0
                depth = np.where(exact > 0, np.clip(np.round(noisy), 0, 65535), 0).astype(np.uint16)[..., None]
            state = np.concatenate([rng.normal(0, 0.1, 7), [1.0], ee, synthetic.quat_z(yaw)]).astype(np.float32)
            stored = {
                f"observation.images.{CAM}": rgb,
                "depth": depth,
                f"observation.intrinsics.{CAM}": K.astype(np.float32),
                f"observation.cam2world.{CAM}": cam2world.astype(np.float32),
                "observation.state": state,
                "action": action.astype(np.float32),
            }
            out.append((stored, exact))
        yield out


def write_storage(root: Path, storage: str, episodes: list, base: dict, size: int) -> Path:
    ds = LeRobotDataset.create(
        "local/bench", fps=10, features=features(storage, size, base), root=root, use_videos=True
    )
    for frames in episodes:
        for stored, _ in frames:
            frame = {k: v for k, v in stored.items() if k != "depth"}
            if storage == "plugin_array":
                frame[f"observation.depth.{CAM}"] = stored["depth"]
            elif storage != "no_depth":
                frame[f"observation.images.{CAM}_depth"] = stored["depth"]
            ds.add_frame({**frame, "observation.environment_state": frame["observation.state"][8:11], "task": "t"})
        ds.save_episode()
    ds.finalize()
    return root


def disk_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())


def read_depth_mm(ds: LeRobotDataset, storage: str, index: int) -> np.ndarray:
    item = ds[index]
    if storage == "plugin_array":
        return item[f"observation.depth.{CAM}"][..., 0].numpy().astype(np.float64)
    return item[f"observation.images.{CAM}_depth"][0].numpy().astype(np.float64)


def measure(roots: dict, episodes: list, size: int, calib: dict) -> dict:
    exact = np.stack([e for frames in episodes for _, e in frames])
    written = np.stack([stored["depth"][..., 0] for frames in episodes for stored, _ in frames]).astype(np.float64)
    without_depth = disk_bytes(roots["no_depth"])
    results = {}
    for storage in STORAGES[:3]:
        root = roots[storage]
        depth_key = f"observation.depth.{CAM}" if storage == "plugin_array" else f"observation.images.{CAM}_depth"
        plain = LeRobotDataset("local/bench", root=root)
        decoded = np.stack([read_depth_mm(plain, storage, i) for i in range(len(plain))])
        if storage == "lerobot_video":  # the codec's hole value, masked as the plugin does
            decoded = np.where(decoded <= 10.5, 0.0, decoded)
        returns, holes = written > 0, written == 0
        both = returns & (decoded > 0)
        codec = np.abs(decoded - written)[both]
        total = np.abs(decoded - exact * 1000)[both]
        timings = {}
        for name, deltas in (
            ("act_chunk", {"action": [i / 10 for i in range(100)]}),
            ("diffusion_history", {"action": [i / 10 for i in range(-1, 15)], depth_key: [-0.1, 0.0]}),
        ):
            ds = LeRobotDataset("local/bench", root=root, delta_timestamps=deltas)
            indices = iter(range(7, 100_000, 13))
            timings[name] = timed(lambda ds=ds, i=indices: ds[next(i) % len(ds)], repeats=30)
        entry = {
            "depth_bytes_per_frame": round((disk_bytes(root) - without_depth) / len(plain)),
            "read_ms": {k: v["median_ms"] for k, v in timings.items()},
            "codec_error_mm": {"median": round(float(np.median(codec)), 3), "max": round(float(codec.max()), 3)},
            "error_vs_exact_mm": {
                "median": round(float(np.median(total)), 3),
                "p99": round(float(np.percentile(total, 99)), 3),
            },
            "returns_kept": round(float((decoded[returns] > 0).mean()), 5),
            "holes_kept": round(float((decoded[holes] == 0).mean()), 5) if holes.any() else None,
        }
        if storage != "plugin_array":
            register = CalibratedDepth(calib)
            sample = {depth_key: torch.as_tensor(decoded[:1, None], dtype=torch.float32)}
            entry["register_ms_per_frame"] = timed(lambda r=register, s=sample: r(s), repeats=30)["median_ms"]
        results[storage] = entry
    return results


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--noise-mm", type=float, default=1.0, help="sensor scene: noise sigma at 1 m, mm")
    parser.add_argument("--dropout", type=float, default=0.02, help="sensor scene: fraction of pixels without return")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    synthetic = load_synthetic()
    base = synthetic.features(args.size, CAM, use_video=True)
    K = synthetic.intrinsics(args.size).tolist()
    calib = {
        CAM: {
            "color_size": [args.size] * 2,
            "color_intrinsics": K,
            "depth_intrinsics": K,
            "depth_to_color": np.eye(4).tolist(),
            "cam2world": np.eye(4).tolist(),
            "depth_min_mm": 10.0,
        }
    }
    results: dict = {}
    for scene, noise, dropout in (("clean", 0.0, 0.0), ("sensor", args.noise_mm, args.dropout)):
        episodes = list(scenes(synthetic, args.episodes, args.frames, args.size, noise, dropout))
        with tempfile.TemporaryDirectory() as tmp:
            roots = {s: write_storage(Path(tmp) / s, s, episodes, base, args.size) for s in STORAGES}
            results[scene] = measure(roots, episodes, args.size, calib)
        for storage, entry in results[scene].items():
            print(scene, storage, entry)
    frames = args.episodes * args.frames
    write(
        "depth_storage",
        {
            "image_size": args.size,
            "frames": frames,
            "sensor_noise_mm_at_1m": args.noise_mm,
            "sensor_dropout": args.dropout,
            "results": results,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
