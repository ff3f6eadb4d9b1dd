"""Several ObsBench envs stepped together, for lockstep evaluation (`envs.evaluate`).

ManiSkill's CPU simulation runs one env per process, so `SubprocessEnvs` keeps each env in a worker process of
its own: the parent sends every slot's command first and then collects the answers, so the slots simulate and
render at the same time, on as many cores as there are. `InProcessEnvs` is the same interface over one env in
this process (batch size 1: sequential evaluation, exactly as before lockstep existed).

Workers are started with `forkserver` (as LeRobot's own async vector envs are): a fork of a process holding
torch's threads or a Vulkan device is not safe. Each worker runs torch on one thread; an error in a worker is
raised again in the parent with the worker's message.
"""

from __future__ import annotations

import multiprocessing as mp
import traceback
from collections.abc import Callable, Sequence

import numpy as np

from lerobot_obsbench.errors import ObsBenchError

# Episodes advanced together by default, per device kind: cpu measured by benchmarks/bench_eval.py (the N with
# the least total time over its two policies in benchmarks/results/eval_cpu.json, on this 2-core machine: 3, by
# 10%); cuda not measured (no GPU was available), so one episode at a time there.
DEFAULT_BATCH_SIZE = {"cpu": 3, "cuda": 1}


def default_batch_size(device: str) -> int:
    return DEFAULT_BATCH_SIZE["cuda" if device.startswith("cuda") else "cpu"]


class EnvWorkerError(ObsBenchError, RuntimeError):
    """An env worker process failed or died."""


def _worker(connection, make_env: Callable, env_kwargs: dict) -> None:
    """One env in its own process: answers ("reset", seed), ("step", action), ("render", None), ("close", None)
    with ("ok", result), or ("raise", the exception, its traceback) and stops."""
    import pickle

    import torch

    torch.set_num_threads(1)
    env = None
    try:
        env = make_env(**env_kwargs)
        connection.send(("ok", None))
        while True:
            command, argument = connection.recv()
            if command == "close":
                break
            if command == "reset":
                result = env.reset(seed=argument)
            elif command == "step":
                result = env.step(argument)
            else:
                result = env.render()
            connection.send(("ok", result))
    except (KeyboardInterrupt, EOFError):  # the parent was interrupted or went away
        pass
    except Exception as err:  # raised again in the parent: the same error as in one process, with this traceback
        text = traceback.format_exc()
        try:
            pickle.loads(pickle.dumps(err))  # an exception the parent could not rebuild travels as text only
        except Exception:
            err = None
        connection.send(("raise", err, text))
    finally:
        if env is not None:
            env.close()
        connection.close()


class InProcessEnvs:
    """One env in this process, behind the slot interface of `SubprocessEnvs`."""

    def __init__(self, make_env: Callable, env_kwargs: dict):
        self.env = make_env(**env_kwargs)

    def reset(self, seeds: Sequence[int]) -> list[tuple[dict, dict]]:
        (seed,) = seeds
        return [self.env.reset(seed=seed)]

    def step(self, slots: Sequence[int], actions: Sequence[np.ndarray]) -> list[tuple]:
        return [self.env.step(action) for action in actions]

    def render(self, slots: Sequence[int]) -> list[np.ndarray]:
        return [self.env.render() for _ in slots]

    def close(self) -> None:
        self.env.close()


class SubprocessEnvs:
    """`size` envs made by `make_env(**env_kwargs)` (a module-level function, so that workers can import it),
    one per worker process, addressed by slot."""

    def __init__(self, make_env: Callable, env_kwargs: dict, size: int):
        context = mp.get_context("forkserver")
        # the fork server imports the env's module (the simulator) once; each worker forked from it then only builds
        # its env
        context.set_forkserver_preload([make_env.__module__])
        self.connections, self.processes = [], []
        try:
            for _ in range(size):
                parent, child = context.Pipe()
                process = context.Process(target=_worker, args=(child, make_env, env_kwargs), daemon=True)
                self.connections.append(parent)
                process.start()
                self.processes.append(process)
                child.close()
            self._collect(range(size))  # each worker made its env (or failed to: its error is raised here)
        except BaseException:
            self.close()
            raise

    def _collect(self, slots: Sequence[int]) -> list:
        results = []
        for slot in slots:
            try:
                status, result, *text = self.connections[slot].recv()
            except EOFError:
                self.processes[slot].join(timeout=5)
                raise EnvWorkerError(f"env worker {slot} died (exit code {self.processes[slot].exitcode})") from None
            if status == "raise":
                cause = EnvWorkerError(f"in env worker {slot}:\n{text[0]}")
                if result is None:
                    raise cause
                raise result from cause
            results.append(result)
        return results

    def reset(self, seeds: Sequence[int]) -> list[tuple[dict, dict]]:
        """Reset slots 0..len(seeds)-1 with `seeds`, all at once."""
        for slot, seed in enumerate(seeds):
            self.connections[slot].send(("reset", int(seed)))
        return self._collect(range(len(seeds)))

    def step(self, slots: Sequence[int], actions: Sequence[np.ndarray]) -> list[tuple]:
        """Step `slots` with their actions, all at once; their (obs, reward, terminated, truncated, info)."""
        for slot, action in zip(slots, actions, strict=True):
            self.connections[slot].send(("step", action))
        return self._collect(slots)

    def render(self, slots: Sequence[int]) -> list[np.ndarray]:
        for slot in slots:
            self.connections[slot].send(("render", None))
        return self._collect(slots)

    def close(self) -> None:
        for connection, process in zip(self.connections, self.processes, strict=False):
            if process.is_alive():
                try:
                    connection.send(("close", None))
                except (BrokenPipeError, OSError):
                    pass
        for connection in self.connections:
            connection.close()
        for process in self.processes:
            process.join(timeout=30)
            if process.is_alive():
                process.kill()


def make_envs(make_env: Callable, env_kwargs: dict, size: int) -> InProcessEnvs | SubprocessEnvs:
    """`size` envs for lockstep evaluation: one in this process, or one per worker process."""
    if size < 1:
        raise ValueError(f"the evaluation batch size must be >= 1; got {size}")
    return InProcessEnvs(make_env, env_kwargs) if size == 1 else SubprocessEnvs(make_env, env_kwargs, size)
