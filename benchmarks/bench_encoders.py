"""Forward + backward time and peak memory of every registered encoder on its observation space, side by
side in one run: batch 8, one 128² camera (ray-cast cluttered frames through the ObservationAdapter for the
point cloud), ACT token output at the paper's width (512) and 2048 point tokens.

    .venv/bin/python -m benchmarks.bench_encoders [--batch 8] [--device cpu] [--repeats 3] [--out FILE]

Peak memory: CUDA's max_memory_allocated on a GPU; on CPU the growth of the process's peak resident set
(ru_maxrss) over the forward + backward passes, each encoder in its own process.
"""

from __future__ import annotations

import argparse
import resource
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import torch

from benchmarks.bench_preprocess import CAM, WORKSPACE, cluttered_frames, sensor_batch
from benchmarks.common import load_synthetic, timed, write
from lerobot_obsbench.encoders import encoder_info, make_encoder
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter

PAIRS = [
    ("resnet18", "rgb"),
    ("resnet50", "rgb"),
    ("vit_b", "rgb"),
    ("multivit_b", "rgbd"),
    ("pointnet", "pointcloud"),
    ("spunet34", "pointcloud"),
]


def peak_mb(device: str) -> float:
    if device.startswith("cuda"):
        return torch.cuda.max_memory_allocated() / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def measure(name: str, space: str, batch: int, size: int, device: str, repeats: int, num_tokens: int) -> dict:
    """Runs in its own process, so each encoder's memory peak is its own."""
    frames = sensor_batch(cluttered_frames(load_synthetic(), batch, size), device)
    adapter = ObservationAdapter(AdapterConfig(space, [CAM], workspace=WORKSPACE)).to(device).train()
    options = {"num_tokens": num_tokens, "knn": 16, "image_size": size}
    options = {k: v for k, v in options.items() if k in encoder_info(name).options}
    encoder = make_encoder(name, space, output="tokens", dim=512, **options).to(device).train()
    params = sum(p.numel() for p in encoder.parameters())

    def step():
        tokens, pos = encoder(adapter(frames))
        (tokens.float().square().mean() + 0 * pos.sum()).backward()
        if device.startswith("cuda"):
            torch.cuda.synchronize()

    if device.startswith("cuda"):
        torch.cuda.reset_peak_memory_stats()
    before = 0.0 if device.startswith("cuda") else peak_mb(device)
    timing = timed(step, repeats=repeats, warmup=1)
    return {
        **timing,
        "params_M": round(params / 1e6, 3),
        "peak_memory_MB": round(peak_mb(device) - before, 1),
        "samples_per_s": round(batch * 1000 / timing["median_ms"], 2),
    }


def main(argv=None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--num-tokens", type=int, default=2048)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)

    results = {}
    for name, space in PAIRS:
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            entry = pool.submit(
                measure, name, space, args.batch, args.size, args.device, args.repeats, args.num_tokens
            ).result()
        results[f"{name}/{space}"] = entry
        print(
            f"{name:10s} {space:10s} {entry['params_M']:7.2f}M  fwd+bwd {entry['median_ms']:9.1f} ms / batch "
            f"{args.batch}  peak +{entry['peak_memory_MB']:8.1f} MB",
            flush=True,
        )
    base = results["resnet18/rgb"]["median_ms"]
    for entry in results.values():
        entry["vs_resnet18"] = round(entry["median_ms"] / base, 2)
    return write(
        f"encoders_{args.device.split(':')[0]}",
        {"batch": args.batch, "size": args.size, "num_tokens": args.num_tokens, "results": results},
        args.out,
    )


if __name__ == "__main__":
    main()
