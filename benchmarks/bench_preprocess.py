"""Point-cloud preprocessing per frame at 128×128: unproject -> crop -> voxel 5 mm -> FPS 2048 -> kNN 16.

The plugin's batched pipeline (ObservationAdapter + geometry FPS/kNN) against a straightforward per-sample
NumPy implementation of the same steps, on the same ray-cast cluttered frames, side by side in one run; and FPS
alone on the unvoxelized clouds, the device's path (fpsample on CPU, the Triton kernel on CUDA) against the
batched tensor loop.

    .venv/bin/python -m benchmarks.bench_preprocess [--batch 32] [--device cpu] [--out FILE]
"""

from __future__ import annotations

import argparse
import functools
from pathlib import Path

import fpsample
import numpy as np
import torch
from scipy.spatial import cKDTree

from benchmarks.common import load_synthetic, timed, write
from lerobot_obsbench import geometry
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter

CAM = "base_camera"
WORKSPACE = (-0.6, 0.6, -0.6, 0.6, 0.005, 0.8)


def cluttered_frames(synthetic, n: int, size: int, seed: int = 0) -> dict[str, np.ndarray]:
    """n frames of 12 random boxes (3-9 cm) on the table, in the dataset schema's layout."""
    rng = np.random.default_rng(seed)
    K = synthetic.intrinsics(size)
    cam2world = synthetic.look_at(eye=(0.45, 0.0, 0.55), target=(0.0, 0.0, 0.0))
    rgbs, depths = [], []
    for _ in range(n):
        boxes = []
        for _ in range(12):
            half = rng.uniform(0.015, 0.045)
            centre = np.array([rng.uniform(-0.25, 0.25), rng.uniform(-0.25, 0.25), half])
            boxes.append((centre, half, tuple(int(c) for c in rng.integers(0, 255, 3))))
        rgb, depth, _ = synthetic.render(K, cam2world, size, boxes)
        rgbs.append(rgb)
        depths.append(depth)
    return {"rgb": np.stack(rgbs), "depth": np.stack(depths), "K": K, "cam2world": cam2world}


def sensor_batch(frames: dict[str, np.ndarray], device) -> dict[str, torch.Tensor]:
    """`cluttered_frames` as the batch LeRobot's loader gives the policy (float CHW rgb, int depth, K, pose)."""
    n = len(frames["rgb"])
    return {
        f"observation.images.{CAM}": torch.tensor(frames["rgb"]).permute(0, 3, 1, 2).float().div(255).to(device),
        f"observation.depth.{CAM}": torch.tensor(frames["depth"].astype(np.int64)).to(device),
        f"observation.intrinsics.{CAM}": torch.tensor(frames["K"], dtype=torch.float32).expand(n, 3, 3).to(device),
        f"observation.cam2world.{CAM}": torch.tensor(frames["cam2world"], dtype=torch.float32)
        .expand(n, 4, 4)
        .to(device),
    }


def numpy_reference(rgb, depth, K, cam2world, voxel=0.005, n_seeds=2048, k=16, libraries=False):
    """One frame, plain NumPy: returns seed xyz (S, 3), neighbour indices (S, k) and the voxel count.

    `libraries=True` swaps the FPS loop and brute-force kNN for fpsample and scipy's KD-tree (a per-frame
    CPU anchor made of well-kept libraries)."""
    h, w = depth.shape[:2]
    z = depth[..., 0].astype(np.float64) / 1000.0
    v, u = np.mgrid[0:h, 0:w]
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1).reshape(-1, 3)
    world = cam @ cam2world[:3, :3].T + cam2world[:3, 3]
    colour = rgb.reshape(-1, 3) / 127.5 - 1
    box = np.asarray(WORKSPACE).reshape(3, 2)
    keep = (z.reshape(-1) > 0) & np.all((world >= box[:, 0]) & (world <= box[:, 1]), axis=1)
    world, colour = world[keep], colour[keep]
    _, first = np.unique(np.floor(world / voxel).astype(np.int64), axis=0, return_index=True)
    first.sort()
    pts = world[first]
    n = min(n_seeds, len(pts))
    if libraries:
        seeds = pts[fpsample.fps_sampling(pts, n, start_idx=0).astype(np.int64)] if n < len(pts) else pts
        return seeds, cKDTree(pts).query(seeds, k=k)[1], len(pts)
    chosen = [0]
    dist = np.full(len(pts), np.inf)
    for _ in range(n - 1):
        dist = np.minimum(dist, ((pts - pts[chosen[-1]]) ** 2).sum(1))
        chosen.append(int(dist.argmax()))
    seeds = pts[chosen]
    d = ((seeds[:, None] - pts[None]) ** 2).sum(-1)
    neighbours = np.argpartition(d, min(k, len(pts) - 1), axis=1)[:, :k]
    return seeds, neighbours, len(pts)


def plugin_pipeline(adapter: ObservationAdapter, batch: dict, n_seeds: int = 2048, k: int = 16):
    cloud = adapter(batch)
    # the plugin pipeline's FPS (QuickFPS's start on CPU; `point_pipeline: official` starts at the first point)
    idx, seed_mask = geometry.farthest_point_sample(cloud.xyz, cloud.mask, n_seeds, start="any")
    seeds = geometry.gather(cloud.xyz, idx)
    neighbours = geometry.knn(seeds, cloud.xyz, cloud.mask, k)
    return seeds, neighbours, cloud.mask.sum(1)


def fps_paths(batch: dict, n_seeds: int = 2048) -> dict:
    """FPS alone, 2,048 seeds from each frame's whole cloud, table included and not voxelized (~16k points): the
    device's own path against the batched tensor loop (the path of devices without one), side by side, and the
    coverage radius of each sample."""
    with_table = (*WORKSPACE[:4], -0.05, WORKSPACE[5])
    raw = ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=with_table, voxel_size=1e-4)).eval()
    with torch.no_grad():
        cloud = raw.to(batch[f"observation.depth.{CAM}"].device)(batch)
    quick = functools.partial(geometry._fps_fpsample, start="any")
    dedicated = {"cpu": ("fpsample", quick), "cuda": ("triton_kernel", geometry._fps_cuda)}
    name, fast = dedicated[cloud.xyz.device.type]
    out = {"points_per_frame_mean": round(float(cloud.mask.sum(1).float().mean()), 1)}
    seeds = {}
    for label, fps in (("tensor_loop", geometry._fps_torch), (name, fast)):

        def run(fps=fps, label=label):
            seeds[label] = fps(cloud.xyz, cloud.mask, n_seeds)
            if cloud.xyz.device.type == "cuda":
                torch.cuda.synchronize()

        out[f"{label}_ms"] = timed(run, repeats=3)["median_ms"]
    out["speedup"] = round(out["tensor_loop_ms"] / out[f"{name}_ms"], 1)
    # depth in whole millimetres makes many distances tie exactly, and paths break ties differently: compare the
    # samples' quality (the farthest any point lies from its nearest seed, mean over frames) rather than indices
    for label, idx in seeds.items():
        radius = [
            torch.cdist(cloud.xyz[b][cloud.mask[b]], cloud.xyz[b][idx[b]]).amin(dim=1).max() for b in range(len(idx))
        ]
        out[f"{label}_coverage_mm"] = round(float(torch.stack(radius).mean()) * 1000, 2)
    print(f"FPS {n_seeds} seeds, batch {len(cloud.xyz)}: {out}")
    return out


def measure(device: torch.device, batch_size: int, size: int, reference_frames: int) -> dict:
    """The plugin's pipeline on `batch_size` cluttered `size`² frames on `device`, the NumPy reference on the first
    `reference_frames` of them and NumPy + fpsample + scipy on all, and FPS alone (`fps_paths`)."""
    frames = cluttered_frames(load_synthetic(), batch_size, size)
    batch = sensor_batch(frames, device)
    config = AdapterConfig("pointcloud", [CAM], workspace=WORKSPACE, voxel_size=0.005)
    adapter = ObservationAdapter(config).eval().to(device)

    def run_plugin():
        with torch.no_grad():
            out = plugin_pipeline(adapter, batch)
        if device.type == "cuda":
            torch.cuda.synchronize()
        return out

    points_per_frame = run_plugin()[2].float()
    plugin = timed(run_plugin, repeats=5)
    ref_points = []

    def run_reference():
        for i in range(reference_frames):
            ref_points.append(
                numpy_reference(frames["rgb"][i], frames["depth"][i], frames["K"], frames["cam2world"])[2]
            )

    reference = timed(run_reference, repeats=2, warmup=0)
    fps = fps_paths(batch)

    def run_libraries():
        for i in range(batch_size):
            numpy_reference(frames["rgb"][i], frames["depth"][i], frames["K"], frames["cam2world"], libraries=True)

    libraries = timed(run_libraries, repeats=3)
    plugin_ms = plugin["median_ms"] / batch_size
    reference_ms = reference["median_ms"] / reference_frames
    libraries_ms = libraries["median_ms"] / batch_size
    assert ref_points[0] == int(points_per_frame[0]), "both pipelines must keep the same voxels"
    result = {
        "image_size": size,
        "batch": batch_size,
        "device": str(device),
        "voxel_size": 0.005,
        "fps_seeds": 2048,
        "knn": 16,
        "points_after_voxel_mean": round(float(points_per_frame.mean()), 1),
        "plugin_ms_per_frame": round(plugin_ms, 3),
        "numpy_reference_ms_per_frame": round(reference_ms, 3),
        "speedup": round(reference_ms / plugin_ms, 1),
        "target_speedup": 10,
        "plugin_batch": plugin,
        "reference_frames": reference,
        "numpy_fpsample_scipy_ms_per_frame": round(libraries_ms, 3),
        "speedup_vs_numpy_fpsample_scipy": round(libraries_ms / plugin_ms, 2),
        "fps_2048_per_batch": fps,
    }
    print(
        f"{size}² frames, ~{result['points_after_voxel_mean']:.0f} voxels each: plugin {plugin_ms:.2f} ms/frame "
        f"(batch {batch_size}, {device}) vs NumPy reference {reference_ms:.1f} ms/frame -> {result['speedup']}x; "
        f"NumPy + fpsample + scipy {libraries_ms:.2f} ms/frame"
    )
    return result


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--reference-frames", type=int, default=4)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    result = measure(torch.device(args.device), args.batch, args.size, args.reference_frames)
    write(f"preprocess_{args.device}", result, args.out)


if __name__ == "__main__":
    main()
