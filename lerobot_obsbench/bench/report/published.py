"""The paper's published tables: the ones shipped with the package, reading one (or any CSV of success rates),
and the row name the paper gives a task."""

from __future__ import annotations

import csv
from pathlib import Path

from lerobot_obsbench.bench.package_data import TABLES, path_or_shipped, shipped
from lerobot_obsbench.bench.report.statistics import ReportError
from lerobot_obsbench.rlbench.paper_tasks import PAPER_ROWS, grid_task_name


def published_tables() -> list[str]:
    """The paper's tables, typed from its LaTeX source, shipped with the package (`--table NAME`)."""
    return shipped(TABLES, ".csv")


def resolve_table(name_or_path: str | Path):
    """A CSV path, or the packaged paper table of that name."""
    found = path_or_shipped(name_or_path, TABLES, ".csv")
    if found is not None:
        return found
    raise ReportError(f"no table {str(name_or_path)!r}: give a CSV path or one of {', '.join(published_tables())}")


def read_published(path: Path) -> dict[str, dict[str, float]]:
    """A published table as CSV: first column the task, one column per method, success rates in [0, 1];
    empty cells are missing values."""
    rows = list(csv.reader(path.read_text().splitlines()))
    if len(rows) < 2 or len(rows[0]) < 2:
        raise ReportError(f"{path}: expected a header (task, method, ...) and at least one task row")
    methods = [m.strip() for m in rows[0][1:]]
    table = {}
    for number, row in enumerate(rows[1:], start=2):
        if not row or not row[0].strip():
            continue
        if len(row) != len(methods) + 1:
            raise ReportError(f"{path}:{number}: {len(row)} cells, the header has {len(methods) + 1}")
        values = {}
        for method, text in zip(methods, row[1:], strict=True):
            if not text.strip():
                continue
            try:
                value = float(text)
            except ValueError:
                raise ReportError(f"{path}:{number}: {method} = {text!r} is not a number") from None
            if not 0 <= value <= 1:
                raise ReportError(f"{path}:{number}: {method} = {value} is not a success rate in [0, 1]")
            values[method] = value
        table[row[0].strip()] = values
    return table


def paper_row(task: str) -> str:
    """The row name the paper's tables give a task: RLBench's as Table 2 prints them, ManiSkill's without the
    version suffix (PickCube-v1 -> PickCube)."""
    name = grid_task_name(task)
    if name is not None:
        return PAPER_ROWS.get(name, name.replace("_", " "))
    return task.removesuffix("-v1")
