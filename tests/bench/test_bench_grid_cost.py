"""benchmarks/bench_grid_cost.py's options: a bad number or an output path it cannot or may not write is refused,
naming the option and the fix, before the results are read; what it writes is strict JSON, and it replaces only
its own earlier output unless told to overwrite (tests/bench/test_bench_grid.py holds the cost model to the
published measurement)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from benchmarks import bench_grid_cost
from tests.support.paths import REPO_ROOT

RESULTS = REPO_ROOT / "docs" / "results" / "cpu-suite" / "results.jsonl"


def run_tool(monkeypatch, *options: str, results: Path = RESULTS) -> None:
    command = ["bench_grid_cost", "--grid", "cpu-suite", "--results", str(results), *options]
    monkeypatch.setattr(sys, "argv", command)
    bench_grid_cost.main()


def strict_json(text: str):
    """`text` as JSON, refusing NaN and Infinity (which Python writes but JSON does not have)."""

    def refuse(constant: str):
        raise ValueError(f"{constant} is not JSON")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture
def no_work(monkeypatch):
    """Reading the results is where the tool's work starts: a refusal must come before it."""

    def work_started(*args, **kwargs):
        raise AssertionError("the results were read before the refusal")

    monkeypatch.setattr(bench_grid_cost, "read_results", work_started)


@pytest.mark.parametrize(
    "options, message",
    [
        (["--wall-s", "nan"], "argument --wall-s: must be a finite number > 0, got nan"),
        (["--wall-s", "inf"], "argument --wall-s: must be a finite number > 0, got inf"),
        (["--wall-s", "0"], "argument --wall-s: must be a finite number > 0, got 0"),
        (["--wall-s", "-7531"], "argument --wall-s: must be a finite number > 0, got -7531"),
        (["--wall-s", "2h"], "argument --wall-s: expected a finite number > 0, got '2h'"),
        (["--workers", "0"], "argument --workers: must be a whole number >= 1, got 0"),
        (["--workers", "-2"], "argument --workers: must be a whole number >= 1, got -2"),
        (["--workers", "1.5"], "argument --workers: expected a whole number >= 1, got '1.5'"),
        (["--workers", "nan"], "argument --workers: expected a whole number >= 1, got 'nan'"),
    ],
)
def test_a_bad_number_is_refused_naming_its_option_before_any_work(
    no_work, monkeypatch, capsys, tmp_path, options, message
):
    out = tmp_path / "cost.json"
    with pytest.raises(SystemExit) as exit_:
        run_tool(monkeypatch, "--out", str(out), *options)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and message in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize(
    "case, message",
    [
        ("a folder", "is a directory; give a file path, e.g. --out"),
        ("a file it did not write", "add --overwrite to replace it, or give another path"),
        ("its own input, even with --overwrite", "would write over this command's input"),
        ("under a file", "is a file, so the folder cannot be created"),
    ],
)
def test_an_out_path_it_cannot_or_may_not_write_is_refused_before_any_work(
    no_work, monkeypatch, capsys, tmp_path, case, message
):
    notes = tmp_path / "notes.json"
    notes.write_text("my own notes\n")
    out, extra = {
        "a folder": (tmp_path, []),
        "a file it did not write": (notes, []),
        "its own input, even with --overwrite": (RESULTS, ["--overwrite"]),
        "under a file": (notes / "cost.json", []),
    }[case]
    results_before = RESULTS.read_bytes()
    with pytest.raises(SystemExit) as exit_:
        run_tool(monkeypatch, "--out", str(out), *extra)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and f"--out {out}" in err and message in err and "Traceback" not in err
    assert notes.read_text() == "my own notes\n" and RESULTS.read_bytes() == results_before


def test_it_writes_strict_json_and_replaces_only_its_own_output_unless_told_to_overwrite(monkeypatch, tmp_path):
    out = tmp_path / "cost.json"
    run_tool(monkeypatch, "--wall-s", "7531.2", "--workers", "2", "--out", str(out))
    first = strict_json(out.read_text())
    assert first["benchmark"] == "grid_cost_cpu-suite" and first["wall_s"] == 7531.2 and first["workers"] == 2
    assert set(first["evaluation"]) == {"PushCubeWide-v1", "PickCube-v1", "StackCube-v1", "PegInsertionSide-v1"}

    run_tool(monkeypatch, "--workers", "1", "--out", str(out))  # its own output of the same results: replaced
    assert strict_json(out.read_text())["workers"] == 1

    copy = tmp_path / "copy.jsonl"  # another results file: this output is not its to replace
    copy.write_bytes(RESULTS.read_bytes())
    with pytest.raises(SystemExit) as exit_:
        run_tool(monkeypatch, "--out", str(out), results=copy)
    assert exit_.value.code == 2 and strict_json(out.read_text())["workers"] == 1

    other = tmp_path / "other.json"
    other.write_text('{"benchmark": "grid_cost_cpu-suite"}\n')  # written by hand, whatever it says
    with pytest.raises(SystemExit):
        run_tool(monkeypatch, "--out", str(other))
    run_tool(monkeypatch, "--out", str(other), "--overwrite")
    assert strict_json(other.read_text())["evaluation"] == first["evaluation"]
