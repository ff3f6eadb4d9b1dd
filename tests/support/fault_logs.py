"""A pytest plugin: each test process (every pytest-xdist worker) writes the stack of a crash — a segmentation fault
in a simulator, a native kernel or a driver — to a file of its own, and the run's summary prints those files. A
worker's own stderr never reaches the log, and pytest-xdist reports a crashed worker by its test's name alone.

Loaded by tests/conftest.py (`pytest_plugins`)."""

from __future__ import annotations

import faulthandler
import os
import shutil
import tempfile
from pathlib import Path

import pytest

FAULT_DIR_ENV = "OBSBENCH_TEST_FAULT_DIR"  # where the controller asks its workers to write (they inherit it)
_open_files = []  # a worker's log stays open for the faulthandler as long as the process lives


@pytest.hookimpl(trylast=True)  # after pytest's own faulthandler plugin, which points it at stderr
def pytest_configure(config):
    # A worker is known by its own config, not by the environment: a test that starts pytest inside a worker
    # inherits that worker's variables, and its run must still collect its own workers' logs.
    worker_input = getattr(config, "workerinput", None)
    if worker_input is None:  # the controller (or a run without workers): one folder for this run's logs
        folder = tempfile.mkdtemp(prefix="pytest-faults-")
        os.environ[FAULT_DIR_ENV] = folder
        config._fault_folder = Path(folder)
        return
    folder = os.environ.get(FAULT_DIR_ENV)
    if folder:
        log = open(Path(folder) / f"{worker_input['workerid']}.log", "w")  # kept open for the process's life
        _open_files.append(log)
        faulthandler.enable(file=log, all_threads=True)


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    folder = getattr(config, "_fault_folder", None)
    if folder is None:
        return
    for log in sorted(folder.glob("*.log")):
        text = log.read_text(errors="replace").strip()
        if text:
            terminalreporter.write_sep("=", f"crash in test worker {log.stem}: its own stack")
            terminalreporter.write_line(text)


def pytest_unconfigure(config):
    folder = getattr(config, "_fault_folder", None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
