"""A finished grid's measured unit times against the cost model's prices for the same units (`bench/cost.py`).

Reads the grid's results file: each evaluation record's `wall_s` and each training record's `train_s`, both taken
while the grid ran (with its workers sharing the machine), against what the model prices the same unit at with
one worker per core (`episode_seconds` without a task factor, `train_seconds`). Per task, the evaluations'
measured over priced seconds is the cost model's per-task factor (`benchmarks/refresh_rates.py` copies the
cpu-suite's into the package's rates file); training is reported per task and space. `--wall-s` records the
whole run's wall time (as `time` measured it) next to the dry run's estimate for the grid from nothing, before and
after the factors.

    .venv/bin/python -m benchmarks.bench_grid_cost --grid cpu-suite --results outputs/bench/cpu-suite/results.jsonl
        [--wall-s 7200] [--workers 2] [--out FILE] [--overwrite]

Writes benchmarks/results/grid_cost_<grid>.json, or --out: an existing --out file is replaced only when this tool
wrote it from the same grid and results (lerobot_obsbench/outputs.py's rule), or with --overwrite. The options and
the output path are checked before the results are read.
"""

from __future__ import annotations

import argparse
import re
from collections import defaultdict
from pathlib import Path
from unittest import mock

from benchmarks.common import RESULTS, write
from lerobot_obsbench.bench import cost
from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.results import by_kind, read_results
from lerobot_obsbench.bench.runner import load_work, print_plan
from lerobot_obsbench.numeric import number_argument
from lerobot_obsbench.outputs import OutputPathError, check_output_file, record_outputs


def evaluation_rows(records: list[dict], image_sizes: dict[str, int]) -> dict[str, dict]:
    """Per task: evaluations, episodes, env steps simulated, measured and priced seconds, and their ratio."""
    rows = defaultdict(lambda: {"evaluations": 0, "episodes": 0, "env_steps": 0, "measured_s": 0.0, "priced_s": 0.0})
    for record in by_kind(records, "eval"):
        if "copied_from" in record:  # the same episodes as another record, not run again
            continue
        row = rows[record["task"]]
        row["evaluations"] += 1
        row["episodes"] += record["episodes"]
        row["env_steps"] += sum(record["per_seed"]["length"])
        row["measured_s"] += record["wall_s"]
        row["priced_s"] += cost.episode_seconds(
            record["episodes"],
            record["max_steps"],
            record["device"],
            batch_size=record["batch_size"],
            image_size=image_sizes[record["run_id"]],
        )
    return {task: finished(row) for task, row in rows.items()}


def training_rows(records: list[dict], grid) -> dict[str, dict]:
    """Per task and observation space: runs, measured and priced training seconds, and their ratio."""
    runs = {run.run_id: run for run in grid.expand()}
    rows = defaultdict(lambda: {"runs": 0, "measured_s": 0.0, "priced_s": 0.0})
    for record in by_kind(records, "train"):
        run = runs[record["run_id"]]
        row = rows[f"{run.task} {run.obs_space}"]
        row["runs"] += 1
        row["measured_s"] += record["timings"]["train_s"]
        row["priced_s"] += cost.train_seconds(run, record["train_steps"], record["device"])
    return {key: finished(row) for key, row in sorted(rows.items())}


def finished(row: dict) -> dict:
    """`row` with its seconds rounded and its factor: measured over priced seconds."""
    row = {k: round(v, 1) if isinstance(v, float) else v for k, v in row.items()}
    return {**row, "factor": round(row["measured_s"] / row["priced_s"], 2)}


def dry_run_hours(grid, workers: int) -> float:
    """The dry run's wall-time estimate with `workers` local workers for `grid` from nothing."""
    lines = []
    print_plan(grid, load_work(grid, Path("/nonexistent")), Path("/nonexistent"), "cpu", lines.append, workers)
    # with one worker the plan states only the one-worker cost, which is then the wall time
    patterns = (r"~([0-9.]+) h of wall time", r"with one worker: ([0-9.]+) h on a 2-core CPU")
    found = [match for pattern in patterns for line in lines if (match := re.search(pattern, line))]
    return float(found[0].group(1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--grid", required=True, help="the grid's name or YAML file")
    parser.add_argument("--results", type=Path, required=True, help="its results.jsonl")
    parser.add_argument(
        "--wall-s",
        type=number_argument(above=0),
        help="the run's wall time from nothing in seconds, as `time` measured it (a finite number > 0)",
    )
    parser.add_argument(
        "--workers",
        type=number_argument(whole=True, minimum=1),
        default=2,
        help="the local workers it ran with (a whole number >= 1)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        help="the JSON file to write (default: benchmarks/results/grid_cost_GRID.json, regenerated like every "
        "benchmark's result); an existing one is replaced only when this tool wrote it from the same grid and "
        "results, or with --overwrite",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an --out file this tool did not write")
    args = parser.parse_args()

    grid = load_grid(args.grid)
    name = f"grid_cost_{grid.name}"
    out = args.out or RESULTS / f"{name}.json"
    made_by = {"writer": "bench_grid_cost", "grid": grid.name, "results": str(args.results.resolve())}
    try:
        check_output_file(out, "--out", args.out is None or args.overwrite, [args.results], made_by)
    except OutputPathError as err:
        parser.error(str(err))
    records = read_results(args.results)
    foreign = {r["run_id"] for r in records} - {run.run_id for run in grid.expand()}
    if not records or foreign:
        parser.error(
            f"--results {args.results}: "
            + (f"{len(foreign)} runs not in grid {grid.name}" if foreign else "empty")
            + f"; give the results file that `obsbench run {args.grid}` wrote"
        )
    image_sizes = {r["run_id"]: r["config"]["image_size"] for r in by_kind(records, "train")}
    evaluation = evaluation_rows(records, image_sizes)
    with mock.patch.dict(cost.EVAL_TASK_FACTOR, {"cpu": {}}):
        before = dry_run_hours(grid, args.workers)
    payload = {
        "grid": grid.name,
        "results": str(args.results),
        "workers": args.workers,
        "wall_s": args.wall_s,
        "dry_run_hours": {"without_task_factors": before, "with_task_factors": dry_run_hours(grid, args.workers)},
        "evaluation": evaluation,
        "training": training_rows(records, grid),
    }
    written = write(name, payload, out)
    if args.out is not None:  # the default file is regenerated whatever wrote it: no record beside it
        record_outputs([written], made_by)


if __name__ == "__main__":
    main()
