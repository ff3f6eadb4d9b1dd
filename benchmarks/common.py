"""Helpers shared by the benchmarks: timing, machine description, JSON output."""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import torch

from benchmarks.portable import portable

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def load_synthetic():
    """The stock-LeRobot synthetic scene writer (scripts/make_synthetic_dataset.py)."""
    from scripts import make_synthetic_dataset

    return make_synthetic_dataset


def timed(fn, repeats: int, warmup: int = 1) -> dict:
    """Median / min wall time of `fn()` in milliseconds."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1000)
    times.sort()
    return {"median_ms": round(times[len(times) // 2], 3), "min_ms": round(times[0], 3), "repeats": repeats}


def machine() -> dict:
    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "platform": platform.platform(),
        "date": time.strftime("%Y-%m-%d"),
    }


def write(name: str, payload: dict, out: Path | None = None) -> Path:
    path = out or RESULTS / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(portable({"benchmark": name, "machine": machine(), **payload}), indent=2) + "\n")
    print(f"wrote {path}")
    return path
