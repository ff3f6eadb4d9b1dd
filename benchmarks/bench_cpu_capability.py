"""What pinning the CPU kernels costs: the training step of each seeing space of a grid, as the grid runs it, under
each kernel pin `obsbench run --cpu-capability` offers (lerobot_obsbench/bench/machine.py) — `native` (unpinned:
this machine's best), `avx2` (the grids' default) and `default` (no vector kernels) — side by side. A pin holds for
a whole process, so each pin's policy lives in a worker process of its own started under it; the driver asks the
workers for one step in turn, so that whatever else the machine does falls on all alike. Every worker builds the
policy from one seed and reports its first loss on the same batch: equal losses mean the pins compute the same
numbers on this machine, different ones that runs under them part.

    .venv/bin/python -m benchmarks.bench_cpu_capability [--grid quick] [--obs-spaces rgb pointcloud] [--repeats 30]
        [--capabilities native avx2 default] [--out FILE]

Writes benchmarks/results/cpu_capability_<grid>.json: per run, each pin's median step, native's median over each
pin's, the median of the per-round ratios, and each pin's first loss and the capability torch reported.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from benchmarks.common import ROOT, write
from lerobot_obsbench.bench.machine import CAPABILITY_CHOICES, PIN_VARIABLES, pin_environment
from lerobot_obsbench.numeric import number_argument


def worker(grid: str, method: str, threads: int) -> None:
    """Build `method`'s run of `grid` and its batch, report the first loss and the capability, then take one timed
    optimizer step per line read from stdin, answering each with its milliseconds."""
    import torch

    from benchmarks.bench_step_variants import first_loss, milliseconds
    from benchmarks.bench_train_step import grid_run_policy, prepare, train_step
    from benchmarks.common import load_synthetic
    from lerobot_obsbench.bench.grid import load_grid

    device = torch.device("cpu")
    prepare(device)
    torch.set_num_threads(threads)
    (run,) = [r for r in reversed(load_grid(grid).expand()) if r.method == method][:1]
    policy, batch = grid_run_policy(run, device, load_synthetic())
    loss = first_loss(policy, batch)
    step = train_step(policy, batch)
    step()  # warm-up
    print(json.dumps({"capability": torch.backends.cpu.get_cpu_capability(), "first_loss": loss}), flush=True)
    for _ in sys.stdin:
        print(round(milliseconds(step), 3), flush=True)


def start(grid: str, method: str, threads: int, capability: str) -> tuple[subprocess.Popen, dict]:
    env = {k: v for k, v in os.environ.items() if k not in PIN_VARIABLES}
    env.update(pin_environment(capability), OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
    command = [sys.executable, "-m", "benchmarks.bench_cpu_capability", "--worker", grid, method, str(threads)]
    proc = subprocess.Popen(command, cwd=ROOT, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    return proc, json.loads(proc.stdout.readline())


def compare(grid: str, method: str, capabilities: list[str], repeats: int, threads: int) -> dict:
    workers = {c: start(grid, method, threads, c) for c in capabilities}
    times = {c: [] for c in capabilities}
    for _ in range(repeats):
        for capability, (proc, _) in workers.items():
            proc.stdin.write("step\n")
            proc.stdin.flush()
            times[capability].append(float(proc.stdout.readline()))
    for proc, _ in workers.values():
        proc.stdin.close()
        proc.wait()
    medians = {c: statistics.median(t) for c, t in times.items()}
    base = capabilities[0]
    row = {
        "method": method,
        "threads": threads,
        "repeats": repeats,
        "torch_capability": {c: info["capability"] for c, (_, info) in workers.items()},
        "first_loss": {c: info["first_loss"] for c, (_, info) in workers.items()},
        "median_ms": {c: round(m, 2) for c, m in medians.items()},
        f"{base}_over": {c: round(medians[base] / medians[c], 3) for c in capabilities[1:]},
        "median_round_ratio": {
            c: round(statistics.median(b / x for b, x in zip(times[base], times[c], strict=True)), 3)
            for c in capabilities[1:]
        },
    }
    shown = ", ".join(f"{c} {medians[c]:.1f} ms" for c in capabilities)
    print(f"{method:34s} {shown}; first losses {row['first_loss']}", flush=True)
    return row


def main() -> None:
    if sys.argv[1:2] == ["--worker"]:
        grid, method, threads = sys.argv[2:5]
        worker(grid, method, int(threads))
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", default="quick", help="grid preset name or file (its seeing spaces' runs)")
    parser.add_argument("--obs-spaces", nargs="+", default=["rgb", "pointcloud"], help="which of its seeing spaces")
    whole = number_argument(whole=True, minimum=1)
    parser.add_argument("--repeats", type=whole, default=30, help="interleaved steps of each pin (>= 1)")
    parser.add_argument("--threads", type=whole, default=1, help="CPU threads per worker, a grid's --threads (>= 1)")
    parser.add_argument(
        "--capabilities",
        nargs="+",
        default=["native", "avx2", "default"],
        choices=CAPABILITY_CHOICES,
        help="the pins compared, the first the one the others are measured against",
    )
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    from lerobot_obsbench.bench.grid import load_grid

    methods = {run.method: run for run in load_grid(args.grid).expand() if run.obs_space in args.obs_spaces}
    if not methods:
        parser.error(f"--obs-spaces: none of {args.obs_spaces} in grid {args.grid}")
    rows = [compare(args.grid, m, args.capabilities, args.repeats, args.threads) for m in methods]
    write(f"cpu_capability_{Path(args.grid).name.removesuffix('.yaml')}", {"rows": rows}, args.out)


if __name__ == "__main__":
    main()
