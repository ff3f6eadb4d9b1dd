"""Output files written whole or not at all, and checked before the work that fills them.

A command that runs for minutes and then writes one file (an evaluation's JSON result) checks that file's path
first — not a directory, not already there unless the user said to replace it, its folder creatable and
writable — so the work is never lost on a bad path; and it writes through a temporary name renamed into place,
so an interruption never leaves half a file where a whole one was.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from lerobot_obsbench.errors import ObsBenchError


class OutputPathError(ObsBenchError, ValueError):
    """An output path the command could not write, or would replace without being asked to."""


def check_output_file(path: Path, flag: str, overwrite: bool = False) -> None:
    """Refuse, before any work, an output file `path` (given by `flag`) that cannot be written or that exists
    while `overwrite` is False."""
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{flag} {path} is a directory; give a file path, e.g. {flag} {path / 'result.json'}")
    if path.exists() and not overwrite:
        raise OutputPathError(f"{flag} {path} already exists; add --overwrite to replace it, or give another path")
    _check_creatable(path.parent, path, flag)


def check_output_folder(path: Path, flag: str) -> None:
    """Refuse, before any work, an output folder `path` (given by `flag`) that is a file or cannot be created or
    written. What the command writes in it replaces files of the same name (a regenerated report, a camera's
    new calibration)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"{flag} {path} is a file; give a folder")
    _check_creatable(path, path, flag)


def _check_creatable(folder: Path, path: Path, flag: str) -> None:
    while not folder.exists():  # the nearest existing folder decides whether the rest can be created
        folder = folder.parent
    if not folder.is_dir():
        raise OutputPathError(f"{flag} {path}: {folder} is a file, so the folder cannot be created")
    if not os.access(folder, os.W_OK):
        raise OutputPathError(f"{flag} {path}: the folder {folder} is not writable; give another path")


def write_json_atomic(path: Path, data) -> None:
    """`data` as JSON, written whole (a reader polling the file never sees half of it)."""
    write_text_atomic(path, json.dumps(data))


def write_text_atomic(path: Path, text: str) -> None:
    """Write `text` to `path` through a temporary file in the same folder, renamed into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
