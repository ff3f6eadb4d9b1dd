"""End to end on the simulator (slow): grids of tiny runs trained with stock lerobot-train and evaluated.

- a grid killed mid-way resumes to exactly one train record per run and one eval record per evaluation;
- adding a perturbation to a finished grid evaluates its checkpoints and trains nothing;
- a run killed mid-training resumes from its last checkpoint (LeRobot's training state); a run killed
  mid-evaluation keeps its checkpoint;
- the Ray engine (a local instance, loopback only) gives the local engine's records and resumes after the driver
  is killed.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.results import by_kind, read_results
from lerobot_obsbench.bench.units import resumable_step

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
checkpoints: 1
"""
# fields that differ between two executions of the same unit of work
TIMING = ("timings", "wall_s", "finished_at", "checkpoint", "checkpoints", "versions", "trained_in")


def _ctrl_c_reaches_it() -> None:
    """A command started from a shell's background job inherits SIGINT ignored; Ctrl-C tests need it delivered."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def obsbench(*args, env: dict | None = None, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / "obsbench"), *args],
        env=env or ENV,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=_ctrl_c_reaches_it,
        **kwargs,
    )


def quiet(path: Path) -> list[dict]:
    return read_results(path, warn=lambda message: None)


def wait_for(condition, proc: subprocess.Popen, timeout: float = 900) -> None:
    deadline = time.time() + timeout
    while not condition():
        assert proc.poll() is None, proc.stdout.read()
        assert time.time() < deadline, "timed out"
        time.sleep(0.2)


def kill(proc: subprocess.Popen) -> None:
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def finish(*args: str, env: dict | None = None) -> str:
    proc = obsbench(*args, env=env)
    log, _ = proc.communicate(timeout=1800)
    assert proc.returncode == 0, log
    return log


def comparable(records: list[dict]) -> dict:
    """Records keyed by identity, without what differs between executions (timings, paths, versions)."""
    return {r.get("eval_id", r["run_id"]): {k: v for k, v in r.items() if k not in TIMING} for r in records}


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
        "obs_act/rgb/resnet18",
        "obs_act/pointcloud/pointnet",
        "obs_diffusion/rgb/resnet18",
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


def evaluated_episodes(out: Path) -> int:
    """Episodes finished by the evaluations running under `out` (whatever their count: a poll can miss a step)."""
    done = 0
    for path in out.glob("runs/*/eval/*.progress"):
        with contextlib.suppress(FileNotFoundError):  # an evaluation that ends removes its progress file
            done = max(done, json.loads(path.read_text())["done"])
    return done


def one_run_grid(path: Path, *changes: tuple[str, str]) -> Path:
    """GRID narrowed to one run (obs_act on rgb), with `changes` (old, new) applied to its text."""
    text = GRID.replace("obs_spaces: [rgb, pointcloud]", "obs_spaces: [rgb]").replace(
        "policies: [obs_act, obs_diffusion]", "policies: [obs_act]"
    )
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new)
    path.write_text(text)
    return path


def test_killed_training_resumes_from_its_checkpoint_and_evaluation_keeps_it(tmp_path):
    # rgb through the small keypoint encoder: the kills need a run that renders (an evaluation long enough to be
    # killed in), not resnet18's 11M parameters, whose 80 steps were most of this test's time on a loaded machine
    grid = one_run_grid(
        tmp_path / "one.yaml",
        ("obs_spaces: [rgb]", "obs_spaces: [rgb]\nencoders: {rgb: [spatial_softmax]}"),
        ("steps: 3", "steps: 80"),
        ("checkpoints: 1", "checkpoints: 8"),
        ("eval_episodes: 2", "eval_episodes: 4"),
    )
    out = tmp_path / "out"
    (run,) = load_grid(grid).expand()
    train_dir = out / "runs" / run.run_id / "train"
    proc = obsbench("run", str(grid), "--out", str(out), start_new_session=True)
    wait_for(lambda: (resumable_step(train_dir) or 0) >= 20, proc)  # killed after a checkpoint, mid-training
    kill(proc)
    saved = resumable_step(train_dir)
    assert 20 <= saved < 80
    # restarted: LeRobot resumes from that step; then killed during the (4-episode) evaluation
    proc = obsbench("run", str(grid), "--out", str(out), start_new_session=True)
    wait_for(lambda: evaluated_episodes(out) >= 1, proc)
    kill(proc)
    (train,) = by_kind(quiet(out / "results.jsonl"), "train")
    assert train["resumed_from"] == saved and resumable_step(train_dir) == 80
    assert f"resuming at step {saved}" in (out / "runs" / run.run_id / "train.log").read_text()
    step_file = train_dir / "checkpoints" / "last" / "training_state" / "training_step.json"
    assert json.loads(step_file.read_text())["step"] == 80
    assert by_kind(quiet(out / "results.jsonl"), "eval") == []
    assert Path(train["checkpoint"], "model.safetensors").is_file()  # the kill during evaluation kept it
    log = finish("run", str(grid), "--out", str(out))
    assert "1 already trained, 0 to train" in log and "trained " not in log
    assert len(by_kind(quiet(out / "results.jsonl"), "eval")) == 2


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


def test_best_checkpoint_is_chosen_on_the_validation_seeds(tmp_path):
    """Every saved checkpoint is scored on the validation seeds (10000+); the test seeds then evaluate the last
    checkpoint and the best one (ties: the later); when they are the same checkpoint the record is copied."""
    grid = one_run_grid(
        tmp_path / "select.yaml",
        ("steps: 3", "steps: 4\nvalidation_episodes: 2"),
        ("checkpoints: 1", "checkpoints: 2"),
        ("perturbations: [light:0.05]\n", ""),
    )
    out = tmp_path / "out"
    finish("run", str(grid), "--out", str(out))
    evals = by_kind(quiet(out / "results.jsonl"), "eval")
    validation = [r for r in evals if r["split"] == "validation"]
    assert sorted(r["checkpoint_step"] for r in validation) == [2, 4]
    assert all(r["per_seed"]["seeds"] == [10000, 10001] for r in validation)
    best_step = max((r["success_rate"], r["checkpoint_step"]) for r in validation)[1]
    tests = {r["checkpoint"]: r for r in evals if r["split"] == "test"}
    assert set(tests) == {"last", "best"}
    assert tests["last"]["checkpoint_step"] == 4 and tests["best"]["checkpoint_step"] == best_step
    assert tests["last"]["per_seed"]["seeds"] == [0, 1]
    if best_step == 4:
        assert tests["best"]["copied_from"] == tests["last"]["eval_id"]
        assert tests["best"]["per_seed"] == tests["last"]["per_seed"]
    else:
        assert "copied_from" not in tests["best"]


def test_a_grid_run_records_its_diagnostics_on_held_out_demos_and_the_report_shows_them(tmp_path):
    grid = one_run_grid(
        tmp_path / "diag.yaml",
        ("demos: [2]", "demos: [2]\nheld_out_demos: 1"),
        ("obs_spaces: [rgb]", "obs_spaces: [pointcloud]"),
    )
    out = tmp_path / "out"
    log = finish("run", str(grid), "--out", str(out))
    # the recording reports itself when done, as training and evaluation do
    assert re.search(r"demonstrations \S+: 3 episodes of PushCube-v1 in \d+ s", log), log
    (train,) = by_kind(quiet(out / "results.jsonl"), "train")
    found = train["diagnostics"]
    assert "error" not in found, found
    # 3 demonstrations recorded, the last never trained on
    assert found["held_out_episodes"] == [2] and train["config"]["demos"] == 2
    steps = [step for step, _ in found["loss_curve"]]
    assert steps and steps[-1] <= 3 and all(loss > 0 for _, loss in found["loss_curve"])
    assert found["open_loop_error"] > 0
    assert 0 <= found["object_token_share"] <= 1 and found["object_pixels"]["obj"] > 1
    finish("report", str(out / "results.jsonl"))
    md = (out / "report" / "report.md").read_text()
    assert "Diagnostics per run" in md and f"{found['open_loop_error']:.3f}" in md
    assert (out / "report" / "training_loss.png").is_file()


@pytest.mark.slow
def test_the_same_run_on_the_same_machine_trains_bit_identical_weights(tiny_dataset, tmp_path):
    """Reproducibility the report's training-seed intervals rest on: one run trained twice (the grid's own
    training unit, threads pinned as the runner pins them) gives the same checkpoint, byte for byte; another
    training seed does not. Across machines floating-point paths differ, which is why grids train seeds."""
    from lerobot_obsbench.bench.grid import parse_grid
    from lerobot_obsbench.bench.units import train_unit

    grid = parse_grid(
        {
            "name": "reproducibility",
            "tasks": ["PushCube-v1"],
            "obs_spaces": ["pointcloud"],
            "encoders": {"pointcloud": ["dp3"]},
            "demos": [6],
            "seeds": [3, 4],
            "steps": 4,
            "batch_size": 2,
            "preset": "tiny",
            "policy_overrides": {"workspace": [-0.5, 0.5, -0.5, 0.5, 0.005, 0.5]},
        }
    )
    first, other_seed = grid.expand()
    weights = []
    for run, out in ((first, "a"), (first, "b"), (other_seed, "c")):
        record = train_unit(run.config(), str(tiny_dataset), str(tmp_path / out), checkpoints=1, threads=2)
        weights.append(Path(record["checkpoint"], "model.safetensors").read_bytes())
    assert weights[0] == weights[1]
    assert weights[0] != weights[2]


def test_a_learning_curve_is_one_run_evaluated_at_its_listed_checkpoints_and_reused_when_run_again(tmp_path):
    """`eval_checkpoints`: the run keeps those steps' checkpoints (and no other it saved on the way), each is
    evaluated on the test seeds, and the report draws the curve; running the grid again trains and evaluates
    nothing; a step listed after the run was trained is reported missing, with how to get it, not retrained."""
    grid = one_run_grid(
        tmp_path / "curve.yaml",
        ("obs_spaces: [rgb]", "obs_spaces: [none]"),
        ("steps: 3", "steps: 6\neval_checkpoints: [2, 4]"),
        ("perturbations: [light:0.05]\n", ""),
    )
    out = tmp_path / "out"
    finish("run", str(grid), "--out", str(out))
    (train,) = by_kind(quiet(out / "results.jsonl"), "train")
    assert sorted(int(s) for s in train["checkpoints"]) == [2, 4, 6]
    evals = by_kind(quiet(out / "results.jsonl"), "eval")
    assert sorted(r["checkpoint"] for r in evals) == ["last", "step:2", "step:4"]
    assert {r["checkpoint_step"] for r in evals} == {2, 4, 6} and {r["split"] for r in evals} == {"test"}
    finish("report", str(out / "results.jsonl"))
    md = (out / "report" / "report.md").read_text()
    assert "Learning curves" in md and "step 2" in md and "step 6" in md
    assert (out / "report" / "learning_curves.png").is_file()
    again = finish("run", str(grid), "--out", str(out))
    assert "1 already trained, 0 to train" in again and "3 of 3 test evaluations done" in again
    grid.write_text(grid.read_text().replace("eval_checkpoints: [2, 4]", "eval_checkpoints: [2, 3, 4]"))
    later = finish("run", str(grid), "--out", str(out))
    assert "kept no checkpoint at steps [3] of eval_checkpoints" in later and "3 of 3 test evaluations done" in later
    assert "\ntrained " not in later and len(by_kind(quiet(out / "results.jsonl"), "eval")) == 3
