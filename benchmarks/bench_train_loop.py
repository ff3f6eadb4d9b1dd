"""Steps/s of real `lerobot-train` runs, LeRobot's own reader vs the plugin's (only what the policy reads, decoded
once: `lerobot_obsbench.dataset_reads`), side by side in one run, for every method of a benchmark grid — with
lerobot-train's own `data_s` (loading the batch) and `updt_s` (the model update), and the model alone on
batches already in memory (`bench_train_step --grid`'s rate) as the ceiling.

    .venv/bin/python -m benchmarks.bench_train_loop [--grid quick] [--steps 300] [--threads 1] [--out FILE]

It trains on the grid's own demonstrations (`obsbench run GRID` records them; `--dataset` names another copy),
one run at a time with `--threads` CPU threads each (the main job's one per unit), and takes the medians of
lerobot-train's logged windows after the first (the warm-up).
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import torch

from benchmarks.common import ROOT, write
from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.units import demo_dir, thread_env, train_command
from lerobot_obsbench.dataset_reads import READER_ENV

READERS = ("stock", "memory")
LOG_LINE = re.compile(r"updt_s:([0-9.]+) data_s:([0-9.]+)")


def timed_run(command: list[str], reader: str, threads: int, log: Path) -> dict:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", READER_ENV: reader, **thread_env(threads)}
    start = time.perf_counter()
    with log.open("w") as sink:
        proc = subprocess.run(command, stdout=sink, stderr=subprocess.STDOUT, env=env, stdin=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise SystemExit(f"lerobot-train failed ({reader} reader); its log: {log}")
    windows = [(float(u), float(d)) for u, d in LOG_LINE.findall(log.read_text())][1:]
    if not windows:
        raise SystemExit(f"no updt_s/data_s lines in {log}: give more --steps")
    update = statistics.median(u for u, _ in windows)
    data = statistics.median(d for _, d in windows)
    return {
        "updt_s": round(update, 4),
        "data_s": round(data, 4),
        "data_share": round(data / (update + data), 3),
        "steps_per_s": round(1 / (update + data), 2),
        "process_wall_s": round(wall, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--grid", default="quick")
    parser.add_argument(
        "--steps", type=int, default=300, help="training steps per run (lerobot-train logs ~50 windows)"
    )
    parser.add_argument("--threads", type=int, default=1, help="CPU threads per run")
    parser.add_argument("--dataset", type=Path, help="the demonstrations (default: the grid's, under outputs/bench)")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    if args.steps < 100:
        parser.error("--steps must be >= 100 (lerobot-train logs every steps/50; the first window is dropped)")

    grid = load_grid(args.grid)
    methods = {run.method: run for run in reversed(grid.expand())}  # the first seed of each method
    rows = []
    for run in methods.values():
        dataset = args.dataset or demo_dir(ROOT / "outputs" / "bench" / grid.name, run, run.demos + grid.held_out_demos)
        if not (dataset / "meta" / "info.json").is_file():
            raise SystemExit(
                f"{dataset}: no demonstrations; record them with `obsbench run {args.grid}` or pass --dataset"
            )
        row = {"method": run.method, "obs_space": run.obs_space, "encoder": run.encoder, "batch": run.batch_size}
        with tempfile.TemporaryDirectory() as tmp:
            for reader in READERS:
                output_dir = Path(tmp) / reader
                command = train_command(run, dataset, output_dir, args.steps, "cpu", save_every=args.steps)
                row[reader] = timed_run(command, reader, args.threads, Path(tmp) / f"{reader}.log")
        row["speedup"] = round(row["memory"]["steps_per_s"] / row["stock"]["steps_per_s"], 2)
        rows.append(row)
        print(
            f"{run.method:32s} stock {row['stock']['steps_per_s']:6.2f} steps/s (data {row['stock']['data_share']:.0%})"
            f"  memory {row['memory']['steps_per_s']:6.2f} steps/s (data {row['memory']['data_share']:.0%})"
            f"  x{row['speedup']}"
        )

    from benchmarks.bench_train_step import grid_rows

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    ceiling = {
        r["obs_space"] + "/" + r["encoder"]: r["steps_per_s"] for r in grid_rows(args.grid, torch.device("cpu"), 20)
    }
    for row in rows:
        row["model_only_steps_per_s"] = ceiling.get(row["obs_space"] + "/" + row["encoder"])
    write(
        "train_loop",
        {
            "command": f"python -m benchmarks.bench_train_loop --grid {args.grid} --steps {args.steps} "
            f"--threads {args.threads}",
            "grid": args.grid,
            "steps": args.steps,
            "threads": args.threads,
            "readers": {"stock": "LeRobot 0.6.1's reader (with the plugin's column fix)", "memory": "dataset_reads"},
            "model_only": "bench_train_step --grid: the update alone on batches already in memory (synthetic frames)",
            "rows": rows,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
