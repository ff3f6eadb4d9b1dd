"""End to end on the simulator (slow): a grid of tiny runs trained with stock lerobot-train and evaluated.

- a grid killed mid-way resumes to exactly one train record per run and one eval record per evaluation;
- adding a perturbation to a finished grid evaluates its checkpoints and trains nothing;
- the Ray engine (a local instance, loopback only) gives the local engine's records and resumes after the driver
  is killed.

One run of a grid (kills mid-training and mid-evaluation, checkpoint selection, diagnostics, learning curves) is in
test_bench_one_run.py, so that the two files share the test workers evenly.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.results import by_kind
from tests.support.grid_cli import BIN, ENV, GRID, comparable, finish, kill, obsbench, quiet, wait_for

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def finished_grid(tmp_path_factory) -> Path:
    """The tiny grid, killed while its second run trains, then resumed with two workers. One thread per unit and
    only the final checkpoint saved (a run killed mid-training restarts from step 0): its records are what one
    uninterrupted run of the grid on any engine gives."""
    root = tmp_path_factory.mktemp("grid")
    (root / "tiny.yaml").write_text(GRID)
    out = root / "out"
    results = out / "results.jsonl"
    first = obsbench("run", str(root / "tiny.yaml"), "--out", str(out), "--threads", "1", start_new_session=True)

    def next_run_training() -> bool:  # a run trained, and another one's training started
        trained = {r["run_id"] for r in by_kind(quiet(results), "train")}
        logs = [p for p in (out / "runs").glob("*/train.log") if p.parent.name not in trained]
        return bool(trained) and bool(logs)

    wait_for(next_run_training, first)
    kill(first)
    trained_before = by_kind(quiet(results), "train")
    assert 1 <= len(trained_before) < 4
    with open(results, "a") as f:
        f.write('{"kind": "eval", "run_id": "truncated by a ki')  # what a kill during a write would leave
    log = finish("run", str(root / "tiny.yaml"), "--out", str(out), "--workers", "2", "--threads", "1")  # process pool
    assert f"4 runs, {len(trained_before)} already trained" in log
    assert "corrupted results line skipped" in log
    return root


def test_grid_resumes_after_a_kill_to_exactly_one_record_per_unit(finished_grid):
    out = finished_grid / "out"
    grid = load_grid(finished_grid / "tiny.yaml")
    records = quiet(out / "results.jsonl")
    trains, evals = by_kind(records, "train"), by_kind(records, "eval")
    assert sorted(r["run_id"] for r in trains) == sorted(r.run_id for r in grid.expand())
    expected = {s.eval_id for r in grid.expand() for s in grid.evaluations(r)}
    assert sorted(r["eval_id"] for r in evals) == sorted(expected)  # no evaluation twice
    for r in evals:
        assert r["episodes"] == 2 and 0 <= r["successes"] <= 2 and r["split"] == "test"
        assert len(r["per_seed"]["success"]) == 2
    for r in trains:
        assert Path(r["checkpoint"], "model.safetensors").is_file() and r["versions"]["lerobot"] == "0.6.1"
    assert {p.name for p in (out / "runs").iterdir()} == {r["run_id"] for r in trains}

    report = subprocess.run(
        [str(BIN / "obsbench"), "report", str(out / "results.jsonl"), "--json", str(finished_grid / "s.json")],
        env=ENV,
        capture_output=True,
        text=True,
    )
    assert report.returncode == 0, report.stderr
    summary = json.loads((finished_grid / "s.json").read_text())["results"]
    assert set(summary) == {
        "obs_act/rgb/spatial_softmax",
        "obs_act/pointcloud/pointnet",
        "obs_diffusion/rgb/spatial_softmax",
        "obs_diffusion/pointcloud/pointnet",
    }
    assert (out / "report" / "report.html").is_file() and (out / "report" / "generalization_light.png").is_file()


def test_more_evaluations_train_nothing(finished_grid):
    out = finished_grid / "out"
    before = quiet(out / "results.jsonl")
    logs = {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/train.log")}
    (finished_grid / "more.yaml").write_text(
        GRID.replace("perturbations: [light:0.05]", "perturbations: [light:0.05, camera_yaw:10]")
    )
    log = finish("run", str(finished_grid / "more.yaml"), "--out", str(out))
    assert "4 runs, 4 already trained, 0 to train; 8 of 12 test evaluations done" in log
    assert "trained " not in log  # no training line: evaluations only
    after = quiet(out / "results.jsonl")
    assert by_kind(after, "train") == by_kind(before, "train")
    assert {p: p.stat().st_mtime_ns for p in logs} == logs  # no lerobot-train ran
    new = [r for r in by_kind(after, "eval") if r not in before]
    assert len(new) == 4 and {r["episodes"] for r in new} == {2}
    assert {r["perturbation"] for r in new} == {"camera_yaw:10"}
    assert {r["run_id"] for r in new} == {r["run_id"] for r in by_kind(before, "train")}


def test_ray_engine_gives_the_local_records_and_resumes_after_the_driver_is_killed(finished_grid, tmp_path):
    """A local Ray instance started by the driver (loopback only). One thread per unit in both engines, so the
    trained weights, and with them the evaluations, are the local engine's (the finished grid's)."""
    grid, ray = finished_grid / "tiny.yaml", tmp_path / "ray"
    proc = obsbench("run", str(grid), "--out", str(ray), "--engine", "ray", "--threads", "1", start_new_session=True)
    wait_for(lambda: by_kind(quiet(ray / "results.jsonl"), "train"), proc, timeout=600)
    kill(proc)
    subprocess.run([str(BIN / "ray"), "stop", "--force"], env=ENV, capture_output=True, timeout=120)  # its instance
    done = {r["run_id"] for r in by_kind(quiet(ray / "results.jsonl"), "train")}
    assert 1 <= len(done) < 4
    log = finish("run", str(grid), "--out", str(ray), "--engine", "ray", "--threads", "1")
    assert f"{len(done)} already trained" in log
    grid_evaluations = {s.eval_id for r in load_grid(grid).expand() for s in load_grid(grid).evaluations(r)}
    local = [
        r for r in quiet(finished_grid / "out" / "results.jsonl") if r.get("eval_id", "") in grid_evaluations | {""}
    ]
    assert comparable(quiet(ray / "results.jsonl")) == comparable(local)
