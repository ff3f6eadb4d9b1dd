"""One writer per output directory: long jobs (demos, real-robot recording, benchmark grids) hold an exclusive
lock on their output, so a second job started on the same directory stops at once with a message naming the
first, instead of both writing the same files.

The lock is `fcntl.flock` on `<dir>/.obsbench.lock`: the kernel releases it when the holding process exits or is
killed, so a crash never leaves a stale lock behind. The file itself is left in place (deleting a lock file
while another process may be opening it would let two writers in).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from lerobot_obsbench.errors import ObsBenchError

LOCK_NAME = ".obsbench.lock"


class OutputLockedError(ObsBenchError, RuntimeError):
    """Another process is writing the same output directory."""


def _writable_dir(path: Path) -> None:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputLockedError(f"cannot create the output directory {path}: {err.strerror}") from None
    if not os.access(path, os.W_OK):
        raise OutputLockedError(f"the output directory {path} is not writable; choose another output directory")


@contextlib.contextmanager
def exclusive_output(path: str | Path, job: str) -> Iterator[Path]:
    """Hold the output lock of directory `path` (created if needed) while the block runs.

    `job` says what writes there (e.g. "obsbench demos"); it is recorded in the lock file so a refused second
    process can name the first. Raises `OutputLockedError` at once if the directory is locked or not writable.
    """
    path = Path(path)
    _writable_dir(path)
    lock_path = path / LOCK_NAME
    handle = open(lock_path, "a+")
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            raise OutputLockedError(
                f"{path} is being written by {holder}; wait for it to finish (or stop it), or choose another "
                "output directory"
            ) from None
        handle.seek(0)
        handle.truncate()
        command = " ".join(Path(sys.argv[0]).name if i == 0 else a for i, a in enumerate(sys.argv))
        handle.write(f"{job} (pid {os.getpid()}, started {time.strftime('%Y-%m-%d %H:%M:%S')}: {command})\n")
        handle.flush()
        yield path
    finally:
        handle.close()  # closing the descriptor releases the lock
