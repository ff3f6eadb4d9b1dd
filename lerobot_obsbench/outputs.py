"""Output files written whole or not at all, and checked before the work that fills them.

A command that runs for minutes and then writes one file (an evaluation's JSON result) checks that file's path
first — not a directory, not already there unless the user said to replace it, its folder creatable and
writable — so the work is never lost on a bad path; and it writes through a temporary name renamed into place,
so an interruption never leaves half a file where a whole one was.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

from lerobot_obsbench.errors import ObsBenchError


class OutputPathError(ObsBenchError, ValueError):
    """An output path the command could not write, or would replace without being asked to."""


def check_output_file(path: Path, flag: str, overwrite: bool = False, inputs: Iterable[Path] = ()) -> None:
    """Refuse, before any work, an output file `path` (given by `flag`) that cannot be written, that exists while
    `overwrite` is False, that is one of the command's `inputs` (or inside one) or inside a LeRobot dataset."""
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{flag} {path} is a directory; give a file path, e.g. {flag} {path / 'result.json'}")
    _check_not_an_input(path, flag, inputs)
    if path.exists() and not overwrite:
        raise OutputPathError(f"{flag} {path} already exists; add --overwrite to replace it, or give another path")
    _check_creatable(path.parent, path, flag)


def check_output_folder(path: Path, flag: str, inputs: Iterable[Path] = ()) -> None:
    """Refuse, before any work, an output folder `path` (given by `flag`) that is a file, cannot be created or
    written, is one of the command's `inputs` (or inside one) or lies inside a LeRobot dataset. What the command
    writes in it replaces files of the same name (a regenerated report, a camera's new calibration)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"{flag} {path} is a file; give a folder")
    _check_not_an_input(path, flag, inputs)
    _check_creatable(path, path, flag)


def dataset_holding(path: Path) -> Path | None:
    """The LeRobot dataset (a folder with meta/info.json) that `path` is, or lies inside, if any."""
    for folder in (path, *path.parents):
        if (folder / "meta" / "info.json").is_file():
            return folder
    return None


def _check_not_an_input(path: Path, flag: str, inputs: Iterable[Path]) -> None:
    resolved = path.expanduser().resolve()
    for given in inputs:
        source = Path(given).expanduser().resolve()
        if resolved == source or source in resolved.parents:
            raise OutputPathError(
                f"{flag} {path} would write over this command's input {given}; give a path outside it"
            )
    dataset = dataset_holding(resolved)
    if dataset is not None:
        raise OutputPathError(
            f"{flag} {path} is inside the LeRobot dataset {dataset}; write outputs outside datasets (their files "
            "are what training reads)"
        )


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
