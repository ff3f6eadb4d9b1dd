"""The grid driver's choice of what a free worker runs next: demonstrations, then evaluations, then trainings, each kind
in the order it became ready; the local engine is handed one unit per worker, Ray every ready unit."""

from __future__ import annotations

from pathlib import Path

from lerobot_obsbench.bench.engines import LocalEngine, RayEngine
from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.jobs import DemoJob, EvalJob, TrainJob, WorkQueue
from lerobot_obsbench.bench.runner import Driver


class RecordingEngine:
    """An engine that runs nothing: it keeps what it was handed, in order, with `slots` as a real one declares."""

    name = "recording"

    def __init__(self, slots):
        self.slots, self.handed = slots, []

    def submit(self, job):
        self.handed.append(job)
        return len(self.handed) - 1  # the handle


def _jobs():
    grid = load_grid("quick")
    runs = grid.expand()[:3]
    demo = DemoJob(key=runs[0].demo_key, task=runs[0].task, episodes=210, path="demos", image_size=64, cameras=())
    trains = [TrainJob(run, "demos", "out", "cpu", 2, 10, 0, 1) for run in runs]
    evals = [EvalJob(run, grid.evaluations(run)[0], "ckpt", 3000, "out", "cpu", 1, 1) for run in runs]
    return grid, demo, trains, evals


def test_the_queue_orders_demonstrations_evaluations_trainings_and_arrivals_within_each():
    _, demo, trains, evals = _jobs()
    queue = WorkQueue()
    for job in [trains[0], evals[1], trains[1], demo, evals[0]]:
        queue.push(job)
    assert list(queue) == [demo, evals[1], evals[0], trains[0], trains[1]]  # what it pops, without popping
    assert [queue.pop() for _ in range(len(queue))] == [demo, evals[1], evals[0], trains[0], trains[1]]
    assert not queue


def test_a_freed_worker_evaluates_a_trained_run_before_the_next_run_trains():
    grid, _, trains, evals = _jobs()
    engine = RecordingEngine(slots=1)
    runner = Driver(grid, None, Path("out"), engine, device="cpu", loader_workers=0, threads=1, echo=print)
    for job in trains:
        runner.submit(job)
    assert engine.handed == [trains[0]] and len(runner.queue) == 2  # one worker: one unit handed over
    runner.submit(evals[0])  # ready while the worker is busy: it waits too
    assert engine.handed == [trains[0]]
    runner.pending.pop(0)  # the first training finishes
    runner.dispatch()
    assert engine.handed == [trains[0], evals[0]]  # its evaluation goes first, not the next training
    runner.pending.pop(1)
    runner.dispatch()
    assert engine.handed == [trains[0], evals[0], trains[1]]


def test_an_engine_without_slots_gets_every_ready_unit():
    grid, _, trains, evals = _jobs()
    engine = RecordingEngine(slots=None)
    runner = Driver(grid, None, Path("out"), engine, device="cpu", loader_workers=0, threads=1, echo=print)
    for job in [*trains, *evals]:
        runner.submit(job)
    assert engine.handed == [*trains, *evals] and not runner.queue


def test_the_engines_declare_their_slots():
    engine = LocalEngine(workers=3)
    try:
        assert engine.slots == 3
    finally:
        engine.shutdown()
    assert RayEngine.slots is None
