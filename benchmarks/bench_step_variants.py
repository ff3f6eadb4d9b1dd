"""The training step of each seeing space of a grid, as the grid runs it (eager) against the two CPU speed-ups that
leave the model as it is: `compile_encoder` (the observation encoder compiled by torch.compile) and, for an image
encoder, channels-last memory (its convolutions' weights and input frames stored NHWC, the layout oneDNN's kernels
prefer). The variants are timed interleaved: one eager step, one compiled, one channels-last, and so on, so that
whatever else the machine does falls on all alike. Every variant is built from one seed (the same weights), and
the first loss of each on the same batch is recorded, to show each trains the same model.

    .venv/bin/python -m benchmarks.bench_step_variants [--grid cpu-ranking] [--obs-spaces rgb depth] [--repeats 30]
        [--threads 1] [--out FILE]

Writes benchmarks/results/step_variants_<device>_grid_<grid>.json: per run, each variant's median, eager's median
over each variant's, and the median of the per-step ratios.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch
from torch import nn

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


def channels_last(policy: nn.Module) -> int:
    """Store every 2-D convolution stack of `policy` channels-last and feed it channels-last frames; the number of
    stacks converted (0: nothing to convert)."""
    stacks = [m for m in policy.modules() if isinstance(m, nn.Sequential) and isinstance(m[0], nn.Conv2d)]
    for stack in stacks:
        stack.to(memory_format=torch.channels_last)
        stack.register_forward_pre_hook(lambda _, args: (args[0].contiguous(memory_format=torch.channels_last),))
    return len(stacks)


def variants(run, device: torch.device, synthetic) -> tuple[dict, dict]:
    """The run's policy as each variant builds it, from one seed, and the batch they all train on."""
    built = {}
    for name in ("eager", "compiled", "channels_last"):
        torch.manual_seed(0)
        built[name] = grid_run_policy(run, device, synthetic, compile_encoder=name == "compiled")
    if not channels_last(built["channels_last"][0]):
        del built["channels_last"]  # a point or control encoder has no 2-D convolution stack to lay out
    batch = built["eager"][1]
    return {name: policy for name, (policy, _) in built.items()}, batch


def compare(run, device: torch.device, synthetic, repeats: int, warmup: int) -> dict:
    policies, batch = variants(run, device, synthetic)
    reference = list(policies["eager"].state_dict().values())
    same_weights = all(
        all(torch.equal(a, b) for a, b in zip(reference, p.state_dict().values(), strict=True))
        for p in policies.values()
    )
    losses = {name: first_loss(policy, batch) for name, policy in policies.items()}
    steps = {name: train_step(policy, batch) for name, policy in policies.items()}
    start = time.perf_counter()
    for _ in range(warmup):  # the compiled policy's first steps compile
        for step in steps.values():
            step()
    warmup_s = time.perf_counter() - start
    times = {name: [] for name in steps}
    for _ in range(repeats):
        for name, step in steps.items():
            times[name].append(milliseconds(step))
    medians = {name: statistics.median(t) for name, t in times.items()}
    faster = {name: round(medians["eager"] / medians[name], 3) for name in medians if name != "eager"}
    pairs = {
        name: round(statistics.median(e / v for e, v in zip(times["eager"], times[name], strict=True)), 3)
        for name in faster
    }
    row = {
        "method": run.method,
        "task": run.task,
        "batch": run.batch_size,
        "image_size": run.image_size,
        "threads": torch.get_num_threads(),
        "same_weights": same_weights,
        "first_loss": {k: round(v, 6) for k, v in losses.items()},
        "median_ms": {k: round(v, 2) for k, v in medians.items()},
        "eager_over": faster,
        "median_pair_ratio": pairs,
        "repeats": repeats,
        "warmup_steps": warmup,
        "warmup_s": round(warmup_s, 1),
    }
    shown = ", ".join(f"{name} {medians[name]:.1f} ms (x{faster[name]}, pairs x{pairs[name]})" for name in faster)
    print(f"{run.method:32s} eager {medians['eager']:.1f} ms, {shown}; first losses {row['first_loss']}", flush=True)
    del policies, steps
    release(device)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", default="cpu-ranking", help="grid preset name or file (its seeing spaces' runs)")
    parser.add_argument(
        "--obs-spaces",
        nargs="+",
        help="only these of its seeing spaces (default: all; the synthetic frames are a "
        "ManiSkill scene, outside a Meta-World task's crop box)",
    )
    parser.add_argument("--device", default="cpu")
    whole = number_argument(whole=True, minimum=1)
    parser.add_argument("--repeats", type=whole, default=30, help="interleaved steps of each variant (>= 1)")
    parser.add_argument("--warmup", type=whole, default=3, help="untimed steps of each first, compiling (>= 1)")
    parser.add_argument("--threads", type=whole, default=1, help="CPU threads, a grid's --threads (>= 1)")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    from lerobot_obsbench.bench.grid import load_grid

    device = torch.device(args.device)
    prepare(device)
    torch.set_num_threads(args.threads)
    grid_runs = load_grid(args.grid).expand()
    chosen = set(args.obs_spaces or (run.obs_space for run in grid_runs if not is_control(run.obs_space)))
    unknown = chosen - {run.obs_space for run in grid_runs}
    if unknown:
        parser.error(f"--obs-spaces: {sorted(unknown)} not in grid {args.grid}")
    runs = {run.method: run for run in reversed(grid_runs) if run.obs_space in chosen}
    synthetic = load_synthetic()
    rows = [compare(run, device, synthetic, args.repeats, args.warmup) for run in runs.values()]
    grid = Path(args.grid).name.removesuffix(".yaml")
    write(f"step_variants_{device.type}_grid_{grid}", {"grid": args.grid, "rows": rows}, args.out)


if __name__ == "__main__":
    main()
