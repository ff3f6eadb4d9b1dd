"""The jobs the grid's driver hands an engine: one frozen dataclass per unit of work (`units.py`), carrying every
input its unit needs. Jobs are picklable, so the local pool and Ray take the same ones: a worker runs
`run_job(job)` (the job's `execute`), and the engine reserves the job's `cpus` and `gpus` for it."""

from __future__ import annotations

import heapq
import itertools
import time
from collections.abc import Mapping
from dataclasses import dataclass

from lerobot_obsbench.bench.specs import EvalSpec, RunSpec
from lerobot_obsbench.bench.units import demos_unit, eval_unit, train_unit


def gpus_for(device: str) -> int:
    """GPUs a unit asks the engine for on `device`: one on CUDA (Ray then runs one unit per GPU), else none."""
    return 1 if device.startswith("cuda") else 0


@dataclass(frozen=True)
class DemoJob:
    """Recording the scripted demonstrations shared by every run of one dataset into `path` (resumable); for an
    RLBench task, importing them from PerAct's data (`rlbench`: its folder and the CLIP weights)."""

    key: str  # the `RunSpec.demo_key` of the runs that train on them
    task: str
    episodes: int
    path: str
    image_size: int
    cameras: tuple[str, ...]
    rlbench: Mapping[str, str | None] | None = None

    # `demos_unit` is given no device and records with one env process
    cpus = 1
    gpus = 0

    def execute(self) -> dict:
        """The recording's sidecar, with the unit's `wall_s`."""
        start = time.monotonic()
        info = demos_unit(
            task=self.task,
            episodes=self.episodes,
            path=self.path,
            image_size=self.image_size,
            cameras=list(self.cameras),
            rlbench=self.rlbench,
        )
        return {**info, "wall_s": round(time.monotonic() - start, 1)}

    def describe(self) -> str:
        return f"demonstrations {self.key}"


@dataclass(frozen=True)
class TrainJob:
    """Training one run with stock lerobot-train on its `dataset` (resuming from its last checkpoint after a kill),
    keeping `checkpoints` evenly spaced checkpoints and those of its learning curve's `curve` steps, then its
    diagnostics on the dataset's last `held_out` demonstrations."""

    run: RunSpec
    dataset: str
    out: str
    device: str
    checkpoints: int
    held_out: int
    loader_workers: int
    threads: int | None
    curve: tuple[int, ...] = ()
    retrain: bool = False  # its earlier training's checkpoints are gone: its record replaces that training's

    @property
    def cpus(self) -> int:
        return max(1, self.threads or 1)

    @property
    def gpus(self) -> int:
        return gpus_for(self.device)

    def execute(self) -> dict:
        return train_unit(
            run_config=self.run.config(),
            dataset=self.dataset,
            out_dir=self.out,
            device=self.device,
            checkpoints=self.checkpoints,
            held_out=self.held_out,
            loader_workers=self.loader_workers,
            threads=self.threads,
            curve=self.curve,
            retrain=self.retrain,
        )

    def describe(self) -> str:
        return f"training {self.run.run_id} {self.run.method} on {self.run.task}"


@dataclass(frozen=True)
class EvalJob:
    """Evaluating the checkpoint of `run` saved at `step` (its pretrained_model directory `checkpoint`) as
    `spec` says, `batch_size` ManiSkill episodes in lockstep; an RLBench run on PerAct's data (`rlbench`)."""

    run: RunSpec
    spec: EvalSpec
    checkpoint: str
    step: int
    out: str
    device: str
    threads: int | None
    batch_size: int
    rlbench: Mapping[str, str | None] | None = None

    @property
    def cpus(self) -> int:
        # each of the lockstep envs simulates and renders in a process of its own
        return max(1, self.threads or 1, self.batch_size)

    @property
    def gpus(self) -> int:
        return gpus_for(self.device)

    def execute(self) -> dict:
        return eval_unit(
            eval_config=self.spec.config(),
            run_config=self.run.config(),
            checkpoint=self.checkpoint,
            checkpoint_step=self.step,
            out_dir=self.out,
            device=self.device,
            threads=self.threads,
            rlbench=self.rlbench,
            batch_size=self.batch_size,
        )

    def describe(self) -> str:
        spec = self.spec
        return f"evaluation {spec.eval_id} of {self.run.run_id} ({spec.split}, {spec.checkpoint}, {spec.perturbation})"


Job = DemoJob | TrainJob | EvalJob


class WorkQueue:
    """Units ready to run, waiting for a worker: demonstrations first (trainings wait on them), then evaluations (a
    trained run's results are in before another run trains, so a grid stopped early has whole results for what it
    trained), then trainings; in the order they became ready within each kind."""

    ORDER = (DemoJob, EvalJob, TrainJob)

    def __init__(self):
        self._heap: list[tuple[int, int, Job]] = []
        self._arrivals = itertools.count()

    def push(self, job: Job) -> None:
        heapq.heappush(self._heap, (self.ORDER.index(type(job)), next(self._arrivals), job))

    def pop(self) -> Job:
        return heapq.heappop(self._heap)[2]

    def __len__(self) -> int:
        return len(self._heap)

    def __iter__(self):
        return (job for _, _, job in sorted(self._heap))


def run_job(job: Job) -> dict:
    """Run `job`'s unit in this process (an engine's worker); returns its result (a record, for train and eval)."""
    return job.execute()
