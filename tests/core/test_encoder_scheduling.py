"""LeRobot's video encoding leaves the calling thread's scheduling as it found it (lerobot_obsbench/patches.py, fix
3): SVT-AV1 raises the thread that opens an encoder to SCHED_FIFO priority 99 when it may (as root), and that
thread then preempts the machine's normal processes and passes the policy to every process it starts. The
encodings run in fresh interpreters, so that the stock control cannot leave the test process real-time."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from lerobot_obsbench.patches import thread_scheduling_kept

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="scheduling policies are Linux's")


def _may_go_real_time() -> bool:
    """Whether this process may make a thread real-time (root with CAP_SYS_NICE), tried on a throwaway thread."""
    allowed = []

    def attempt():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        except OSError:
            return
        allowed.append(True)

    if hasattr(os, "sched_setscheduler"):
        thread = threading.Thread(target=attempt)
        thread.start()
        thread.join()
    return bool(allowed)


MAY_GO_REAL_TIME = _may_go_real_time()

ENCODE = """
import os, subprocess, sys
from pathlib import Path

import numpy as np
import PIL.Image

import lerobot_obsbench  # noqa: F401  (applies the patches, as LeRobot's plugin discovery does)
from lerobot.datasets import dataset_writer, video_utils

frames = Path(sys.argv[1])
frames.mkdir()
for i in range(4):
    PIL.Image.fromarray(np.full((32, 32, 3), 40 * i, np.uint8)).save(frames / f"frame-{i:06d}.png")
patched = dataset_writer.encode_video_frames
stock = getattr(video_utils.encode_video_frames, "__wrapped__", video_utils.encode_video_frames)
encode = {"patched": patched, "stock": stock}[sys.argv[2]]
encode(frames, frames.parent / "out.mp4", fps=10, overwrite=True)
assert (frames.parent / "out.mp4").stat().st_size > 0
child = [sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"]
print(os.sched_getscheduler(0), os.sched_getparam(0).sched_priority, subprocess.check_output(child, text=True).strip())
"""


def encode_and_report(tmp_path, which: str) -> tuple[int, int, int]:
    """(policy, priority) of the thread that encoded, and the policy of a process it started afterwards."""
    out = subprocess.run(
        [sys.executable, "-c", ENCODE, str(tmp_path / "frames"), which], capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    policy, priority, child = map(int, out.stdout.split()[-3:])
    return policy, priority, child


@pytest.mark.skipif(not MAY_GO_REAL_TIME, reason="the encoder can raise its thread's priority only as root")
def test_stock_encoding_as_root_leaves_the_thread_and_its_children_real_time(tmp_path):
    """The control: without the patch the encoder's switch is visible, so the next test can see it undone."""
    assert encode_and_report(tmp_path, "stock") == (os.SCHED_FIFO, 99, os.SCHED_FIFO)


def test_patched_encoding_leaves_the_thread_and_its_children_as_they_were(tmp_path):
    assert encode_and_report(tmp_path, "patched") == (os.SCHED_OTHER, 0, os.SCHED_OTHER)


@pytest.mark.skipif(not MAY_GO_REAL_TIME, reason="only root (with CAP_SYS_NICE) may make a thread real-time")
def test_thread_scheduling_kept_restores_a_policy_changed_inside():
    seen = {}

    def worker():
        with thread_scheduling_kept():
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            seen["inside"] = os.sched_getscheduler(0)
        seen["after"] = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)

    thread = threading.Thread(target=worker)  # its own thread: the test process's main thread is never touched
    thread.start()
    thread.join()
    assert seen == {"inside": os.SCHED_FIFO, "after": (os.SCHED_OTHER, 0)}
