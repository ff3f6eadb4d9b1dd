"""Dataset loading: one training sample (128² rgb video + uint16 depth, ACT chunk of 100 actions) with stock
LeRobot 0.4.4 vs the plugin's loading fix, side by side on the same dataset.

    .venv/bin/python benchmarks/bench_loading.py [--size 128] [--out FILE]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from lerobot.datasets.lerobot_dataset import LeRobotDataset

import lerobot_obsbench  # noqa: F401  (applies the fix)
from benchmarks.common import load_synthetic, timed, write
from lerobot_obsbench import patches


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--chunk", type=int, default=100)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    synthetic = load_synthetic()
    with tempfile.TemporaryDirectory() as tmp:
        root = synthetic.write_dataset(Path(tmp) / "ds", episodes=2, frames=150, size=args.size, seed=0)
        act = {"action": [i / 10 for i in range(args.chunk)]}
        diffusion = {
            "action": [i / 10 for i in range(-1, 15)],
            **{
                k: [-0.1, 0.0]
                for k in ("observation.images.base_camera", "observation.depth.base_camera", "observation.state")
            },
        }
        results = {}
        for name, deltas in (("act_chunk", act), ("diffusion_history", diffusion)):
            fast = LeRobotDataset("local/bench", root=root, delta_timestamps=deltas)
            with patches.stock_loading():
                stock = LeRobotDataset("local/bench", root=root, delta_timestamps=deltas)
                indices = iter(range(7, 10_000, 13))
                stock_t = timed(lambda ds=stock, i=indices: ds[next(i) % len(ds)], repeats=3)
            indices = iter(range(7, 10_000, 13))
            fast_t = timed(lambda ds=fast, i=indices: ds[next(i) % len(ds)], repeats=30)
            results[name] = {
                "stock": stock_t,
                "plugin": fast_t,
                "speedup": round(stock_t["median_ms"] / fast_t["median_ms"], 1),
            }
            print(
                f"{name}: stock {stock_t['median_ms']:.1f} ms, plugin {fast_t['median_ms']:.2f} ms per sample "
                f"({results[name]['speedup']}x)"
            )
    write("loading", {"image_size": args.size, "chunk": args.chunk, "target_ms": 10, "results": results}, args.out)


if __name__ == "__main__":
    main()
