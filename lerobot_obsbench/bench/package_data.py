"""Files shipped inside the package (preset grids, the paper's tables), found by name or given as a path, so
that a built wheel finds them as well as a source checkout."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def shipped(folder: str, suffix: str) -> list[str]:
    """Names (without `suffix`) of the files in the package folder `lerobot_obsbench/bench/<folder>`."""
    root = resources.files("lerobot_obsbench.bench") / folder
    return sorted(p.name.removesuffix(suffix) for p in root.iterdir() if p.name.endswith(suffix))


def path_or_shipped(name_or_path: str | Path, folder: str, suffix: str):
    """An existing file's path, else the shipped file `<folder>/<name><suffix>`, else None."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    packaged = resources.files("lerobot_obsbench.bench") / folder / f"{name_or_path}{suffix}"
    return packaged if packaged.is_file() else None
