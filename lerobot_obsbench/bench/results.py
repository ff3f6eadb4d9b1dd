"""The results store: one JSON record per finished run, appended to a JSON-lines file.

Only finished runs are written, each as one line flushed and fsynced before the next run is announced, so a
kill leaves at most a truncated last line. Reading reports every unreadable line with its line number and
skips it (the run it belonged to simply runs again), instead of dropping it silently.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

REQUIRED = ("run_id", "config", "method", "evaluations")


def read_results(path: Path, warn=None) -> list[dict]:
    """Records of `path` (missing file: none). Bad lines are reported through `warn` (default: stderr)."""
    warn = warn or (lambda message: print(message, file=sys.stderr))
    path = Path(path)
    if not path.is_file():
        return []
    records = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as err:
            warn(
                f"{path}:{number}: corrupted results line skipped ({err.msg} at column {err.colno}); "
                "its run will be redone"
            )
            continue
        missing = [k for k in REQUIRED if not isinstance(record, dict) or k not in record]
        if missing:
            warn(f"{path}:{number}: results line without {missing} skipped")
            continue
        records.append(record)
    return records


def append_result(path: Path, record: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    line = json.dumps(record, sort_keys=True) + "\n"
    with open(path, "a+b") as f:
        # A previous kill may have left a truncated line without its newline: start on a fresh line.
        if f.seek(0, os.SEEK_END):
            f.seek(-1, os.SEEK_END)
            if f.read(1) != b"\n":
                f.write(b"\n")
        f.write(line.encode())
        f.flush()
        os.fsync(f.fileno())
