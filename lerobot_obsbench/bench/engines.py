"""Where a grid's units of work run: a local process pool (default) or an existing Ray cluster. Both expose the
same three calls to the driver — submit a job (`jobs.py`: a unit of work and the resources it asks for), wait
for some to finish, fetch a result — and neither schedules anything itself: the pool and Ray do.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import signal
import threading

from tqdm import tqdm

from lerobot_obsbench.bench.jobs import Job, run_job
from lerobot_obsbench.bench.units import die_with_parent
from lerobot_obsbench.errors import MissingDependencyError, UsageError

ENGINES = ("local", "ray")
RAY_HELP = "the Ray engine needs Ray: pip install 'lerobot_policy_obsbench[ray]' (or pip install ray)"


class LocalEngine:
    """`workers` spawned worker processes on this machine (each runs one unit at a time)."""

    name = "local"

    def __init__(self, workers: int = 1):
        self.workers = max(1, workers)
        # units handed to the pool at once: one per worker, so the driver chooses what runs next
        self.slots = self.workers
        self.pool = cf.ProcessPoolExecutor(
            self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=_worker_start
        )

    def submit(self, job: Job):
        return self.pool.submit(run_job, job)

    def wait(self, handles: list, timeout: float) -> list:
        done, _ = cf.wait(handles, timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return list(done)

    def result(self, handle):
        return handle.result()

    def shutdown(self, abort: bool = False) -> None:
        """Stop taking work; `abort` (Ctrl-C): also kill the workers and with them their units' subprocesses,
        instead of letting the interpreter's exit wait for the running units to finish."""
        if abort:
            for process in list(self.pool._processes.values()):  # the executor has no public kill
                process.kill()
        self.pool.shutdown(wait=False, cancel_futures=True)


def _worker_start() -> None:
    """A pool worker dies with the driver and leaves Ctrl-C to it (the driver stops the grid in one line; a
    worker interrupted too would print its own traceback). Its progress bars share a thread lock instead of
    tqdm's default multiprocessing one: a worker killed on Ctrl-C cannot unlink that semaphore, and the
    resource tracker would print a leaked-semaphore warning under the driver's one line."""
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    tqdm.set_lock(threading.RLock())


class RayEngine:
    """Ray tasks on the cluster at `address` ("auto": the one this machine belongs to; None: a new local Ray
    instance). Each unit asks for its CPUs and GPUs; Ray places it. The output directory must be visible to
    every node (a shared filesystem, as on Slurm clusters)."""

    name = "ray"
    slots = None  # every ready unit goes to the cluster, which places each by the resources it asks for

    def __init__(self, address: str | None = None, env: dict[str, str] | None = None, **init_kwargs):
        try:
            import ray
        except ImportError as err:
            raise MissingDependencyError(RAY_HELP) from err
        self.ray = ray
        if not ray.is_initialized():
            if address is None:  # a new instance on this machine, reachable on loopback only
                init_kwargs = {"_node_ip_address": "127.0.0.1", "include_dashboard": False, **init_kwargs}
            ray.init(address=address, log_to_driver=False, **init_kwargs)
        self._run_job = ray.remote(run_job)
        # each unit's worker process starts with these variables (the kernel pins), as the local pool's inherit them
        self.runtime_env = {"env_vars": dict(env)} if env else None

    def submit(self, job: Job):
        options = {"num_cpus": job.cpus, "num_gpus": job.gpus, "max_retries": 0}
        if self.runtime_env:
            options["runtime_env"] = self.runtime_env
        return self._run_job.options(**options).remote(job)

    def wait(self, handles: list, timeout: float) -> list:
        done, _ = self.ray.wait(handles, num_returns=1, timeout=timeout)
        if done:  # everything else that is ready too
            more, _ = self.ray.wait(handles, num_returns=len(handles), timeout=0)
            done = list({id(h): h for h in [*done, *more]}.values())
        return done

    def result(self, handle):
        return self.ray.get(handle)

    def shutdown(self, abort: bool = False) -> None:
        pass  # the cluster outlives the driver; a local instance stops with this process


def make_engine(name: str, workers: int = 1, address: str | None = None, env: dict[str, str] | None = None):
    """`env`: environment variables every unit runs with (the local pool's workers inherit the driver's)."""
    if name == "local":
        return LocalEngine(workers)
    if name == "ray":
        return RayEngine(address, env=env)
    raise UsageError(f"Unknown engine {name!r}; choose one of {', '.join(ENGINES)}")
