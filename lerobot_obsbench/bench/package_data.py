"""Files shipped with the package (preset grids, the paper's tables), found by name or given as a path, so that
an installed wheel finds them as well as a source checkout.

The preset grids live in the repository's top-level `configs/grids/`, which the wheel ships inside the package as
`lerobot_obsbench/configs/grids/` (setup.py); the paper's tables live in `lerobot_obsbench/bench/tables/`."""

from __future__ import annotations

from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

GRIDS = "configs/grids"
TABLES = "bench/tables"


def _folder(folder: str) -> Traversable:
    """`lerobot_obsbench/<folder>` as installed, else `<folder>` at the top of the source checkout."""
    installed = resources.files("lerobot_obsbench").joinpath(folder)
    return installed if installed.is_dir() else Path(__file__).resolve().parents[2] / folder


def shipped(folder: str, suffix: str) -> list[str]:
    """Names (without `suffix`) of the files shipped in `folder` (GRIDS or TABLES)."""
    return sorted(p.name.removesuffix(suffix) for p in _folder(folder).iterdir() if p.name.endswith(suffix))


def path_or_shipped(name_or_path: str | Path, folder: str, suffix: str):
    """An existing file's path, else the shipped file `<folder>/<name><suffix>`, else None."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    packaged = _folder(folder) / f"{name_or_path}{suffix}"
    return packaged if packaged.is_file() else None
