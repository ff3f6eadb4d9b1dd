"""Keeping the control rate on a real robot: per-step timing with a warning when the policy cannot keep up, and
asynchronous chunk inference.

`StepTimer` measures each control step (observation -> action sent) and the policy's share of it; its summary
goes into every rollout record and, when the policy is slower than the rate, a warning names the measured
figure and the options (benchmarks/bench_latency.py measures them per space and encoder).

`AsyncChunks` computes the next action chunk in a background thread while the arm executes the current one
(the idea of LeRobot's newer asynchronous inference, in-process): each step takes the action of the newest
chunk that belongs to it (chunk computed from the observation of step t0 holds the actions of steps t0, t0+1,
...). A slow policy then acts on an older plan instead of stalling the arm; a step beyond the newest chunk's end
repeats its last action and is counted as starved.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import numpy as np

from lerobot_obsbench.errors import ObsBenchError

logger = logging.getLogger(__name__)


class AsyncInferenceError(ObsBenchError, RuntimeError):
    """The background thread computing action chunks failed; the message carries its error."""


class StepTimer:
    """Durations (seconds) of each control step and of the policy's part of it, for one episode."""

    def __init__(self, fps: int):
        self.fps = fps
        self.steps: list[float] = []
        self.policy: list[float] = []

    def record(self, step_s: float, policy_s: float) -> None:
        self.steps.append(step_s)
        self.policy.append(policy_s)

    def summary(self) -> dict:
        """Median / 95th percentile step and policy times (ms), and how many steps overran 1 / fps."""
        if not self.steps:
            return {}
        steps, policy = np.array(self.steps) * 1000, np.array(self.policy) * 1000
        budget = 1000 / self.fps
        return {
            "step_ms_median": round(float(np.median(steps)), 2),
            "step_ms_p95": round(float(np.percentile(steps, 95)), 2),
            "policy_ms_median": round(float(np.median(policy)), 2),
            "late_steps": int((steps > budget * 1.05).sum()),
            "achieved_hz": round(float(len(steps) / (steps.sum() / 1000)), 1),
        }

    def warning(self, asynchronous: bool) -> str | None:
        """A message when the median step overran the budget (None when the rate was kept)."""
        summary = self.summary()
        budget = 1000 / self.fps
        if not summary or summary["step_ms_median"] <= budget * 1.05:
            return None
        options = "fewer point tokens (--policy.num_tokens at training), a GPU (--device=cuda)"
        if not asynchronous:
            options += ", or --async_inference=true (ACT: the arm follows the last chunk while the next is computed)"
        return (
            f"the control loop ran at {summary['achieved_hz']} Hz, not {self.fps}: a step took "
            f"{summary['step_ms_median']:.1f} ms (median; the policy {summary['policy_ms_median']:.1f} ms) against "
            f"a budget of {budget:.1f} ms. Options: {options}."
        )


class AsyncChunks:
    """Action chunks computed off the control loop.

    `infer(observation) -> (n, action_dim)` array runs in a worker thread; `action(step, observation)` is called
    once per control step with that step's observation and returns the action to send: it hands the
    observation to the worker when the worker is idle, waits only for the episode's first chunk, and otherwise
    never blocks.
    """

    def __init__(self, infer: Callable[[object], np.ndarray]):
        self.infer = infer
        self.starved_steps = 0
        self.chunks_done = 0
        self._newest: tuple[int, np.ndarray] | None = None
        self._request: tuple[int, object] | None = None
        self._error: BaseException | None = None
        self._stop = False
        self._lock = threading.Condition()
        self._thread = threading.Thread(target=self._work, name="obsbench-async-inference", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while True:
            with self._lock:
                while self._request is None and not self._stop:
                    self._lock.wait()
                if self._stop:
                    return
                step, observation = self._request
            try:
                chunk = np.asarray(self.infer(observation))
            except BaseException as error:  # handed to the control loop, which raises it
                with self._lock:
                    self._error, self._request = error, None
                    self._lock.notify_all()
                return
            with self._lock:
                self._newest, self._request = (step, chunk), None
                self.chunks_done += 1
                self._lock.notify_all()

    def action(self, step: int, observation) -> np.ndarray:
        with self._lock:
            self._raise_worker_error()
            if self._request is None:
                self._request = (step, observation)
                self._lock.notify_all()
            while self._newest is None:  # the episode's first chunk: nothing to act on yet
                self._lock.wait()
                self._raise_worker_error()
            start, chunk = self._newest
        offset = step - start
        if offset >= len(chunk):
            self.starved_steps += 1
            return chunk[-1]
        return chunk[offset]

    def _raise_worker_error(self) -> None:
        if self._error is not None:
            raise AsyncInferenceError(f"asynchronous inference failed: {self._error!r}") from self._error

    def close(self) -> None:
        with self._lock:
            self._stop = True
            self._lock.notify_all()
        self._thread.join(timeout=60)
