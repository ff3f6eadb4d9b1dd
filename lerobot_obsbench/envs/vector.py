"""Several ObsBench envs stepped together, for lockstep evaluation (`envs.evaluate`).

Three backends behind one slot interface: `reset(seeds)` gives the batch of first observations (slot i: seed i);
`step(slots, actions)` steps the listed slots with their rows of the batched `actions` and gives the observation
batch of every slot (a slot not stepped keeps its last) and each stepped slot's (reward, terminated, truncated,
info); `render(slots)` their viewer images.

- `SubprocessEnvs`: ManiSkill's CPU simulation runs one env per process, so each env lives in a worker process of
  its own: the parent sends every slot's command first and then collects the answers, so the slots simulate and
  render at the same time, on as many cores as there are.
- `InProcessEnvs`: one env in this process (batch size 1: sequential evaluation, exactly as before lockstep).
- `BatchedEnvs`: one env object that simulates all slots in one process (`num_envs`: ManiSkill's GPU
  simulation and rendering), whose observations stay tensors on its device, from the renderer to the policy.

`SubprocessEnvs` and `InProcessEnvs` also run any other method of their envs: `call(slot, method, *args)` starts
it and `result(slot)` waits for what it returned (`obsbench demos --workers` records whole expert episodes so).

Workers are started with `forkserver` (as LeRobot's own async vector envs are): a fork of a process holding
torch's threads or a Vulkan device is not safe. Envs that render on a CUDA device get `spawn`, which CUDA needs.
Each worker runs torch on one thread; an error in a worker is raised again in the parent with the worker's
message.
"""

from __future__ import annotations

import multiprocessing as mp
import traceback
from collections.abc import Callable, Sequence

import numpy as np

from lerobot_obsbench.envs.base_task import to_numpy
from lerobot_obsbench.errors import ConfigError, ObsBenchError

# Episodes advanced together by default, per device kind: the measured N with the least time per episode
# (docs/performance.md#the-cost-model; on a GPU host, starting one worker process per env costs more than it saves
# on the grids' evaluations).
DEFAULT_BATCH_SIZE = {"cpu": 3, "cuda": 1}


def default_batch_size(device: str) -> int:
    return DEFAULT_BATCH_SIZE["cuda" if device.startswith("cuda") else "cpu"]


class EnvWorkerError(ObsBenchError, RuntimeError):
    """An env worker process failed or died."""


def _worker(connection, make_env: Callable, env_kwargs: dict) -> None:
    """One env in its own process: answers each (method, args, kwargs) with ("ok", env.method(*args, **kwargs)),
    or ("raise", the exception, its traceback) and stops; ("close", ...) ends it."""
    import pickle

    import torch

    torch.set_num_threads(1)
    env = None
    try:
        env = make_env(**env_kwargs)
        connection.send(("ok", None))
        while True:
            method, args, kwargs = connection.recv()
            if method == "close":
                break
            connection.send(("ok", getattr(env, method)(*args, **kwargs)))
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


def stacked(observations: list):
    """Per-slot observations -> one batch (each leaf stacked on a new first axis)."""
    first = observations[0]
    if isinstance(first, dict):
        return {k: stacked([o[k] for o in observations]) for k in first}
    return np.stack(observations)


def _action_rows(actions, slots: Sequence[int]) -> list[np.ndarray]:
    rows = to_numpy(actions)
    return [rows[slot] for slot in slots]


class InProcessEnvs:
    """One env in this process, behind the slot interface."""

    def __init__(self, make_env: Callable, env_kwargs: dict):
        self.env = make_env(**env_kwargs)

    def reset(self, seeds: Sequence[int]) -> dict:
        (seed,) = seeds
        self.observations = [self.env.reset(seed=seed)[0]]
        return stacked(self.observations)

    def step(self, slots: Sequence[int], actions) -> tuple[dict, list[tuple]]:
        results = [self.env.step(action) for action in _action_rows(actions, slots)]
        for slot, (obs, *_) in zip(slots, results, strict=True):
            self.observations[slot] = obs
        return stacked(self.observations), [tuple(outcome) for _, *outcome in results]

    def render(self, slots: Sequence[int]) -> list[np.ndarray]:
        return [self.env.render() for _ in slots]

    def call(self, slot: int, method: str, *args, **kwargs) -> None:
        """Run `env.method(*args, **kwargs)` now (there is no other process to run it in); `result(slot)` gives
        what it returned."""
        self._result = getattr(self.env, method)(*args, **kwargs)

    def result(self, slot: int):
        return self._result

    def close(self) -> None:
        self.env.close()


class SubprocessEnvs:
    """`size` envs made by `make_env(**env_kwargs)` (a module-level function, so that workers can import it),
    one per worker process, addressed by slot."""

    def __init__(self, make_env: Callable, env_kwargs: dict, size: int):
        if str(env_kwargs.get("device") or "").startswith("cuda"):
            # envs rendering on a GPU: a fresh interpreter per worker, as CUDA requires (on the GPU machine a worker
            # forked from the fork server found CUDA initialised there and could not start)
            context = mp.get_context("spawn")
        else:
            context = mp.get_context("forkserver")
            # the fork server imports the env's module (the simulator) once; each worker forked from it then only
            # builds its env
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

    def call(self, slot: int, method: str, *args, **kwargs) -> None:
        """Start `env.method(*args, **kwargs)` in slot's worker, without waiting for it."""
        self.connections[slot].send((method, args, kwargs))

    def result(self, slot: int):
        """What slot's finished call returned (its error, raised here)."""
        return self._collect([slot])[0]

    def reset(self, seeds: Sequence[int]) -> dict:
        """Reset slots 0..len(seeds)-1 with `seeds`, all at once."""
        for slot, seed in enumerate(seeds):
            self.call(slot, "reset", seed=int(seed))
        self.observations = [obs for obs, _ in self._collect(range(len(seeds)))]
        return stacked(self.observations)

    def step(self, slots: Sequence[int], actions) -> tuple[dict, list[tuple]]:
        """Step `slots` with their rows of `actions`, all at once."""
        for slot, action in zip(slots, _action_rows(actions, slots), strict=True):
            self.call(slot, "step", action)
        results = self._collect(slots)
        for slot, (obs, *_) in zip(slots, results, strict=True):
            self.observations[slot] = obs
        return stacked(self.observations), [tuple(outcome) for _, *outcome in results]

    def render(self, slots: Sequence[int]) -> list[np.ndarray]:
        for slot in slots:
            self.call(slot, "render")
        return self._collect(slots)

    def close(self) -> None:
        for connection, process in zip(self.connections, self.processes, strict=False):
            if process.is_alive():
                try:
                    connection.send(("close", (), {}))
                except (BrokenPipeError, OSError):
                    pass
        for connection in self.connections:
            connection.close()
        for process in self.processes:
            process.join(timeout=30)
            if process.is_alive():
                process.kill()


def _first_rows(batch, rows: int):
    if isinstance(batch, dict):
        return {key: _first_rows(value, rows) for key, value in batch.items()}
    return batch[:rows]


class BatchedEnvs:
    """`size` envs simulated together by one env object, `make_env(**env_kwargs, num_envs=size)`, that has
    `reset_all(seeds)`, `step_all(actions)` and `render_all()` over all its envs (`ObsBenchEnv` on ManiSkill's GPU
    simulation). Its observations stay tensors on its device.

    All envs step together: a finished slot is stepped on with its row of the policy's actions, and what it returns
    is not read. A wave shorter than `size` (the last one) fills the spare envs with its last seed, not read either.
    """

    def __init__(self, make_env: Callable, env_kwargs: dict, size: int):
        self.env = make_env(**env_kwargs, num_envs=size)
        self.size, self.rows = size, size

    def reset(self, seeds: Sequence[int]) -> dict:
        if not 0 < len(seeds) <= self.size:
            raise ConfigError(f"a wave of {len(seeds)} seeds for {self.size} batched envs")
        self.rows = len(seeds)
        observations, _ = self.env.reset_all([*seeds, *[seeds[-1]] * (self.size - len(seeds))])
        return _first_rows(observations, self.rows)

    def step(self, slots: Sequence[int], actions) -> tuple[dict, list[tuple]]:
        import torch

        actions = torch.as_tensor(actions, device=self.env.device)
        if len(actions) < self.size:  # the spare envs of a short wave stand still
            actions = torch.cat([actions, actions.new_zeros(self.size - len(actions), *actions.shape[1:])])
        observations, reward, terminated, truncated, info = self.env.step_all(actions)
        reward, terminated, truncated = reward.tolist(), terminated.tolist(), truncated.tolist()
        info = {key: value.tolist() for key, value in info.items()}
        outcomes = [
            (reward[slot], terminated[slot], truncated[slot], {key: value[slot] for key, value in info.items()})
            for slot in slots
        ]
        return _first_rows(observations, self.rows), outcomes

    def render(self, slots: Sequence[int]) -> list[np.ndarray]:
        images = to_numpy(self.env.render_all())
        return [images[slot] for slot in slots]

    def close(self) -> None:
        self.env.close()


def make_envs(make_env: Callable, env_kwargs: dict, size: int, batched: bool = False):
    """`size` envs for lockstep evaluation: one in this process, one per worker process, or (`batched`) all in one
    env object that simulates them together."""
    if size < 1:
        raise ConfigError(f"the evaluation batch size must be >= 1; got {size}")
    if batched:
        return BatchedEnvs(make_env, env_kwargs, size)
    return InProcessEnvs(make_env, env_kwargs) if size == 1 else SubprocessEnvs(make_env, env_kwargs, size)
