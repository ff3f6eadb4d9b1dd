"""`obsbench run GRID`: the grid's driver. It plans the units of work (`units.py`: demonstrations, training,
evaluations), hands them as jobs (`jobs.py`) to an engine (`engines.py`: a local process pool or Ray), appends each
finished unit's record to OUT/results.jsonl, and prints live progress; `cost.py` prices the plan and the ETA.

Resuming is by identity: a run whose train record exists is not trained again, an evaluation whose eval record
exists is not run again; a run killed mid-training resumes from its last checkpoint (`units.train_unit`). A grid
with `checkpoints_from` trains nothing: it evaluates the checkpoints another grid trained.

Order of work per run: train -> validation evaluations of every checkpoint (when the grid selects checkpoints)
-> test evaluations of the last and the best-on-validation checkpoint, nominally and under each perturbation.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from lerobot_obsbench.bench.cost import (
    DEVICE_KINDS,
    PlanCost,
    device_kind,
    eval_seconds,
    planned_steps,
    train_seconds,
    unmeasured,
)
from lerobot_obsbench.bench.engines import make_engine
from lerobot_obsbench.bench.grid import Grid
from lerobot_obsbench.bench.jobs import DemoJob, EvalJob, Job, TrainJob, WorkQueue
from lerobot_obsbench.bench.machine import CapabilityError, default_capability, native_capability, pin_environment
from lerobot_obsbench.bench.results import RESULTS_FILE, append_result, by_kind, read_results
from lerobot_obsbench.bench.specs import BUDGET_UNITS, EvalSpec, GridError, RunSpec
from lerobot_obsbench.bench.units import demo_dir, demos_recorded, evaluation_progress, run_dir, training_progress
from lerobot_obsbench.envs.base_task import TASKS, asset_help, missing_assets
from lerobot_obsbench.envs.catalog import task_record
from lerobot_obsbench.envs.vector import default_batch_size
from lerobot_obsbench.errors import UsageError
from lerobot_obsbench.locks import exclusive_output
from lerobot_obsbench.rlbench.paper_tasks import grid_task_name
from lerobot_obsbench.rlbench.preflight import data_problems, simulator_problem


def eval_batch_size(grid: Grid, device: str, cores: int | None = None) -> int:
    """Episodes a ManiSkill evaluation runs in lockstep: the grid's `eval_batch_size`, else the device's default,
    on CPU at most the `cores` a unit of work has to itself when it shares the machine (None: it does not)."""
    if grid.eval_batch_size:
        return grid.eval_batch_size
    default = default_batch_size(device)
    return min(default, cores) if cores and device_kind(device) == "cpu" else default


@dataclass
class Work:
    """What a grid still has to do."""

    runs: list[RunSpec]
    trained: dict[str, dict]  # run_id -> train record
    evaluated: dict[str, dict]  # eval_id -> eval record
    to_train: list[RunSpec] = field(default_factory=list)
    demos: dict[str, tuple[RunSpec, int]] = field(default_factory=dict)  # demo_key -> (a run, most demos)
    # run_id -> the checkpoint a trained run's evaluations still need and that is gone: trained again
    gone: dict[str, str] = field(default_factory=dict)


def load_work(grid: Grid, out: Path) -> Work:
    """What `grid` still has to do in `out`, from the records there (and, for a grid with `checkpoints_from`,
    the training records it copies in)."""
    results = out / RESULTS_FILE
    records = read_results(results)
    runs = grid.expand()
    if grid.checkpoints_from:
        records += copy_trained_runs(grid, runs, records, results)
    trained = {r["run_id"]: r for r in by_kind(records, "train")}
    work = Work(runs, trained, {r["eval_id"]: r for r in by_kind(records, "eval")})
    for run in runs:
        missing = checkpoint_gone(grid, run, work)
        if missing is not None:
            work.gone[run.run_id] = missing
    work.to_train = [r for r in runs if r.run_id not in trained or r.run_id in work.gone]
    for run in work.to_train:
        _, most = work.demos.get(run.demo_key, (run, 0))
        work.demos[run.demo_key] = (run, max(most, run.demos))
    # the held-out demonstrations follow the most any run of the dataset trains on
    work.demos = {key: (run, most + grid.held_out_demos) for key, (run, most) in work.demos.items()}
    return work


def checkpoint_gone(grid: Grid, run: RunSpec, work: Work) -> str | None:
    """The checkpoint (a path) that a trained run's evaluations still to do need and that is no longer on disk
    (its output folder deleted, or its results file copied from elsewhere), or None: such a run is trained again,
    into the same run id, to evaluate it (a grid that evaluates another grid's checkpoints trains nothing: its
    evaluations refuse the missing checkpoint instead)."""
    train = work.trained.get(run.run_id)
    if train is None or grid.checkpoints_from:
        return None
    to_do = [s for s in grid.evaluations(run) if s.eval_id not in work.evaluated]
    wanted = {
        str(train["train_steps"]) if s.checkpoint in ("last", "best") else s.checkpoint.removeprefix("step:")
        for s in to_do
    }
    paths = [train["checkpoints"].get(step) for step in sorted(wanted)]
    return next((p for p in paths if p is not None and not Path(p, "model.safetensors").is_file()), None)


def copy_trained_runs(grid: Grid, runs: list[RunSpec], records: list[dict], results: Path) -> list[dict]:
    """Append to `results` the train records of `runs` not yet trained here, and their validation evaluations,
    from the grid `grid.checkpoints_from` names; returns the copies. Raises GridError if that grid lacks a run."""
    trained = {r["run_id"] for r in by_kind(records, "train")}
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
    copies = [
        {**record, "trained_in": str(source.parent)}
        for record in [
            *(theirs[i] for i in sorted(wanted)),
            *(r for r in by_kind(source_records, "eval") if r["run_id"] in wanted and r["split"] == "validation"),
        ]
    ]
    for record in copies:
        append_result(results, record)
    return copies


def missing_curve(grid: Grid, work: Work) -> dict[str, list[int]]:
    """run id -> the `eval_checkpoints` steps a trained run kept no checkpoint of (it was trained before the grid
    listed them): those points of its curve cannot be evaluated without training it again."""
    missing = {}
    for run in work.runs:
        train = work.trained.get(run.run_id)
        steps = [s for s in grid.curve(run) if train is not None and str(s) not in train["checkpoints"]]
        if steps:
            missing[run.run_id] = steps
    return missing


def print_plan(grid: Grid, work: Work, out: Path, device: str, echo=print, workers: int = 1) -> None:
    """What `grid` still has to do in `out`, run by run, and its rough cost (planning on `device` with `workers`
    local workers)."""
    missing = missing_curve(grid, work)
    done_evals = sum(s.eval_id in work.evaluated for r in work.runs for s in grid.evaluations(r))
    all_evals = sum(len(grid.evaluations(r)) for r in work.runs) - sum(len(steps) for steps in missing.values())
    echo(
        f"grid {grid.name}: {len(work.runs)} runs, {len(work.runs) - len(work.to_train)} already trained, "
        f"{len(work.to_train)} to train; {done_evals} of {all_evals} test evaluations done; results -> "
        f"{out / RESULTS_FILE}"
    )
    for run_id, path in work.gone.items():
        echo(
            f"  run {run_id} has evaluations to do and its checkpoint {path} is gone: it is trained again (the same "
            "run id; under the same CPU kernels and library builds, the same weights)"
        )
    for run_id, steps in missing.items():
        echo(
            f"  run {run_id} kept no checkpoint at steps {steps} of eval_checkpoints (it was trained before they "
            f"were listed): its learning curve lacks them; delete {run_dir(out, run_id)} to train it again"
        )
    if grid.checkpoints_from:
        echo(f"  evaluates the checkpoints trained by {grid.checkpoints_from} (trains nothing)")
    cost = PlanCost()
    to_record = [
        (run, episodes)
        for run, episodes in work.demos.values()
        if run.rlbench_task is None and not demos_recorded(demo_dir(out, run, episodes))
    ]
    for run, episodes in to_record:
        cost.add_demos(grid, run, episodes)
    if to_record:
        echo(
            f"  demonstrations to record: {sum(n for _, n in to_record)} episodes of "
            + ", ".join(f"{run.task} ({n})" for run, n in to_record)
        )
    # the cost line's machines: one worker (the whole machine) on a 2-core CPU, or one GPU
    batch_sizes = {kind: eval_batch_size(grid, kind) for kind in DEVICE_KINDS}
    for run in work.runs:
        steps, exact = planned_steps(run, out)
        train = run.run_id not in work.trained
        skipped = {f"step:{step}" for step in missing.get(run.run_id, [])}
        evals = [s for s in grid.evaluations(run) if s.eval_id not in work.evaluated and s.checkpoint not in skipped]
        if grid.validation_episodes:  # one per checkpoint, for the estimate
            evals += grid.validations(run, list(range(grid.per_policy("checkpoints", run.policy))))
        if not train and not evals:
            continue
        echo(plan_line(run, steps, exact, train, evals))
        cost.add_run(run, steps, train, evals, batch_sizes)
    echo(
        f"  total to do: {cost.steps} optimizer steps, {cost.samples} training samples, "
        f"{cost.episodes} evaluation episodes. Budget units: "
        + "; ".join(f"{u} = {what}" for u, what in BUDGET_UNITS.items() if any(r.budget_unit == u for r in work.runs))
    )
    for line in cost.lines(device, workers):
        echo(line)
    defaults = unmeasured(work.runs)
    if defaults:
        echo(
            "  priced at the defaults, not measured: "
            + "; ".join(f"{task} ({', '.join(names)})" for task, names in defaults.items())
            + " (`python -m benchmarks.bench_grid_cost` and `python -m benchmarks.bench_experts` measure them)"
        )
    if len(set(grid.seeds)) < 2:
        echo(
            f"  note: one training seed ({grid.seeds[0]}): every comparison rests on it, so its intervals cover "
            "evaluation episodes only and the report marks a method above blind with △, never ▲; list at least "
            "3 `seeds` to measure training variance"
        )


def plan_line(run: RunSpec, steps: int, exact: bool, train: bool, evals: list[EvalSpec]) -> str:
    """One run's line of the plan: what it trains, its budget in steps (`exact`: not estimated), whether it is
    still to `train`, and the evaluations it still has to do."""
    approx = "" if exact else "~"
    return (
        f"  {run.run_id}  {run.task:20s} {run.method:34s} demos {run.demos:<4d} seed {run.seed:<4d} "
        f"lr {run.lr:<7g} batch {run.batch_size:<3d} {run.budget:g} {run.budget_unit} = {approx}{steps} steps, "
        f"{approx}{steps * run.batch_size} samples{'' if train else ' (trained)'}; "
        f"{len(evals)} evaluations, {sum(s.episodes for s in evals)} episodes"
    )


class Driver:
    """Submits units as their inputs become ready, records their results, prints progress."""

    def __init__(
        self,
        grid: Grid,
        work: Work,
        out: Path,
        engine,
        *,
        device: str,
        loader_workers: int,
        threads: int | None,
        echo,
        eval_cores: int | None = None,
    ):
        self.grid, self.work, self.out, self.engine = grid, work, out, engine
        self.device, self.loader_workers, self.threads, self.echo = device, loader_workers, threads, echo
        self.results = out / RESULTS_FILE
        self.pending: dict[object, Job] = {}  # engine handle -> job, running (or in the engine's own queue)
        self.queue = WorkQueue()  # ready units not yet given to the engine
        self.copies: dict[str, list[dict]] = {}  # eval_id of a "last" eval -> "best" records waiting to copy it
        self.failures = 0
        self.started = time.time()
        self.rates: dict[str, tuple[float, int]] = {}  # run_id -> (time, step) at the previous progress line
        # where an RLBench grid's units find PerAct's data and the CLIP weights (not part of any run's identity)
        self.rlbench = {"data": grid.rlbench_data, "clip_weights": grid.clip_weights} if grid.rlbench_data else None
        self.eval_batch_size = eval_batch_size(grid, device, eval_cores)

    # ---- scheduling ----------------------------------------------------------------------------------------

    def submit(self, job: Job) -> None:
        self.queue.push(job)
        self.dispatch()

    def dispatch(self) -> None:
        """Hand the engine the queue's first units while it has free slots (all of them: an engine without)."""
        slots = getattr(self.engine, "slots", None)
        while self.queue and (slots is None or len(self.pending) < slots):
            job = self.queue.pop()
            self.pending[self.engine.submit(job)] = job

    def start(self) -> None:
        for key, (run, episodes) in self.work.demos.items():
            self.submit(
                DemoJob(
                    key=key,
                    task=run.task,
                    episodes=episodes,
                    path=str(demo_dir(self.out, run, episodes)),
                    image_size=run.image_size,
                    cameras=run.cameras,
                    rlbench=self.rlbench,
                )
            )
        for run in self.work.runs:
            if run.run_id in self.work.trained and run.run_id not in self.work.gone:
                self.schedule_evaluations(run)

    def train(self, run: RunSpec, dataset: str) -> None:
        self.submit(
            TrainJob(
                run=run,
                dataset=dataset,
                out=str(self.out),
                device=self.device,
                checkpoints=self.grid.per_policy("checkpoints", run.policy),
                held_out=self.grid.held_out_demos,
                loader_workers=self.loader_workers,
                threads=self.threads,
                curve=self.grid.curve(run),
                retrain=run.run_id in self.work.gone,
            )
        )

    def evaluate(self, run: RunSpec, spec: EvalSpec, step: int) -> None:
        self.submit(
            EvalJob(
                run=run,
                spec=spec,
                checkpoint=self.work.trained[run.run_id]["checkpoints"][str(step)],
                step=step,
                out=str(self.out),
                device=self.device,
                threads=self.threads,
                batch_size=self.eval_batch_size,
                rlbench=self.rlbench,
            )
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
            if spec.checkpoint.startswith("step:"):  # a learning curve's point (missing ones: `missing_curve`)
                step = int(spec.checkpoint.removeprefix("step:"))
                if str(step) in train["checkpoints"]:
                    self.evaluate(run, spec, step)
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

    def finished(self, job: Job, outcome) -> None:
        match job:
            case DemoJob():
                self.echo(f"{job.describe()}: {job.episodes} episodes of {job.task} in {outcome['wall_s']:.0f} s")
                for run in self.work.to_train:
                    if run.demo_key == job.key:
                        self.train(run, job.path)
            case TrainJob(run=run):
                self.record(outcome)
                self.echo(
                    f"trained {run.run_id} {run.method} on {run.task}: {outcome['train_steps']} steps in "
                    f"{outcome['timings']['train_s']:.0f} s"
                    + (f" (resumed at step {outcome['resumed_from']})" if outcome["resumed_from"] else "")
                )
                self.schedule_evaluations(run)
            case EvalJob(run=run, spec=spec):
                self.record(outcome)
                lo, hi = outcome["ci95"]
                self.echo(
                    f"evaluated {run.run_id} {run.method} on {run.task} [{spec.split}, {spec.checkpoint} = step "
                    f"{outcome['checkpoint_step']}, {spec.perturbation}]: {outcome['successes']}/"
                    f"{outcome['episodes']} = {outcome['success_rate']:.0%} (95% CI {lo:.0%}-{hi:.0%})"
                )
                if spec.split == "validation" and self.best_step(run) is not None:
                    self.schedule_tests(run)
                if spec.eval_id in self.copies:
                    self.copy_records(spec.eval_id)

    def failed(self, job: Job, err: Exception) -> None:
        self.failures += 1
        self.echo(f"FAILED {job.describe()}: {type(err).__name__}: {err}")

    def loop(self, every: float) -> None:
        last_progress = time.time()
        while self.pending:
            for handle in self.engine.wait(list(self.pending), timeout=min(every, 5.0)):
                job = self.pending.pop(handle)
                try:
                    outcome = self.engine.result(handle)
                except Exception as err:
                    self.failed(job, err)
                    continue
                self.finished(job, outcome)
            self.dispatch()
            if time.time() - last_progress >= every and self.pending:
                self.progress()
                last_progress = time.time()

    # ---- progress -------------------------------------------------------------------------------------------

    def progress(self) -> None:
        lines, remaining = [], 0.0
        for job in [*self.pending.values(), *self.queue]:
            match job:
                case TrainJob():
                    left, line = self.training_left(job)
                case EvalJob():
                    left, line = self.evaluation_left(job)
                case _:  # demonstrations: not counted
                    continue
            remaining += left
            if line:
                lines.append(line)
        workers = getattr(self.engine, "workers", 1)
        elapsed = (time.time() - self.started) / 60
        self.echo(
            f"[{elapsed:.1f} min] {len(self.pending) + len(self.queue)} units queued or running; grid ETA ~"
            f"{math.ceil(remaining / max(workers, 1) / 60)} min (later units not counted until ready)"
        )
        for line in lines:
            self.echo(line)

    def training_left(self, job: TrainJob) -> tuple[float, str | None]:
        """(seconds left, progress line or None before it starts) of a queued or running training: from the
        run's own rate once it has reported two steps, else from the cost model."""
        run = job.run
        state = training_progress(self.out, run.run_id)
        steps, _ = planned_steps(run, self.out)
        if state is None or state["started"] < self.started:
            return train_seconds(run, steps, self.device), None
        now, (then, before) = time.time(), self.rates.get(run.run_id, (self.started, state["step"]))
        rate = (state["step"] - before) / max(now - then, 1e-6) if state["step"] > before else None
        self.rates[run.run_id] = (now, state["step"])
        left = (state["steps"] - state["step"]) / rate if rate else train_seconds(run, steps, self.device)
        loss = f" loss {state['loss']:.4f}" if state["loss"] is not None else ""
        speed = f", {rate:.2f} steps/s, ETA {left / 60:.1f} min" if rate else ""
        return left, (
            f"  training {run.run_id} {run.method} on {run.task}: step {state['step']}/{state['steps']}{loss}{speed}"
        )

    def evaluation_left(self, job: EvalJob) -> tuple[float, str | None]:
        """(seconds left, progress line or None before it starts) of a queued or running evaluation."""
        run, spec = job.run, job.spec
        state = evaluation_progress(self.out, run.run_id, spec.eval_id)
        left = eval_seconds(spec, run, self.device, self.eval_batch_size) * (
            1 - (state or {"done": 0})["done"] / spec.episodes
        )
        if not state:
            return left, None
        return left, (
            f"  evaluating {run.run_id} {run.method} [{spec.split}, {spec.checkpoint}, {spec.perturbation}]: "
            f"episode {state['done']}/{state['episodes']}, {state['successes']} successes"
        )


def rlbench_problems(grid: Grid) -> list[str]:
    """What an RLBench grid lacks on this machine: its tasks' data folders and their episodes, the CLIP weights, and
    last the simulator stack."""
    # the episodes each split must hold, and the grid field that asks for them
    needed = {
        "test": (grid.eval_episodes, "the grid's eval_episodes"),
        "val": (grid.validation_episodes, "the grid's validation_episodes"),
    }
    if not grid.checkpoints_from:
        needed["train"] = (max(grid.demos), "the grid's demos")
    problems = data_problems(grid.rlbench_data, [grid_task_name(t) for t in grid.tasks], needed, grid.clip_weights)
    simulator = simulator_problem()
    return problems + ([simulator] if simulator else [])


def check_tasks(grid: Grid, dry_run: bool = False, echo=print) -> None:
    """Refuse, before anything runs, a task the grid cannot record demonstrations of (no scripted expert) or
    cannot simulate here (its ManiSkill assets missing; for RLBench: its data, CLIP weights or the simulator),
    naming every problem and its fix. A dry run only notes what RLBench lacks here (a plan needs none of it)."""
    if grid.rlbench_data:
        problems = rlbench_problems(grid)
        if problems and dry_run:
            echo(f"note: this machine cannot run {grid.name} as it is: " + ". Also: ".join(problems))
        elif problems:
            raise GridError(f"{grid.name}: " + ". Also: ".join(problems))
        return
    for name in grid.tasks:
        spec = task_record(name)
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


def kernel_pins(capability: str) -> dict[str, str]:
    """The environment pinning `capability`'s CPU kernels (`machine.pin_environment`), refused in one line where
    this machine cannot run them."""
    try:
        return pin_environment(capability)
    except CapabilityError as err:
        raise UsageError(str(err)) from None


def pin_line(pins: dict[str, str]) -> str:
    if not pins:
        return f"CPU kernels: this machine's own ({native_capability()}), not pinned: the records name them"
    return (
        f"CPU kernels pinned to {pins['ATEN_CPU_CAPABILITY']} ({', '.join(f'{k}={v}' for k, v in pins.items())}; "
        f"this machine's best: {native_capability()}), so that the runs' numbers do not depend on the processor"
    )


@contextlib.contextmanager
def environment(variables: dict[str, str]):
    """`variables` set in this process's environment (inherited by the processes it starts) while inside."""
    before = {name: os.environ.get(name) for name in variables}
    os.environ.update(variables)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


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
    cpu_capability: str | None = None,
) -> int:
    """Run every unit of `grid` that has no record yet; returns the number of failed units.

    `threads`: CPU threads per unit (None: the machine's cores shared by the local workers; Ray: 1 per CPU
    the unit asks for). `loader_workers`: LeRobot's DataLoader workers per training run (0 is fastest on a
    2-core CPU, where a worker competes with training). `cpu_capability`: the CPU kernels every unit runs with
    (`machine.py`; None: the default pin)."""
    out = Path(out)
    check_tasks(grid, dry_run, echo)
    pins = kernel_pins(cpu_capability or default_capability())
    echo(pin_line(pins))
    if dry_run:
        print_plan(grid, load_work(grid, out), out, device, echo=echo, workers=workers)
        return 0
    # lockstep envs may use the cores a unit has to itself: the machine's with one local worker (unless --threads
    # says fewer), its share with several, one CPU under Ray (what a unit asks for there)
    whole_machine = engine == "local" and workers <= 1 and threads is None
    if threads is None and engine == "local":
        threads = max(1, (os.cpu_count() or 1) // max(workers, 1))
    eval_cores = None if whole_machine else (threads or 1)
    # a second runner on `out` is refused; the units (pool workers, lerobot-train) inherit the kernel pins
    with exclusive_output(out, f"obsbench run {grid.name}"), environment(pins):
        work = load_work(grid, out)
        print_plan(grid, work, out, device, echo=echo, workers=workers)
        driver = Driver(
            grid,
            work,
            out,
            make_engine(engine, workers, address, env=pins),
            device=device,
            loader_workers=loader_workers,
            threads=threads,
            echo=echo,
            eval_cores=eval_cores,
        )
        try:
            driver.start()
            if not driver.pending:
                echo("nothing to do: every run is trained and every evaluation it can make recorded")
            driver.loop(progress_every)
        except KeyboardInterrupt:
            driver.engine.shutdown(abort=True)
            raise
        finally:
            driver.engine.shutdown()
    return driver.failures
