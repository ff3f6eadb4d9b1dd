"""One writer per output directory: a second job is refused naming the first, a killed holder leaves no stale
lock, an unusable directory is one line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from lerobot_obsbench.cli import main
from lerobot_obsbench.locks import LOCK_NAME, OutputLockedError, exclusive_output

HOLD = "from lerobot_obsbench.locks import exclusive_output as x\nwith x({!r}, 'obsbench demos'):\n    input()\n"


def _holder(path):
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD.format(str(path))], stdin=subprocess.PIPE, text=True, cwd=os.getcwd()
    )
    deadline = time.time() + 600  # bounds a hang only: the holder is polled for, not timed
    while time.time() < deadline and f"pid {proc.pid}" not in _text(path / LOCK_NAME):
        time.sleep(0.05)
    assert f"pid {proc.pid}" in _text(path / LOCK_NAME), "the holder never took the lock"
    return proc


def _text(path):
    return path.read_text() if path.is_file() else ""


def test_second_writer_is_refused_naming_the_first_and_a_kill_frees_the_lock(tmp_path):
    holder = _holder(tmp_path)
    with pytest.raises(OutputLockedError, match=rf"is being written by obsbench demos \(pid {holder.pid}, started"):
        with exclusive_output(tmp_path, "obsbench demos"):
            pass
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    with exclusive_output(tmp_path, "obsbench demos"):  # the kernel released it with the process
        assert f"pid {os.getpid()}" in (tmp_path / LOCK_NAME).read_text()


def test_lock_is_released_when_the_block_ends_or_raises(tmp_path):
    with pytest.raises(RuntimeError):
        with exclusive_output(tmp_path, "job"):
            raise RuntimeError("boom")
    with exclusive_output(tmp_path, "job"):
        pass


def test_a_second_grid_runner_on_the_same_output_is_refused(tmp_path, capsys):
    grid = tmp_path / "g.yaml"
    grid.write_text("tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\npreset: tiny\neval_episodes: 1\n")
    out = tmp_path / "out"
    with exclusive_output(out, "obsbench run g"):
        assert main(["run", str(grid), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"obsbench run: error: {out} is being written by obsbench run g (pid {os.getpid()}")
    assert len(err.strip().splitlines()) == 1
    assert not (out / "results.jsonl").exists() and not (out / "demos").exists()


def test_an_unusable_output_directory_is_one_line(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    assert main(["demos", "--task", "PushCube-v1", "--episodes", "1", "--out", str(blocker / "demos")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"obsbench demos: error: cannot create the output directory {blocker / 'demos'}")
    assert len(err.splitlines()) == 1
