"""`obsbench run GRID`: demos -> train (stock `lerobot-train`) -> evaluate -> one results record per run.

Layout of the output directory:

    OUT/results.jsonl                 one JSON record per finished run (see `results.py`)
    OUT/demos/<task>-<px>-<cams>-<ctrl>-<N>ep/   scripted demonstrations shared by every run of that task
    OUT/runs/<run_id>/train/          lerobot-train's output_dir (checkpoint under checkpoints/last)
    OUT/runs/<run_id>/train.log       lerobot-train's console output
    OUT/runs/<run_id>/eval/<perturbation>.json   per-episode evaluation results

Resuming: runs whose id is already in results.jsonl are skipped; any other run directory is a leftover of a
killed run and is deleted before that run starts again, so a run is recorded once, from one clean attempt.

Scale-out: `execute_run(config, dataset, out_dir, device)` is a plain top-level function of picklable
arguments returning the record. Locally `run_grid` maps it over a process pool (`--workers`); an existing
distributed engine can map the same function over a cluster (e.g. `ray.remote(execute_run)`) and hand the
records to `append_result`.
"""

from __future__ import annotations

import ctypes
import json
import math
import os
import platform
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from datetime import UTC, datetime
from importlib import metadata
from multiprocessing import get_context
from pathlib import Path

from lerobot_obsbench.bench.grid import Grid, RunSpec, estimate_seconds
from lerobot_obsbench.bench.results import append_result, read_results

RESULTS_FILE = "results.jsonl"
PACKAGES = ("lerobot", "torch", "mani-skill", "sapien", "lerobot_policy_obsbench")


class RunError(RuntimeError):
    """A run failed; its log says why."""


def _die_with_parent() -> None:
    """Children (training subprocesses, pool workers) get SIGKILL when their parent dies, so a killed grid
    leaves no orphan writing into a run directory that the resumed grid is about to delete."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def versions() -> dict[str, str]:
    found = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def demo_dir(out: Path, run: RunSpec, episodes: int) -> Path:
    return out / "demos" / f"{run.demo_key}-{episodes}ep"


def prepare_demos(runs: list[RunSpec], out: Path) -> dict[str, Path]:
    """Record (or resume recording) the demonstrations the runs need: one dataset per task and camera set,
    holding the largest demo count; a run with fewer demos trains on its first episodes."""
    from lerobot_obsbench.datasets.recording import record_demos

    needed: dict[str, tuple[RunSpec, int]] = {}
    for run in runs:
        _, most = needed.get(run.demo_key, (run, 0))
        needed[run.demo_key] = (run, max(most, run.demos))
    paths = {}
    for key, (run, episodes) in needed.items():
        path = demo_dir(out, run, episodes)
        record_demos(run.task, episodes, path, image_size=run.image_size, cameras=run.cameras)
        paths[key] = path
    return paths


def training_steps(run: RunSpec, dataset: Path) -> int:
    if run.steps is not None:
        return int(run.steps)
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    lengths = LeRobotDatasetMetadata("local/obsbench", root=dataset).episodes["length"][: run.demos]
    return max(1, math.ceil(run.epochs * sum(lengths) / run.batch_size))


def train_command(
    run: RunSpec, dataset: Path, output_dir: Path, steps: int, device: str, loader_workers: int = 0
) -> list[str]:
    from lerobot_obsbench.presets import preset_args

    overrides = [f"--policy.{k}={_cli_value(v)}" for k, v in run.policy_overrides]
    sizes = [a for a in preset_args(run.preset, run.policy, run.obs_space) if not a.startswith("--policy.encoder=")]
    return [
        str(Path(sys.executable).parent / "lerobot-train"),
        f"--policy.type={run.policy}",
        f"--policy.obs_space={run.obs_space}",
        *sizes,
        f"--policy.encoder={run.encoder}",
        f"--policy.cameras=[{','.join(run.cameras)}]",
        *overrides,
        f"--policy.optimizer_lr={run.lr}",
        f"--policy.device={device}",
        "--dataset.repo_id=local/obsbench",
        f"--dataset.root={dataset}",
        f"--dataset.episodes=[{','.join(str(i) for i in range(run.demos))}]",
        f"--seed={run.seed}",
        f"--batch_size={run.batch_size}",
        f"--steps={steps}",
        f"--save_freq={steps}",
        f"--log_freq={max(steps // 20, 1)}",
        f"--num_workers={loader_workers}",
        "--wandb.enable=false",
        f"--output_dir={output_dir}",
        f"--job_name=obsbench_{run.run_id}",
    ]


def _cli_value(value) -> str:
    return "[" + ",".join(str(v) for v in value) + "]" if isinstance(value, (list, tuple)) else str(value)


def _evaluation_summary(result: dict) -> dict:
    keys = ("episodes", "successes", "success_rate", "ci95", "sub_success", "episode_length_mean", "wall_s")
    return {k: result[k] for k in keys}


def execute_run(config: dict, dataset: str, out_dir: str, device: str = "cpu", loader_workers: int = 0) -> dict:
    """Train and evaluate one run from scratch; returns its results record (does not write it)."""
    from lerobot_obsbench.envs.evaluate import evaluate

    run = RunSpec.from_config(config)
    root = Path(out_dir) / "runs" / run.run_id
    shutil.rmtree(root, ignore_errors=True)  # leftover of a killed attempt
    root.mkdir(parents=True)
    (root / "run.json").write_text(json.dumps(run.config(), indent=2) + "\n")
    steps = training_steps(run, Path(dataset))
    start = time.time()
    with open(root / "train.log", "w") as log:
        done = subprocess.run(
            train_command(run, Path(dataset), root / "train", steps, device, loader_workers),
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            preexec_fn=_die_with_parent,
            env={**os.environ, "HF_HUB_OFFLINE": "1"},
        )
    train_s = time.time() - start
    checkpoint = root / "train" / "checkpoints" / "last" / "pretrained_model"
    if done.returncode != 0 or not checkpoint.is_dir():
        tail = "".join((root / "train.log").read_text().splitlines(keepends=True)[-15:])
        raise RunError(
            f"training of run {run.run_id} ({run.method} on {run.task}) failed with exit code "
            f"{done.returncode}; log {root / 'train.log'}:\n{tail}"
        )
    evaluations, eval_s = {}, 0.0
    for perturbation in ("none", *run.perturbations):
        result = evaluate(
            checkpoint,
            run.task,
            run.eval_episodes,
            image_size=run.image_size,
            control_mode=run.control_mode,
            device=device,
            perturbation=perturbation,
            progress=False,
        )
        (root / "eval").mkdir(exist_ok=True)
        (root / "eval" / f"{perturbation.replace(':', '_')}.json").write_text(json.dumps(result, indent=2) + "\n")
        evaluations[perturbation] = _evaluation_summary(result)
        eval_s += result["wall_s"]
    return {
        "run_id": run.run_id,
        "config": run.config(),
        "method": run.method,
        "task": run.task,
        "evaluations": evaluations,
        "train_steps": steps,
        "checkpoint": str(checkpoint),
        "device": device,
        "timings": {"train_s": round(train_s, 1), "eval_s": round(eval_s, 1)},
        "versions": versions(),
        "finished_at": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def describe(run: RunSpec) -> str:
    budget = f"{run.steps} steps" if run.steps is not None else f"{run.epochs:g} epochs"
    return (
        f"{run.run_id}  {run.task:20s} {run.method:34s} demos {run.demos:<4d} seed {run.seed:<5d} lr {run.lr:g} "
        f"{budget}, eval {run.eval_episodes} ep x {1 + len(run.perturbations)}"
    )


def plan(grid: Grid, out: Path) -> tuple[list[RunSpec], list[RunSpec]]:
    """(all runs, runs still to do): finished runs are recognised by the id in results.jsonl."""
    runs = grid.expand()
    done = {r["run_id"] for r in read_results(out / RESULTS_FILE)}
    return runs, [r for r in runs if r.run_id not in done]


def run_grid(
    grid: Grid,
    out: Path,
    workers: int = 1,
    device: str = "cpu",
    dry_run: bool = False,
    loader_workers: int = 0,
    echo=print,
) -> int:
    """Run every unfinished run of `grid`; returns the number of failed runs. `loader_workers` is LeRobot's
    DataLoader `num_workers` per run (0 is fastest on a 2-core CPU, where a worker competes with training)."""
    out = Path(out)
    runs, todo = plan(grid, out)
    estimate = sum(estimate_seconds(r) for r in todo)
    echo(
        f"grid {grid.name}: {len(runs)} runs, {len(runs) - len(todo)} already finished, {len(todo)} to run "
        f"(rough 2-core CPU estimate {estimate / 60:.0f} min with 1 worker); results -> {out / RESULTS_FILE}"
    )
    for run in todo:
        echo("  " + describe(run))
    if dry_run or not todo:
        return 0
    datasets = prepare_demos(todo, out)
    failures = 0
    started = time.time()
    jobs = [(run, str(datasets[run.demo_key])) for run in todo]
    if workers <= 1:

        def sequential():
            for index, (run, dataset) in enumerate(jobs, start=1):
                echo(
                    f"[{index}/{len(jobs)}] training {run.run_id} {run.method} on {run.task} "
                    f"(log: {out / 'runs' / run.run_id / 'train.log'})"
                )
                yield run, _attempt(run, dataset, out, device, loader_workers)

        failures = _collect(sequential(), out, len(jobs), started, echo)
    else:
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_die_with_parent) as pool:
            futures = {pool.submit(_attempt, run, dataset, out, device, loader_workers): run for run, dataset in jobs}
            echo(f"{len(jobs)} runs queued on {workers} worker processes (logs: {out / 'runs'}/<run_id>/train.log)")
            outcomes = ((futures[f], f.result()) for f in as_completed(futures))
            failures = _collect(outcomes, out, len(jobs), started, echo)
    return failures


def _attempt(run: RunSpec, dataset: str, out: Path, device: str, loader_workers: int) -> dict | str:
    try:
        return execute_run(run.config(), dataset, str(out), device, loader_workers)
    except Exception as err:
        return f"{type(err).__name__}: {err}"


def _collect(outcomes, out: Path, total: int, started: float, echo) -> int:
    failures = 0
    for index, (run, outcome) in enumerate(outcomes, start=1):
        elapsed = (time.time() - started) / 60
        if isinstance(outcome, str):
            failures += 1
            echo(f"[{index}/{total}] FAILED {run.run_id} {run.method} on {run.task}: {outcome}")
            continue
        append_result(out / RESULTS_FILE, outcome)
        nominal = outcome["evaluations"]["none"]
        lo, hi = nominal["ci95"]
        echo(
            f"[{index}/{total}] {run.run_id} {run.method} on {run.task}: success {nominal['successes']}/"
            f"{nominal['episodes']} = {nominal['success_rate']:.0%} (95% CI {lo:.0%}-{hi:.0%}); train "
            f"{outcome['timings']['train_s']:.0f} s, eval {outcome['timings']['eval_s']:.0f} s; {elapsed:.1f} min"
        )
    return failures
