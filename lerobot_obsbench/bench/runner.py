"""`obsbench run GRID`: the grid's driver. It plans the units of work (`units.py`: demonstrations, training,
evaluations), hands them to an engine (`engines.py`: a local process pool or Ray), appends each finished unit's
record to OUT/results.jsonl, and prints live progress.

Resuming is by identity: a run whose train record exists is not trained again, an evaluation whose eval record
exists is not run again; a run killed mid-training resumes from its last checkpoint (`units.train_unit`). A grid
with `checkpoints_from` trains nothing: it evaluates the checkpoints another grid trained.

Order of work per run: train -> validation evaluations of every checkpoint (when the grid selects checkpoints)
-> test evaluations of the last and the best-on-validation checkpoint, nominally and under each perturbation.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from lerobot_obsbench.bench.engines import make_engine
from lerobot_obsbench.bench.grid import BUDGET_UNITS, EvalSpec, Grid, GridError, RunSpec
from lerobot_obsbench.bench.results import RESULTS_FILE, append_result, by_kind, read_results
from lerobot_obsbench.bench.units import (
    demo_frames,
    demos_unit,
    eval_unit,
    evaluation_progress,
    train_unit,
    training_progress,
)
from lerobot_obsbench.envs.base_task import TASKS, asset_help, missing_assets, task_spec
from lerobot_obsbench.envs.vector import default_batch_size
from lerobot_obsbench.locks import exclusive_output
from lerobot_obsbench.rlbench.paper_tasks import grid_task_name

DEMO_FRAMES_PER_EPISODE = 30  # for estimates before the demonstrations exist

# Training samples per second by (device kind, preset) and space kind, for `--dry-run` estimates and a grid's ETA
# until a run reports its own rate. Which machine measured each figure, and which figures are bounds:
# docs/performance.md#the-cost-model; tests/test_bench_grid.py holds the measured ones to their benchmark's JSON.
TRAIN_SAMPLES_PER_SECOND = {
    ("cpu", "tiny"): {"image": 100.0, "point": 100.0, "none": 200.0},
    ("cpu", "cpu"): {"image": 170.0, "point": 360.0, "none": 750.0},
    ("cpu", "paper"): {"image": 2.5, "point": 0.5, "none": 50.0},
    ("cuda", "tiny"): {"image": 1190.0, "point": 960.0, "none": 1450.0},
    ("cuda", "cpu"): {"image": 1190.0, "point": 960.0, "none": 1450.0},
    ("cuda", "paper"): {"image": 270.0, "point": 100.0, "none": 270.0},
}
# Evaluation env steps per second with the policy at 64², by lockstep batch size, env start-up included (an
# unmeasured batch size counts as the largest measured one below it); the same page says where each was measured.
EVAL_STEPS_PER_SECOND = {"cpu": {1: 23.6, 2: 24.7, 3: 26.1, 4: 24.1}, "cuda": {1: 43.3, 16: 32.6}}
# One line of the dry run: the machines behind the rates.
RATES_MEASURED_ON = (
    "rates: cpu measured on a 2-core CPU machine; cuda on one H200 with a 16-core host (model steps; evaluation on "
    "ManiSkill's CPU simulation rendering on the GPU: its GPU simulation is not measured); docs/performance.md"
)
EVAL_RATE_IMAGE_SIZE = 64
# The cores of the machine the cpu rates were measured on: more local workers than this share no more of its time.
CPU_RATE_CORES = 2
# RLBench steps per second: a guess, not measured (CoppeliaSim does not run here). Each step plans a path to the
# predicted pose and executes it in CoppeliaSim, which simulates on the CPU whatever the policy's device
RLBENCH_STEPS_PER_SECOND = {"cpu": 1.0, "cuda": 1.0}


def device_kind(device: str) -> str:
    return "cuda" if device.startswith("cuda") else "cpu"


def space_kind(obs_space: str) -> str:
    from lerobot_obsbench.schema import CONTROL_SPACES, reads_points

    return "point" if reads_points(obs_space) else "none" if obs_space in CONTROL_SPACES else "image"


def train_seconds(run: RunSpec, steps: int, device: str) -> float:
    rate = TRAIN_SAMPLES_PER_SECOND[(device_kind(device), run.preset)][space_kind(run.obs_space)]
    # larger images cost more; smaller ones barely less (loading and the fixed per-step work dominate)
    return steps * run.batch_size / rate * max(run.image_size / 128, 1.0) ** 2 + 20


def eval_batch_size(grid: Grid, device: str, cores: int | None = None) -> int:
    """Episodes a ManiSkill evaluation runs in lockstep: the grid's `eval_batch_size`, else the device's default,
    on CPU at most the `cores` a unit of work has to itself when it shares the machine (None: it does not)."""
    if grid.eval_batch_size:
        return grid.eval_batch_size
    default = default_batch_size(device)
    return min(default, cores) if cores and device_kind(device) == "cpu" else default


def episode_seconds(
    episodes: float,
    max_steps: int,
    device: str,
    rlbench: bool = False,
    batch_size: int = 1,
    image_size: int = 128,
    used: float = 0.6,
) -> float:
    """Running `episodes` simulated episodes of up to `max_steps` steps, `batch_size` in lockstep, each using
    `used` of its budget (a successful episode ends early; a failed one runs it out)."""
    if rlbench:
        rate = RLBENCH_STEPS_PER_SECOND[device_kind(device)]
    else:
        measured = EVAL_STEPS_PER_SECOND[device_kind(device)]
        rate = measured[max(n for n in measured if n <= batch_size)]
        if device_kind(device) == "cpu":  # the CPU renderer slows with the frame; the GPU's did not from 64² to 128²
            rate *= min(1.0, EVAL_RATE_IMAGE_SIZE / image_size)
    return episodes * max_steps * used / rate + 10


def eval_seconds(spec: EvalSpec, device: str, rlbench: bool = False, batch_size: int = 1, image_size: int = 128):
    return episode_seconds(spec.episodes, spec.max_steps, device, rlbench, batch_size, image_size)


def demo_seconds(grid: Grid, run: RunSpec, episodes: int, device: str) -> float:
    """Recording `episodes` scripted demonstrations of `run`'s task, one env: an expert's step costs what a
    policy's does in evaluation (the simulator and renderer dominate), and each success comes with the failed
    attempts its expert's success rate implies, each running out the episode's budget."""
    failed = episodes * (1 / task_spec(run.task).expert_success_rate - 1)
    steps = grid.max_steps(run)
    return episode_seconds(episodes, steps, device, image_size=run.image_size) + episode_seconds(
        failed, steps, device, image_size=run.image_size, used=1.0
    )


def demo_dir(out: Path, run: RunSpec, episodes: int) -> Path:
    return out / "demos" / f"{run.demo_key}-{episodes}ep"


def demos_recorded(path: Path) -> bool:
    """Whether `path` holds a finished recording (its LeRobotDataset is assembled only once every episode is in)."""
    return (path / "meta" / "info.json").is_file()


@dataclass
class Work:
    """What a grid still has to do."""

    runs: list[RunSpec]
    trained: dict[str, dict]  # run_id -> train record
    evaluated: dict[str, dict]  # eval_id -> eval record
    to_train: list[RunSpec] = field(default_factory=list)
    demos: dict[str, tuple[RunSpec, int]] = field(default_factory=dict)  # demo_key -> (a run, most demos)


def load_work(grid: Grid, out: Path, echo=print) -> Work:
    results = out / RESULTS_FILE
    records = read_results(results)
    trained = {r["run_id"]: r for r in by_kind(records, "train")}
    runs = grid.expand()
    if grid.checkpoints_from:
        source = Path(grid.checkpoints_from).expanduser() / RESULTS_FILE
        source_records = read_results(source)
        theirs = {r["run_id"]: r for r in by_kind(source_records, "train")}
        missing = [r for r in runs if r.run_id not in trained and r.run_id not in theirs]
        if missing:
            raise GridError(
                f"{grid.name} evaluates checkpoints from {source}, which has no trained run for "
                f"{len(missing)} of its {len(runs)} runs (e.g. {missing[0].method} on {missing[0].task}, seed "
                f"{missing[0].seed}, lr {missing[0].lr:g}): run the training grid first, and keep the two grids' "
                "training fields identical"
            )
        wanted = {r.run_id for r in runs if r.run_id not in trained}
        # the report needs the runs' configs, the best-checkpoint choice their validation scores: copy both here
        for record in [
            *(theirs[i] for i in sorted(wanted)),
            *(r for r in by_kind(source_records, "eval") if r["run_id"] in wanted and r["split"] == "validation"),
        ]:
            record = {**record, "trained_in": str(source.parent)}
            append_result(results, record)
            records.append(record)
            if record["kind"] == "train":
                trained[record["run_id"]] = record
    work = Work(runs, trained, {r["eval_id"]: r for r in by_kind(records, "eval")})
    work.to_train = [r for r in runs if r.run_id not in trained]
    for run in work.to_train:
        _, most = work.demos.get(run.demo_key, (run, 0))
        work.demos[run.demo_key] = (run, max(most, run.demos))
    # the held-out demonstrations follow the most any run of the dataset trains on
    work.demos = {key: (run, most + grid.held_out_demos) for key, (run, most) in work.demos.items()}
    return work


def planned_steps(run: RunSpec, out: Path) -> tuple[int, bool]:
    """(optimizer steps, exact): frame_epochs budgets are estimated until the demonstrations exist."""
    if run.budget_unit != "frame_epochs":
        return run.steps(), True
    path = demo_dir(out, run, run.demos)
    if demos_recorded(path):
        return run.steps(demo_frames(path, run.demos)), True
    return run.steps(run.demos * DEMO_FRAMES_PER_EPISODE), False


def print_plan(grid: Grid, work: Work, out: Path, device: str, echo=print, workers: int = 1) -> None:
    done_evals = sum(s.eval_id in work.evaluated for r in work.runs for s in grid.evaluations(r))
    all_evals = sum(len(grid.evaluations(r)) for r in work.runs)
    echo(
        f"grid {grid.name}: {len(work.runs)} runs, {len(work.runs) - len(work.to_train)} already trained, "
        f"{len(work.to_train)} to train; {done_evals} of {all_evals} test evaluations done; results -> "
        f"{out / RESULTS_FILE}"
    )
    if grid.checkpoints_from:
        echo(f"  evaluates the checkpoints trained by {grid.checkpoints_from} (trains nothing)")
    totals = {"steps": 0, "samples": 0, "episodes": 0, "cpu": 0.0, "cuda": 0.0}
    to_record = [
        (run, episodes)
        for run, episodes in work.demos.values()
        if run.rlbench_task is None and not demos_recorded(demo_dir(out, run, episodes))
    ]
    for run, episodes in to_record:
        for kind in ("cpu", "cuda"):
            totals[kind] += demo_seconds(grid, run, episodes, kind)
    if to_record:
        echo(
            f"  demonstrations to record: {sum(n for _, n in to_record)} episodes of "
            + ", ".join(f"{run.task} ({n})" for run, n in to_record)
        )
    for run in work.runs:
        steps, exact = planned_steps(run, out)
        unit = run.budget_unit
        train = run.run_id not in work.trained
        evals = [s for s in grid.evaluations(run) if s.eval_id not in work.evaluated]
        checkpoints = grid.per_policy("checkpoints", run.policy)
        if grid.validation_episodes:
            evals += grid.validations(run, list(range(checkpoints)))  # one per checkpoint, for the estimate
        if not train and not evals:
            continue
        approx = "" if exact else "~"
        echo(
            f"  {run.run_id}  {run.task:20s} {run.method:34s} demos {run.demos:<4d} seed {run.seed:<4d} "
            f"lr {run.lr:<7g} batch {run.batch_size:<3d} {run.budget:g} {unit} = {approx}{steps} steps, "
            f"{approx}{steps * run.batch_size} samples{'' if train else ' (trained)'}; "
            f"{len(evals)} evaluations, {sum(s.episodes for s in evals)} episodes"
        )
        if train:
            totals["steps"] += steps
            totals["samples"] += steps * run.batch_size
        totals["episodes"] += sum(s.episodes for s in evals)
        for kind in ("cpu", "cuda"):
            totals[kind] += (train_seconds(run, steps, kind) if train else 0) + sum(
                # the cost line's machines: one worker (the whole machine) on a 2-core CPU, or one GPU
                eval_seconds(s, kind, run.rlbench_task is not None, eval_batch_size(grid, kind), run.image_size)
                for s in evals
            )
    echo(
        f"  total to do: {totals['steps']} optimizer steps, {totals['samples']} training samples, "
        f"{totals['episodes']} evaluation episodes. Budget units: "
        + "; ".join(f"{u} = {what}" for u, what in BUDGET_UNITS.items() if any(r.budget_unit == u for r in work.runs))
    )
    echo(
        f"  rough cost with one worker: {totals['cpu'] / 3600:.1f} h on a 2-core CPU, {totals['cuda'] / 3600:.1f} h "
        f"on one H200 GPU (planning on {device}; demonstrations to record included)"
    )
    if workers > 1 and device_kind(device) == "cpu":
        shared = min(workers, CPU_RATE_CORES)
        echo(
            f"  with {workers} local workers: ~{totals['cpu'] / 3600 / shared:.1f} h of wall time on a 2-core CPU "
            f"(the one-worker cost shared evenly by {shared}; measured against real grids in docs/performance.md)"
        )
    echo(f"  {RATES_MEASURED_ON}")
    if len(set(grid.seeds)) < 2:
        echo(
            f"  note: one training seed ({grid.seeds[0]}): every comparison rests on it, so its intervals cover "
            "evaluation episodes only and the report marks a method above blind with △, never ▲; list at least "
            "3 `seeds` to measure training variance"
        )


class Driver:
    """Submits units as their inputs become ready, records their results, prints progress."""

    def __init__(
        self,
        grid: Grid,
        work: Work,
        out: Path,
        engine,
        device: str,
        loader_workers: int,
        threads: int | None,
        echo,
        eval_cores: int | None = None,
    ):
        self.grid, self.work, self.out, self.engine = grid, work, out, engine
        self.device, self.loader_workers, self.threads, self.echo = device, loader_workers, threads, echo
        self.results = out / RESULTS_FILE
        self.pending: dict = {}  # engine handle -> (kind, payload)
        self.copies: dict[str, list[dict]] = {}  # eval_id of a "last" eval -> "best" records waiting to copy it
        self.failures = 0
        self.started = time.time()
        self.rates: dict[str, tuple[float, int]] = {}  # run_id -> (time, step) at the previous progress line
        self.gpus = 1 if device.startswith("cuda") else 0
        # where an RLBench grid's units find PerAct's data and the CLIP weights (not part of any run's identity)
        self.rlbench = {"data": grid.rlbench_data, "clip_weights": grid.clip_weights} if grid.rlbench_data else None
        self.eval_batch_size = eval_batch_size(grid, device, eval_cores)

    # ---- scheduling ----------------------------------------------------------------------------------------

    def submit(self, kind: str, payload, fn, *args, cpus: float = 1, gpus: float = 0) -> None:
        self.pending[self.engine.submit(fn, *args, cpus=cpus, gpus=gpus)] = (kind, payload)

    def start(self) -> None:
        for key, (run, episodes) in self.work.demos.items():
            self.submit(
                "demos",
                key,
                demos_unit,
                run.task,
                episodes,
                str(demo_dir(self.out, run, episodes)),
                run.image_size,
                list(run.cameras),
                self.rlbench,
            )
        for run in self.work.runs:
            if run.run_id in self.work.trained:
                self.schedule_evaluations(run)

    def train(self, run: RunSpec, dataset: Path) -> None:
        self.submit(
            "train",
            run,
            train_unit,
            run.config(),
            str(dataset),
            str(self.out),
            self.device,
            self.grid.per_policy("checkpoints", run.policy),
            self.grid.held_out_demos,
            self.loader_workers,
            self.threads,
            cpus=max(1, self.threads or 1),
            gpus=self.gpus,
        )

    def evaluate(self, run: RunSpec, spec: EvalSpec, step: int) -> None:
        train = self.work.trained[run.run_id]
        checkpoint = train["checkpoints"][str(step)]
        self.submit(
            "eval",
            (run, spec),
            eval_unit,
            spec.config(),
            run.config(),
            checkpoint,
            step,
            str(self.out),
            self.device,
            self.threads,
            self.rlbench,
            self.eval_batch_size,
            # each of the lockstep envs simulates and renders in a process of its own
            cpus=max(1, self.threads or 1, self.eval_batch_size),
            gpus=self.gpus,
        )

    def schedule_evaluations(self, run: RunSpec) -> None:
        """Validation evaluations first (when the grid selects checkpoints), then the test evaluations."""
        train = self.work.trained[run.run_id]
        steps = sorted(int(s) for s in train["checkpoints"])
        waiting = [s for s in self.grid.validations(run, steps) if s.eval_id not in self.work.evaluated]
        for spec in waiting:
            self.evaluate(run, spec, int(spec.checkpoint.removeprefix("step:")))
        if not waiting:
            self.schedule_tests(run)

    def best_step(self, run: RunSpec) -> int | None:
        """The checkpoint with the highest validation success rate (ties: the later one)."""
        train = self.work.trained[run.run_id]
        scores = []
        for spec in self.grid.validations(run, sorted(int(s) for s in train["checkpoints"])):
            record = self.work.evaluated.get(spec.eval_id)
            if record is None:
                return None
            scores.append((record["success_rate"], int(spec.checkpoint.removeprefix("step:"))))
        return max(scores)[1] if scores else None

    def schedule_tests(self, run: RunSpec) -> None:
        train = self.work.trained[run.run_id]
        last = int(train["train_steps"])
        best = self.best_step(run)
        for spec in self.grid.evaluations(run):
            if spec.eval_id in self.work.evaluated:
                continue
            if spec.checkpoint == "best" and best == last:  # the same checkpoint: copy the last one's record
                twin = EvalSpec(**{**spec.config(), "checkpoint": "last"})
                self.copies.setdefault(twin.eval_id, []).append(spec.config())
                if twin.eval_id in self.work.evaluated:
                    self.copy_records(twin.eval_id)
                continue
            self.evaluate(run, spec, last if spec.checkpoint == "last" else best)

    def copy_records(self, last_id: str) -> None:
        for config in self.copies.pop(last_id, []):
            spec = EvalSpec(**config)
            self.record({**self.work.evaluated[last_id], **config, "eval_id": spec.eval_id, "copied_from": last_id})

    def record(self, record: dict) -> None:
        append_result(self.results, record)
        if record["kind"] == "train":
            self.work.trained[record["run_id"]] = record
        else:
            self.work.evaluated[record["eval_id"]] = record

    # ---- the loop -------------------------------------------------------------------------------------------

    def finished(self, kind: str, payload, outcome) -> None:
        if kind == "demos":
            for run in self.work.to_train:
                if run.demo_key == payload:
                    _, episodes = self.work.demos[payload]
                    self.train(run, demo_dir(self.out, run, episodes))
            return
        self.record(outcome)
        if kind == "train":
            self.echo(
                f"trained {payload.run_id} {payload.method} on {payload.task}: {outcome['train_steps']} steps in "
                f"{outcome['timings']['train_s']:.0f} s"
                + (f" (resumed at step {outcome['resumed_from']})" if outcome["resumed_from"] else "")
            )
            self.schedule_evaluations(payload)
            return
        run, spec = payload
        lo, hi = outcome["ci95"]
        self.echo(
            f"evaluated {run.run_id} {run.method} on {run.task} [{spec.split}, {spec.checkpoint} = step "
            f"{outcome['checkpoint_step']}, {spec.perturbation}]: {outcome['successes']}/{outcome['episodes']} = "
            f"{outcome['success_rate']:.0%} (95% CI {lo:.0%}-{hi:.0%})"
        )
        if spec.split == "validation" and self.best_step(run) is not None:
            self.schedule_tests(run)
        if spec.eval_id in self.copies:
            self.copy_records(spec.eval_id)

    def failed(self, kind: str, payload, err: Exception) -> None:
        self.failures += 1
        what = {
            "demos": lambda: f"demonstrations {payload}",
            "train": lambda: f"training {payload.run_id} {payload.method} on {payload.task}",
            "eval": lambda: (
                f"evaluation {payload[1].eval_id} of "
                f"{payload[0].run_id} ({payload[1].split}, {payload[1].checkpoint}, {payload[1].perturbation})"
            ),
        }[kind]()
        self.echo(f"FAILED {what}: {type(err).__name__}: {err}")

    def loop(self, every: float) -> None:
        last_progress = time.time()
        while self.pending:
            for handle in self.engine.wait(list(self.pending), timeout=min(every, 5.0)):
                kind, payload = self.pending.pop(handle)
                try:
                    outcome = self.engine.result(handle)
                except Exception as err:
                    self.failed(kind, payload, err)
                    continue
                self.finished(kind, payload, outcome)
            if time.time() - last_progress >= every and self.pending:
                self.progress()
                last_progress = time.time()

    # ---- progress -------------------------------------------------------------------------------------------

    def progress(self) -> None:
        lines, remaining = [], 0.0
        for kind, payload in self.pending.values():
            if kind == "train":
                state = training_progress(self.out, payload.run_id)
                steps, _ = planned_steps(payload, self.out)
                if state is None or state["started"] < self.started:
                    remaining += train_seconds(payload, steps, self.device)
                    continue
                now, (then, before) = time.time(), self.rates.get(payload.run_id, (self.started, state["step"]))
                rate = (state["step"] - before) / max(now - then, 1e-6) if state["step"] > before else None
                self.rates[payload.run_id] = (now, state["step"])
                left = (state["steps"] - state["step"]) / rate if rate else train_seconds(payload, steps, self.device)
                remaining += left
                loss = f" loss {state['loss']:.4f}" if state["loss"] is not None else ""
                speed = f", {rate:.2f} steps/s, ETA {left / 60:.1f} min" if rate else ""
                lines.append(
                    f"  training {payload.run_id} {payload.method} on {payload.task}: step "
                    f"{state['step']}/{state['steps']}{loss}{speed}"
                )
            elif kind == "eval":
                run, spec = payload
                state = evaluation_progress(self.out, run.run_id, spec.eval_id)
                rlbench = run.rlbench_task is not None
                remaining += eval_seconds(spec, self.device, rlbench, self.eval_batch_size, run.image_size) * (
                    1 - (state or {"done": 0})["done"] / spec.episodes
                )
                if state:
                    lines.append(
                        f"  evaluating {run.run_id} {run.method} [{spec.split}, {spec.checkpoint}, "
                        f"{spec.perturbation}]: episode {state['done']}/{state['episodes']}, "
                        f"{state['successes']} successes"
                    )
        workers = getattr(self.engine, "workers", 1)
        elapsed = (time.time() - self.started) / 60
        self.echo(
            f"[{elapsed:.1f} min] {len(self.pending)} units queued or running; grid ETA ~"
            f"{math.ceil(remaining / max(workers, 1) / 60)} min (later units not counted until ready)"
        )
        for line in lines:
            self.echo(line)


def rlbench_problems(grid: Grid) -> tuple[list[str], str | None]:
    """(what an RLBench grid's data lacks: task folders, CLIP weights; what the simulator stack lacks, or None)."""
    from lerobot_obsbench.rlbench.evaluate import RLBenchUnavailable, require_rlbench
    from lerobot_obsbench.rlbench.format import RLBenchFormatError, find_episodes

    data = Path(grid.rlbench_data).expanduser()
    # the episodes each split must hold, and the grid field that asks for them
    needed = {"test": (grid.eval_episodes, "eval_episodes"), "val": (grid.validation_episodes, "validation_episodes")}
    if not grid.checkpoints_from:
        needed["train"] = (max(grid.demos), "demos")
    folders = [(data / split / grid_task_name(t), *needed[split]) for t in grid.tasks for split in needed]
    missing = [str(folder) for folder, count, _ in folders if count and not folder.is_dir()]
    problems = []
    for folder, count, asked_by in folders:
        if count and folder.is_dir():
            try:
                found = len(find_episodes(folder))
            except RLBenchFormatError:
                found = 0
            if found < count:
                problems.append(f"{folder} holds {found} episodes; the grid's {asked_by} needs {count}")
    if missing:
        problems.append(
            f"rlbench_data lacks {len(missing)} task folder(s): {', '.join(missing[:3])}"
            + (" ..." if len(missing) > 3 else "")
            + " (PerAct's pre-generated data: https://github.com/peract/peract, 'Pre-generated datasets'; "
            "one folder per split, train / val / test, holding one folder per task)"
        )
    if grid.clip_weights and not Path(grid.clip_weights).expanduser().is_file():
        problems.append(f"clip_weights {grid.clip_weights} is not a file (a local CLIP ViT-B/16 checkpoint)")
    try:
        require_rlbench()
        simulator = None
    except RLBenchUnavailable as err:
        simulator = str(err)
    return problems, simulator


def check_tasks(grid: Grid, dry_run: bool = False, echo=print) -> None:
    """Refuse, before anything runs, a task the grid cannot record demonstrations of (no scripted expert) or
    cannot simulate here (its ManiSkill assets missing; for RLBench: its data, CLIP weights or the simulator),
    naming every problem and its fix. A dry run only notes what RLBench lacks here (a plan needs none of it)."""
    if grid.rlbench_data:
        problems, simulator = rlbench_problems(grid)
        problems += [simulator] if simulator else []
        if problems and dry_run:
            echo(f"note: this machine cannot run {grid.name} as it is: " + ". Also: ".join(problems))
        elif problems:
            raise GridError(f"{grid.name}: " + ". Also: ".join(problems))
        return
    for name in grid.tasks:
        spec = task_spec(name)
        problems = []
        if spec.expert is None and not grid.checkpoints_from:
            experts = ", ".join(n for n, t in TASKS.items() if t.expert)
            problems.append(
                f"{name} has no scripted expert, and grids record their demonstrations with one (tasks with "
                f"experts: {experts}); for {name}, convert official demonstrations (obsbench import-h5) and train "
                "on them with lerobot-train"
            )
        if missing_assets(spec):
            problems.append(asset_help(spec, os.environ.get("MS_ASSET_DIR")))
        if problems:
            raise GridError(f"{grid.name}: " + ". Also: ".join(problems))


def run_grid(
    grid: Grid,
    out: Path,
    engine: str = "local",
    workers: int = 1,
    device: str = "cpu",
    address: str | None = None,
    dry_run: bool = False,
    loader_workers: int = 0,
    threads: int | None = None,
    progress_every: float = 30.0,
    echo=print,
) -> int:
    """Run every unit of `grid` that has no record yet; returns the number of failed units.

    `threads`: CPU threads per unit (None: the machine's cores shared by the local workers; Ray: 1 per CPU
    the unit asks for). `loader_workers`: LeRobot's DataLoader workers per training run (0 is fastest on a
    2-core CPU, where a worker competes with training)."""
    out = Path(out)
    check_tasks(grid, dry_run, echo)
    if dry_run:
        print_plan(grid, load_work(grid, out, echo), out, device, echo, workers)
        return 0
    # lockstep envs may use the cores a unit has to itself: the machine's with one local worker (unless --threads
    # says fewer), its share with several, one CPU under Ray (what a unit asks for there)
    whole_machine = engine == "local" and workers <= 1 and threads is None
    if threads is None and engine == "local":
        threads = max(1, (os.cpu_count() or 1) // max(workers, 1))
    eval_cores = None if whole_machine else (threads or 1)
    with exclusive_output(out, f"obsbench run {grid.name}"):  # a second runner on `out` is refused
        work = load_work(grid, out, echo)
        print_plan(grid, work, out, device, echo, workers)
        units = make_engine(engine, workers, address)
        runner = Driver(grid, work, out, units, device, loader_workers, threads, echo, eval_cores)
        try:
            runner.start()
            if not runner.pending:
                echo("nothing to do: every run is trained and every evaluation recorded")
            runner.loop(progress_every)
        except KeyboardInterrupt:
            runner.engine.shutdown(abort=True)
            raise
        finally:
            runner.engine.shutdown()
    return runner.failures
