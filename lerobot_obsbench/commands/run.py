"""`obsbench run`: run a benchmark grid, demos -> lerobot-train -> evaluation -> results.jsonl, on this machine
or a Ray cluster (`bench.runner`; resumable)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common

NAME = "run"
HELP = (
    "run a benchmark grid (YAML file or preset name: quick, paper-main, ...): "
    "demos -> lerobot-train -> eval -> results.jsonl; resumable"
)
EXAMPLE = """obsbench run quick --workers 2"""
INTERRUPTED = (
    "every finished unit is kept in the results file (a killed training resumes from its last checkpoint); "
    "run the same command to go on"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lerobot_obsbench.bench.engines import ENGINES
    from lerobot_obsbench.bench.grid import preset_grids
    from lerobot_obsbench.bench.machine import CAPABILITY_CHOICES, default_capability

    p.add_argument("grid", help=f"grid YAML file, or the name of a preset grid: {', '.join(preset_grids())}")
    p.add_argument("--out", type=Path, default=None, help="output directory (default outputs/bench/<grid name>)")
    p.add_argument(
        "--engine",
        default="local",
        choices=ENGINES,
        help="local: a process pool on this machine; "
        "ray: Ray tasks on an existing cluster (--address) or a new local Ray instance",
    )
    p.add_argument("--address", default=None, help="Ray cluster address (e.g. auto, or ray://HEAD:10001)")
    p.add_argument(
        "--workers", type=common.positive_int, default=1, help="units of work run in parallel by the local engine"
    )
    p.add_argument(
        "--device",
        type=common.device_name,
        default="cpu",
        help="torch device for training, evaluation and the simulator's "
        "renderer (cpu, cuda, cuda:N); with cuda each unit asks the engine for one GPU",
    )
    p.add_argument(
        "--threads",
        type=common.positive_int,
        default=None,
        help="CPU threads per unit (default: the cores shared by the local workers; 1 per CPU under Ray)",
    )
    p.add_argument("--progress-every", type=common.positive_float, default=30.0, help="seconds between progress lines")
    p.add_argument(
        "--loader-workers",
        type=common.non_negative_int,
        default=None,
        help="DataLoader workers per training run (default: 0 on cpu, 4 on a GPU)",
    )
    p.add_argument(
        "--tasks",
        nargs="+",
        default=None,
        metavar="TASK",
        help="run only these of the grid's tasks (a piece of it: the same runs, into the same --out; the other "
        "pieces or the whole grid rerun later finish it)",
    )
    p.add_argument(
        "--obs-spaces", nargs="+", default=None, metavar="SPACE", help="run only these of the grid's obs_spaces"
    )
    p.add_argument(
        "--cpu-capability",
        choices=CAPABILITY_CHOICES,
        default=default_capability(),
        help="the CPU kernels every unit runs with (torch, MKL and oneDNN pinned to them), so that a run's numbers do "
        f"not depend on the processor it ran on (default: {default_capability()}; native: this machine's best, "
        "unpinned); the records name them",
    )
    p.add_argument("--dry-run", action="store_true", help="print the runs still to do and a rough cost; run nothing")
    p.add_argument(
        "--rlbench-data", default=None, help="RLBench grids: PerAct's data (DIR/train|val|test/<task>), for the grid's"
    )
    p.add_argument("--clip-weights", default=None, help="RLBench grids: CLIP ViT-B/16 weights file, for the grid's")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.bench.grid import load_grid
    from lerobot_obsbench.bench.runner import run_grid
    from lerobot_obsbench.bench.specs import GridError

    grid = load_grid(args.grid).piece(args.tasks, args.obs_spaces)
    for flag, value in (("--rlbench-data", args.rlbench_data), ("--clip-weights", args.clip_weights)):
        if value is not None and not grid.rlbench_data:
            raise GridError(f"{flag} applies to grids of RLBench tasks; {grid.name} has none")
    grid.rlbench_data = args.rlbench_data or grid.rlbench_data
    grid.clip_weights = args.clip_weights or grid.clip_weights
    out = args.out or Path("outputs") / "bench" / grid.name
    loader_workers = args.loader_workers if args.loader_workers is not None else (0 if args.device == "cpu" else 4)
    failures = run_grid(
        grid,
        out,
        engine=args.engine,
        workers=args.workers,
        device=args.device,
        address=args.address,
        dry_run=args.dry_run,
        loader_workers=loader_workers,
        threads=args.threads,
        progress_every=args.progress_every,
        cpu_capability=args.cpu_capability,
    )
    if failures:
        print(f"{failures} unit(s) of work failed (see the messages above); rerun the same command to retry them.")
        return 1
    if not args.dry_run:
        print(f"done: results in {out / 'results.jsonl'}; `obsbench report {out / 'results.jsonl'}` makes the tables")
        if args.tasks or args.obs_spaces:
            print(f"(a piece of {grid.name}: the same command without --tasks/--obs-spaces runs what it left)")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
