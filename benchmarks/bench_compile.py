"""The training step eager against `compile_encoder` (the observation encoder compiled by torch.compile), for each
seeing space of a grid, timed interleaved: one eager step, one compiled step, and so on, so that whatever else the
machine does falls on both alike. The two policies are built from one seed (the same weights); the first loss of
each on the same batch is recorded, to show the compiled encoder trains the same model.

    .venv/bin/python -m benchmarks.bench_compile [--grid cpu-ranking] [--repeats 30] [--threads 1] [--out FILE]

Writes benchmarks/results/compile_<device>_grid_<grid>.json: per run, both medians, their ratio (eager / compiled)
and the median of the per-pair ratios.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from benchmarks.bench_train_step import grid_run_policy, prepare, release, train_step
from benchmarks.common import load_synthetic, write
from lerobot_obsbench.numeric import number_argument
from lerobot_obsbench.schema import is_control


def milliseconds(step) -> float:
    start = time.perf_counter()
    step()
    return (time.perf_counter() - start) * 1000


def first_loss(policy, batch: dict) -> float:
    torch.manual_seed(1)
    policy.train()
    return policy.forward(batch)[0].item()


def compare(run, device: torch.device, synthetic, repeats: int, warmup: int) -> dict:
    policies = {}
    for compiled in (False, True):
        torch.manual_seed(0)
        policies[compiled] = grid_run_policy(run, device, synthetic, compile_encoder=compiled)
    (eager, batch), (compiled, _) = policies[False], policies[True]
    weights = zip(eager.state_dict().values(), compiled.state_dict().values(), strict=True)
    same_weights = all(torch.equal(a, b) for a, b in weights)
    losses = {"eager": first_loss(eager, batch), "compiled": first_loss(compiled, batch)}
    steps = {"eager": train_step(eager, batch), "compiled": train_step(compiled, batch)}
    start = time.perf_counter()
    for _ in range(warmup):  # the compiled policy's first steps compile
        for step in steps.values():
            step()
    warmup_s = time.perf_counter() - start
    times = {"eager": [], "compiled": []}
    for _ in range(repeats):
        for name, step in steps.items():
            times[name].append(milliseconds(step))
    medians = {name: statistics.median(t) for name, t in times.items()}
    pairs = [e / c for e, c in zip(times["eager"], times["compiled"], strict=True)]
    row = {
        "method": run.method,
        "task": run.task,
        "batch": run.batch_size,
        "image_size": run.image_size,
        "threads": torch.get_num_threads(),
        "same_weights": same_weights,
        "first_loss": {k: round(v, 6) for k, v in losses.items()},
        "median_ms": {k: round(v, 2) for k, v in medians.items()},
        "eager_over_compiled": round(medians["eager"] / medians["compiled"], 3),
        "median_pair_ratio": round(statistics.median(pairs), 3),
        "repeats": repeats,
        "warmup_steps": warmup,
        "warmup_s": round(warmup_s, 1),
    }
    print(
        f"{run.method:32s} eager {medians['eager']:.1f} ms, compiled {medians['compiled']:.1f} ms: "
        f"x{row['eager_over_compiled']} (pairs x{row['median_pair_ratio']}); first loss {losses}",
        flush=True,
    )
    del eager, compiled
    release(device)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", default="cpu-ranking", help="grid preset name or file (its seeing spaces' runs)")
    parser.add_argument("--device", default="cpu")
    whole = number_argument(whole=True, minimum=1)
    parser.add_argument("--repeats", type=whole, default=30, help="interleaved steps of each policy (>= 1)")
    parser.add_argument("--warmup", type=whole, default=3, help="untimed steps of each first, compiling (>= 1)")
    parser.add_argument("--threads", type=whole, default=1, help="CPU threads, a grid's --threads (>= 1)")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    from lerobot_obsbench.bench.grid import load_grid

    device = torch.device(args.device)
    prepare(device)
    torch.set_num_threads(args.threads)
    runs = {run.method: run for run in reversed(load_grid(args.grid).expand()) if not is_control(run.obs_space)}
    synthetic = load_synthetic()
    rows = [compare(run, device, synthetic, args.repeats, args.warmup) for run in runs.values()]
    grid = Path(args.grid).name.removesuffix(".yaml")
    write(f"compile_{device.type}_grid_{grid}", {"grid": args.grid, "rows": rows}, args.out)


if __name__ == "__main__":
    main()
