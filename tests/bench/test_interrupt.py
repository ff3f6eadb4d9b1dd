"""Ctrl-C in the long commands: one line saying what was kept and how to go on, exit code 130, no traceback,
nothing half-written; the same command then finishes the work (that a resumed run is the uninterrupted one:
test_bench_one_run.py)."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest

from lerobot_obsbench.bench.diagnostics import LOSS_PATTERN
from lerobot_obsbench.bench.results import by_kind
from tests.support.grid_cli import finish, obsbench, one_run_grid, quiet, wait_for

pytestmark = pytest.mark.slow


def interrupt(proc) -> str:
    """SIGINT to the command alone (what Ctrl-C sends it), then its output."""
    proc.send_signal(signal.SIGINT)
    log, _ = proc.communicate(timeout=120)
    return log


def test_ctrl_c_during_a_grid_keeps_its_results_and_the_same_command_finishes_it(tmp_path):
    # the small keypoint encoder's steps, not resnet18's: a run long enough to be interrupted, cheap to finish
    grid = one_run_grid(tmp_path / "one.yaml", ("steps: 3", "steps: 400"), ("perturbations: [light:0.05]\n", ""))
    out = tmp_path / "out"
    proc = obsbench("run", str(grid), "--out", str(out), "--threads", "1", start_new_session=True)
    # demos recorded and training under way: its first loss line is logged (of 400 steps)
    wait_for(lambda: any(LOSS_PATTERN.search(log.read_text()) for log in out.glob("runs/*/train.log")), proc)
    log = interrupt(proc)
    assert proc.returncode == 130, log
    assert "Traceback" not in log
    # the last line: no warning from multiprocessing's resource tracker about the killed workers after it
    assert log.rstrip().splitlines()[-1].startswith("obsbench run: interrupted; every finished unit is kept")
    assert by_kind(quiet(out / "results.jsonl"), "train") == []  # stopped mid-training: nothing half-recorded
    log = finish("run", str(grid), "--out", str(out), "--threads", "1")
    assert "1 runs, 0 already trained, 1 to train" in log
    records = quiet(out / "results.jsonl")
    assert len(by_kind(records, "train")) == 1 and len(by_kind(records, "eval")) == 1


def test_ctrl_c_during_demos_keeps_the_recorded_episodes(tmp_path):
    # interrupted once the first episode is on disk: seven more are a window of seconds for the signal to land in
    args = ["demos", "--task", "PushCube-v1", "--episodes", "8", "--image-size", "32"]
    out = tmp_path / "out"
    proc = obsbench(*args, "--out", str(out), start_new_session=True)
    wait_for(lambda: any((out / ".episodes").glob("seed_*.npz")), proc)
    log = interrupt(proc)
    assert proc.returncode == 130, log
    assert "Traceback" not in log
    assert log.rstrip().splitlines()[-1].startswith("obsbench demos: interrupted; the recorded episodes are kept")
    assert not (out / "obsbench_demos.json").exists()
    kept = sorted(p.name for p in (out / ".episodes").glob("seed_*.npz"))
    assert kept and not list((out / ".episodes").glob("*.tmp"))  # the episode in flight is never left half-written
    finish(*args, "--out", str(out))
    seeds = json.loads((out / "obsbench_demos.json").read_text())["seeds"]
    assert len(seeds) == 8 and {f"seed_{seed}.npz" for seed in seeds} >= set(kept)  # the kept ones among them
    info = json.loads(Path(out, "meta", "info.json").read_text())
    assert info["total_episodes"] == 8 and info["total_frames"] > 8
