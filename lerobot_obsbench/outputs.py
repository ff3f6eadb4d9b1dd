"""Output files written whole or not at all, and checked before the work that fills them.

A command that runs for minutes and then writes one file (an evaluation's JSON result) checks that file's path
first — not a directory, not already there unless the user said to replace it, its folder creatable and
writable — so the work is never lost on a bad path; and it writes through a temporary name renamed into place,
so an interruption never leaves half a file where a whole one was.

The rule every writer follows: an existing file is replaced only with `--overwrite`, or when it is the command's
own earlier output of the same inputs. That is recognised by content, not by name: after writing, a command notes
in the folder's record (`OUTPUTS_RECORD`) what made each file and the file's SHA-256, and a later run replaces a
file without being asked only if the record names the same maker and the file still has that content.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable
from pathlib import Path

from lerobot_obsbench.errors import ObsBenchError


class OutputPathError(ObsBenchError, ValueError):
    """An output path the command could not write, or would replace without being asked to."""


# Per folder: which command (and inputs) wrote which of its files, with each file's SHA-256.
OUTPUTS_RECORD = ".obsbench_outputs.json"


def check_output_file(
    path: Path, flag: str, overwrite: bool = False, inputs: Iterable[Path] = (), made_by: dict | None = None
) -> None:
    """Refuse, before any work, an output file `path` (given by `flag`) that cannot be written, that exists while
    `overwrite` is False (unless `made_by` wrote it, see `record_outputs`), that is one of the command's `inputs`
    (or inside one) or inside a LeRobot dataset."""
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{flag} {path} is a directory; give a file path, e.g. {flag} {path / 'result.json'}")
    _check_not_an_input(path, flag, inputs)
    if path.exists() and not overwrite and not (made_by is not None and is_own_output(path, made_by)):
        why = "" if made_by is None else " and is not this command's own output of the same inputs"
        raise OutputPathError(f"{flag} {path} already exists{why}; add --overwrite to replace it, or give another path")
    _check_creatable(path.parent, path, flag)


def check_output_folder(
    path: Path,
    flag: str,
    inputs: Iterable[Path] = (),
    files: Iterable[str] = (),
    made_by: dict | None = None,
    overwrite: bool = False,
) -> None:
    """Refuse, before any work, an output folder `path` (given by `flag`) that is a file, cannot be created or
    written, is one of the command's `inputs` (or inside one) or lies inside a LeRobot dataset; and, of the
    `files` the command will write in it, one already there that `made_by` did not write (`record_outputs`),
    unless `overwrite`."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"{flag} {path} is a file; give a folder")
    _check_not_an_input(path, flag, inputs)
    _check_creatable(path, path, flag)
    if overwrite or not path.is_dir():
        return
    foreign = [
        name
        for name in files
        if (path / name).exists() and not (made_by is not None and is_own_output(path / name, made_by))
    ]
    if foreign:
        shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        raise OutputPathError(
            f"{flag} {path} already holds {shown}, not this command's own output of the same inputs; add "
            "--overwrite to replace what is there, or give another folder"
        )


def is_own_output(path: Path, made_by: dict) -> bool:
    """Whether `path` is a file that `made_by` wrote and that still holds what it wrote (`record_outputs`)."""
    path = Path(path)
    entry = _outputs_record(path.parent).get(path.name)
    return path.is_file() and entry == {**made_by, "sha256": _sha256(path)}


def record_outputs(paths: Iterable[Path], made_by: dict) -> None:
    """Note in each file's folder that `made_by` (the command and the inputs it read, JSON values) wrote these
    files, with their content, so that a later run of the same command on the same inputs may replace them."""
    by_folder: dict[Path, list[Path]] = {}
    for path in map(Path, paths):
        by_folder.setdefault(path.parent, []).append(path)
    for folder, written in by_folder.items():
        record = _outputs_record(folder)
        record.update({path.name: {**made_by, "sha256": _sha256(path)} for path in written})
        write_text_atomic(folder / OUTPUTS_RECORD, json.dumps({"files": record}, indent=1, sort_keys=True) + "\n")


def _outputs_record(folder: Path) -> dict:
    """The folder's record of who wrote what ({} when there is none or it cannot be read: nothing is then
    recognised as a command's own, so nothing is replaced unasked)."""
    try:
        record = json.loads((folder / OUTPUTS_RECORD).read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    files = record.get("files") if isinstance(record, dict) else None
    return files if isinstance(files, dict) else {}


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


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
