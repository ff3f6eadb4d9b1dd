"""Every LeRobot function the plugin replaces is a record (`lerobot_obsbench.patches.PATCHES`), listed in
docs/architecture.md, and the stock commands say at start-up what is in place."""

from __future__ import annotations

import logging
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

from lerobot.datasets import factory

from lerobot_obsbench import dataset_reads, patches

ROOT = Path(__file__).resolve().parents[2]
TABLE_HEAD = "| replaced | part of | LeRobot | when | can go once upstream has |"


def documented_rows() -> list[list[str]]:
    lines = (ROOT / "docs" / "architecture.md").read_text().splitlines()
    start = lines.index(TABLE_HEAD) + 2
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows


def test_the_docs_table_is_the_records():
    records = [[f"`{p.symbol}`", p.fix, p.versions, p.when, p.retire] for p in patches.PATCHES]
    assert documented_rows() == records


def test_each_record_names_what_is_replaced_and_only_that():
    """On import every "on import" record is in place and resolves to a real LeRobot attribute; the aggregation
    fix is in place only inside the plugin's own aggregation."""
    for patch in patches.PATCHES:
        assert pkgutil.resolve_name(patch.symbol) is getattr(patch.owner, patch.attribute), patch.symbol
        assert callable(patch.stock) and patch.stock.__module__.split(".")[0] in ("lerobot", "draccus"), patch.symbol
        assert patch.in_place() == (patch.when == "on import"), patch.symbol
    (aggregation,) = [p for p in patches.PATCHES if p.attribute == "aggregate_data"]
    with patches.array_safe_aggregation():
        assert aggregation.in_place()
    assert not aggregation.in_place()


def test_the_start_up_line_names_what_is_in_place(monkeypatch):
    line = dataset_reads.routes_line()
    on_import = [p for p in patches.PATCHES if p.when == "on import"]
    assert f"patches {len(on_import)} functions" in line and dataset_reads.ARCHITECTURE_TABLE in line
    for fix in ("columns formatted from NumPy", "keeps its thread's scheduling", "refusals keep their reasons"):
        assert fix in line
    assert "read only their features (reader `memory`" in line
    monkeypatch.setenv(dataset_reads.READER_ENV, "stock")
    assert f"LeRobot's reader ({dataset_reads.READER_ENV}=stock)" in dataset_reads.routes_line()
    with patches.stock_loading():  # LeRobot's own column formatting back: the line stops claiming it
        line = dataset_reads.routes_line()
    assert "columns formatted from NumPy" not in line
    assert f"patches {len(on_import) - 2} functions" in line


def test_lerobot_train_s_query_logs_the_line_once(monkeypatch, caplog):
    """lerobot-train sets logging up after importing plugins; the plugin logs when it resolves the query."""
    monkeypatch.setattr(dataset_reads, "_announced", [])
    meta = type("Meta", (), {"fps": 10, "features": {}})()
    config = type("Config", (), {"observation_delta_indices": None, "action_delta_indices": None})()
    config.reward_delta_indices = None
    with caplog.at_level(logging.INFO, logger=dataset_reads.__name__):
        factory.resolve_delta_timestamps(config, meta)
        factory.resolve_delta_timestamps(config, meta)
    logged = [r.getMessage() for r in caplog.records if "lerobot_obsbench patches" in r.getMessage()]
    assert logged == [dataset_reads.routes_line()]


def test_stock_lerobot_eval_logs_the_line_at_start_up():
    """lerobot-eval sets logging up first, then imports the plugin: the line is in its output before its help."""
    command = [str(Path(sys.executable).parent / "lerobot-eval"), "--help"]
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    proc = subprocess.run(command, capture_output=True, text=True, timeout=300, env=env, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "lerobot_obsbench patches" in proc.stdout + proc.stderr
    assert dataset_reads.ARCHITECTURE_TABLE in proc.stdout + proc.stderr
