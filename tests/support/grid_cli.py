"""The `obsbench` command line as the end-to-end grid tests drive it: a tiny grid, the command started as a
process Ctrl-C and kills can reach, waits on what it writes, and its records compared without what differs between
two executions."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from lerobot_obsbench.bench.results import read_results

BIN = Path(sys.executable).parent
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
# a task, two spaces and two policies at the smallest sizes (rgb through the small keypoint encoder, not the tiny
# preset's resnet18); untrained policies rarely succeed, so every episode runs its whole length: 10 steps
GRID = """
name: tiny
tasks: [PushCube-v1]
obs_spaces: [rgb, pointcloud]
encoders: {rgb: [spatial_softmax]}
policies: [obs_act, obs_diffusion]
preset: tiny
seeds: [7]
learning_rates: [1.0e-3]
demos: [2]
batch_size: 4
steps: 3
image_size: 32
eval_episodes: 2
episode_length: 10
perturbations: [light:0.05]
policy_overrides: {workspace: [-1, 1, -1, 1, 0.005, 1]}
checkpoints: 1
"""
# fields that differ between two executions of the same unit of work
TIMING = ("timings", "wall_s", "finished_at", "checkpoint", "checkpoints", "versions", "trained_in")


def _ctrl_c_reaches_it() -> None:
    """A command started from a shell's background job inherits SIGINT ignored; Ctrl-C tests need it delivered."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def obsbench(*args, env: dict | None = None, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / "obsbench"), *args],
        env=env or ENV,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=_ctrl_c_reaches_it,
        **kwargs,
    )


def quiet(path: Path) -> list[dict]:
    return read_results(path, warn=lambda message: None)


def wait_for(condition, proc: subprocess.Popen, timeout: float = 900) -> None:
    deadline = time.time() + timeout
    while not condition():
        assert proc.poll() is None, proc.stdout.read()
        assert time.time() < deadline, "timed out"
        time.sleep(0.2)


def kill(proc: subprocess.Popen) -> None:
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def finish(*args: str, env: dict | None = None) -> str:
    proc = obsbench(*args, env=env)
    log, _ = proc.communicate(timeout=1800)
    assert proc.returncode == 0, log
    return log


def comparable(records: list[dict]) -> dict:
    """Records keyed by identity, without what differs between executions (timings, paths, versions)."""
    return {r.get("eval_id", r["run_id"]): {k: v for k, v in r.items() if k not in TIMING} for r in records}


def one_run_grid(path: Path, *changes: tuple[str, str]) -> Path:
    """GRID narrowed to one run (obs_act on rgb), with `changes` (old, new) applied to its text."""
    text = GRID.replace("obs_spaces: [rgb, pointcloud]", "obs_spaces: [rgb]").replace(
        "policies: [obs_act, obs_diffusion]", "policies: [obs_act]"
    )
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new)
    path.write_text(text)
    return path
