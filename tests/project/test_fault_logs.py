"""A test worker that crashes (a segmentation fault in native code) leaves its own stack in the run's summary, not
only pytest-xdist's "worker crashed" line (tests/support/fault_logs.py)."""

from __future__ import annotations

import subprocess
import sys

from tests.support.paths import REPO_ROOT


def test_a_crashed_workers_own_stack_reaches_the_summary(tmp_path):
    (tmp_path / "test_crash.py").write_text(
        "import ctypes\n\n\ndef test_ok():\n    pass\n\n\ndef test_reads_address_zero():\n    ctypes.string_at(0)\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "2", "-p", "tests.support.fault_logs", "-p", "no:cacheprovider"]
        + ["--rootdir", str(tmp_path), str(tmp_path / "test_crash.py")],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode != 0
    assert "crash in test worker gw" in done.stdout and "Segmentation fault" in done.stdout, done.stdout[-3000:]
    assert "test_reads_address_zero" in done.stdout.split("crash in test worker")[-1]  # the crashing test's frame
