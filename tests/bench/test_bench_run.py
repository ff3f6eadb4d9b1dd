"""End to end on the simulator (slow): a grid of tiny runs trained with stock lerobot-train and evaluated, once for the
module (`finished_grid`), which every test reads or copies:

- the grid gives one train record per run and one eval record per evaluation, its report and its diagnostics on
  held-out demonstrations;
- adding a perturbation to a finished grid evaluates its checkpoints and trains nothing;
- the Ray engine (a local instance, loopback only) gives the local engine's records, and a driver killed mid-grid
  resumes to exactly one record per unit, past a record a kill cut short.

One run of a grid (kills mid-training and mid-evaluation, checkpoint selection, learning curves) is in
test_bench_one_run.py, so that the two files share the test workers evenly.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.results import by_kind
from tests.support.grid_cli import BIN, ENV, GRID, comparable, finish, kill, obsbench, quiet, wait_for

pytestmark = pytest.mark.slow

# the tiny grid with a held-out demonstration, which every run's diagnostics are computed on
HELD_OUT_GRID = GRID + "held_out_demos: 1\n"


@pytest.fixture(scope="module")
def finished_grid(tmp_path_factory) -> tuple[Path, str]:
    """(folder, log) of the tiny grid run once, two units at a time, one thread each."""
    root = tmp_path_factory.mktemp("grid")
    (root / "tiny.yaml").write_text(HELD_OUT_GRID)
    log = finish("run", str(root / "tiny.yaml"), "--out", str(root / "out"), "--workers", "2", "--threads", "1")
    return root, log


def test_a_grid_gives_one_record_per_unit_its_report_and_its_diagnostics(finished_grid, tmp_path):
    root, log = finished_grid
    out = root / "out"
    grid = load_grid(root / "tiny.yaml")
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

    # the diagnostics on the held-out demonstration: 3 recorded, the last never trained on
    assert re.search(r"demonstrations \S+: 3 episodes of PushCube-v1 in \d+ s", log), log
    (train,) = [r for r in trains if r["method"] == "obs_act/pointcloud/pointnet"]
    found = train["diagnostics"]
    assert "error" not in found, found
    assert found["held_out_episodes"] == [2] and train["config"]["demos"] == 2
    steps = [step for step, _ in found["loss_curve"]]
    assert steps and steps[-1] <= 3 and all(loss > 0 for _, loss in found["loss_curve"])
    assert found["open_loop_error"] > 0
    assert 0 <= found["object_token_share"] <= 1 and found["object_pixels"]["obj"] > 1

    report = subprocess.run(
        [
            *(str(BIN / "obsbench"), "report", str(out / "results.jsonl")),
            *("--out", str(tmp_path / "report"), "--json", str(tmp_path / "s.json")),
        ],
        env=ENV,
        capture_output=True,
        text=True,
    )
    assert report.returncode == 0, report.stderr
    summary = json.loads((tmp_path / "s.json").read_text())["results"]
    assert set(summary) == {
        "obs_act/rgb/spatial_softmax",
        "obs_act/pointcloud/pointnet",
        "obs_diffusion/rgb/spatial_softmax",
        "obs_diffusion/pointcloud/pointnet",
    }
    assert (tmp_path / "report" / "report.html").is_file() and (tmp_path / "report" / "robustness_light.png").is_file()
    md = (tmp_path / "report" / "report.md").read_text()
    assert "Diagnostics per run" in md and f"{found['open_loop_error']:.3f}" in md
    assert (tmp_path / "report" / "training_loss.png").is_file()


def test_more_evaluations_train_nothing(finished_grid, tmp_path):
    root, _ = finished_grid
    out = tmp_path / "out"
    shutil.copytree(root / "out", out)  # (the module's grid is left as it was)
    for record_path in (out / "results.jsonl",):  # the copied records name the copy's checkpoints
        record_path.write_text(record_path.read_text().replace(str(root / "out"), str(out)))
    before = quiet(out / "results.jsonl")
    logs = {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/train.log")}
    (tmp_path / "more.yaml").write_text(
        HELD_OUT_GRID.replace("perturbations: [light:0.05]", "perturbations: [light:0.05, camera_yaw:10]")
    )
    log = finish("run", str(tmp_path / "more.yaml"), "--out", str(out), "--workers", "2", "--threads", "1")
    assert "4 runs, 4 already trained, 0 to train; 8 of 12 test evaluations done" in log
    assert "trained " not in log  # no training line: evaluations only
    after = quiet(out / "results.jsonl")
    assert by_kind(after, "train") == by_kind(before, "train")
    assert {p: p.stat().st_mtime_ns for p in logs} == logs  # no lerobot-train ran
    new = [r for r in by_kind(after, "eval") if r not in before]
    assert len(new) == 4 and {r["episodes"] for r in new} == {2}
    assert {r["perturbation"] for r in new} == {"camera_yaw:10"}
    assert {r["run_id"] for r in new} == {r["run_id"] for r in by_kind(before, "train")}


def test_ray_gives_the_local_records_and_a_killed_driver_resumes_to_one_record_per_unit(finished_grid, tmp_path):
    """A local Ray instance started by the driver (loopback only), killed once a run has trained: the same command
    resumes it, past a record the kill cut short, to exactly one record per unit. One thread per unit in both
    engines, so the trained weights, and with them the evaluations, are the local engine's."""
    root, _ = finished_grid
    grid, ray = tmp_path / "nominal.yaml", tmp_path / "ray"
    grid.write_text(HELD_OUT_GRID.replace("perturbations: [light:0.05]\n", ""))  # the nominal evaluations only
    shutil.copytree(root / "out" / "demos", ray / "demos")  # the same recording: not made again
    proc = obsbench("run", str(grid), "--out", str(ray), "--engine", "ray", "--threads", "1", start_new_session=True)
    wait_for(lambda: by_kind(quiet(ray / "results.jsonl"), "train"), proc, timeout=600)
    kill(proc)
    subprocess.run([str(BIN / "ray"), "stop", "--force"], env=ENV, capture_output=True, timeout=120)  # its instance
    done = {r["run_id"] for r in by_kind(quiet(ray / "results.jsonl"), "train")}
    assert 1 <= len(done) < 4
    with open(ray / "results.jsonl", "a") as f:
        f.write('{"kind": "eval", "run_id": "truncated by a ki')  # what a kill during a write would leave
    log = finish("run", str(grid), "--out", str(ray), "--engine", "ray", "--threads", "1")
    assert f"4 runs, {len(done)} already trained" in log and "corrupted results line skipped" in log
    nominal = load_grid(grid)
    evaluations = {s.eval_id for r in nominal.expand() for s in nominal.evaluations(r)}
    records = quiet(ray / "results.jsonl")
    assert sorted(r["eval_id"] for r in by_kind(records, "eval")) == sorted(evaluations)  # each once
    local = [r for r in quiet(root / "out" / "results.jsonl") if r.get("eval_id", "") in evaluations | {""}]
    assert comparable(records) == comparable(local)
