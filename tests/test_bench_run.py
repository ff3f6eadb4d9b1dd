"""End to end: a grid of 4 tiny runs (demos -> lerobot-train -> eval incl. a perturbation -> record -> report),
killed mid-way and resumed, ends with exactly one record per run. Needs the simulator: slow."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.results import read_results

pytestmark = pytest.mark.slow
BIN = Path(sys.executable).parent
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
GRID = """
name: tiny
tasks: [PushCube-v1]
obs_spaces: [rgb, pointcloud]
policies: [obs_act, obs_diffusion]
preset: tiny
seeds: [7]
learning_rates: [1.0e-3]
demos: [2]
batch_size: 4
steps: 3
image_size: 32
eval_episodes: 2
perturbations: [light:0.05]
policy_overrides: {workspace: [-1, 1, -1, 1, 0.005, 1]}
"""


def obsbench(*args, **kwargs):
    return subprocess.Popen(
        [str(BIN / "obsbench"), *args],
        env=ENV,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        **kwargs,
    )


def test_grid_runs_resumes_after_a_kill_and_reports(tmp_path):
    grid_file = tmp_path / "tiny.yaml"
    grid_file.write_text(GRID)
    out = tmp_path / "out"
    results = out / "results.jsonl"
    expected = {r.run_id for r in load_grid(grid_file).expand()}
    assert len(expected) == 4

    first = obsbench("run", str(grid_file), "--out", str(out), start_new_session=True)
    deadline = time.time() + 600

    def next_run_training() -> bool:  # a run recorded, and the next one's training started: kill it mid-run
        finished = {r["run_id"] for r in read_results(results, warn=lambda m: None)}
        logs = [p for p in (out / "runs").glob("*/train.log") if p.parent.name not in finished]
        return bool(finished) and bool(logs)

    while time.time() < deadline and not next_run_training():
        assert first.poll() is None, first.stdout.read()
        time.sleep(0.2)
    os.killpg(first.pid, signal.SIGKILL)
    first.wait()
    done_before = {r["run_id"] for r in read_results(results)}
    assert 1 <= len(done_before) < 4
    with open(results, "a") as f:
        f.write('{"run_id": "truncated by a ki')  # what a kill during a write would leave

    second = obsbench("run", str(grid_file), "--out", str(out), "--workers", "2")  # the process-pool path
    log, _ = second.communicate(timeout=900)
    assert second.returncode == 0, log
    assert f"4 runs, {len(done_before)} already finished" in log
    assert "corrupted results line skipped" in log

    records = read_results(results, warn=lambda m: None)
    assert sorted(r["run_id"] for r in records) == sorted(expected)  # exactly one record per run
    for r in records:
        assert set(r["evaluations"]) == {"none", "light:0.05"}
        nominal = r["evaluations"]["none"]
        assert nominal["episodes"] == 2 and 0 <= nominal["successes"] <= 2
        assert Path(r["checkpoint"], "model.safetensors").is_file()
        assert r["versions"]["lerobot"] == "0.4.4" and r["timings"]["train_s"] > 0
    # no leftovers: one run directory per record
    assert {p.name for p in (out / "runs").iterdir()} == expected

    report = subprocess.run(
        [str(BIN / "obsbench"), "report", str(results), "--json", str(tmp_path / "s.json")],
        env=ENV,
        capture_output=True,
        text=True,
    )
    assert report.returncode == 0, report.stderr
    summary = json.loads((tmp_path / "s.json").read_text())["results"]
    assert set(summary) == {
        "obs_act/rgb/resnet18",
        "obs_act/pointcloud/pointnet",
        "obs_diffusion/rgb/resnet18",
        "obs_diffusion/pointcloud/pointnet",
    }
    assert (out / "report" / "report.html").is_file() and (out / "report" / "generalization_light.png").is_file()
