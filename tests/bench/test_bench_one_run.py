"""End to end on the simulator (slow): one run of a tiny grid, trained with stock lerobot-train and evaluated.

- a run killed mid-training resumes from its last checkpoint (LeRobot's training state) and trains the weights,
  and plays the episodes, of the same run trained straight through; a run killed mid-evaluation keeps its
  checkpoint; the records name the machine facts and CPU kernel pin they were made under;
- the best checkpoint is chosen on the validation seeds;
- a run records its diagnostics on held-out demonstrations, and the report shows them;
- the same run trains bit-identical weights on the same machine;
- a learning curve is one run evaluated at its listed checkpoints, and is reused when run again.
"""

from __future__ import annotations

import contextlib
import json
import platform
import re
from pathlib import Path

import pytest

from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.results import by_kind
from lerobot_obsbench.bench.units import resumable_step
from tests.support.grid_cli import finish, kill, obsbench, one_run_grid, quiet, wait_for

pytestmark = pytest.mark.slow


def evaluated_episodes(out: Path) -> int:
    """Episodes finished by the evaluations running under `out` (whatever their count: a poll can miss a step)."""
    done = 0
    for path in out.glob("runs/*/eval/*.progress"):
        with contextlib.suppress(FileNotFoundError):  # an evaluation that ends removes its progress file
            done = max(done, json.loads(path.read_text())["done"])
    return done


def test_killed_training_resumes_to_the_uninterrupted_run_and_evaluation_keeps_it(tmp_path):
    # rgb: the kills need a run that renders (an evaluation long enough to be killed in)
    grid = one_run_grid(
        tmp_path / "one.yaml",
        ("steps: 3", "steps: 80"),
        ("checkpoints: 1", "checkpoints: 8"),
        ("eval_episodes: 2", "eval_episodes: 4"),
        # one episode at a time, each of 50 steps: the kill after the first episode lands well before the last
        ("episode_length: 10", "episode_length: 50\neval_batch_size: 1"),
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
    # the same grid from nothing, never killed: the same weights, byte for byte, and the same episodes
    straight = tmp_path / "straight"
    finish("run", str(grid), "--out", str(straight))
    (uninterrupted,) = by_kind(quiet(straight / "results.jsonl"), "train")
    assert uninterrupted["resumed_from"] is None and train["resumed_exactly"] is True
    weights = [Path(r["checkpoint"], "model.safetensors").read_bytes() for r in (train, uninterrupted)]
    assert weights[0] == weights[1]
    episodes = [
        {r["eval_id"]: r["per_seed"] for r in by_kind(quiet(o / "results.jsonl"), "eval")} for o in (out, straight)
    ]
    assert episodes[0] == episodes[1]
    # every record names the facts it was made under, the kernel pin among them (x86-64: AVX2 by default)
    for record in quiet(straight / "results.jsonl"):
        facts = record["machine"]
        assert {"cpu_capability", "cpu", "torch", "threads"} <= set(facts) and facts["threads"] >= 1
        if platform.machine() == "x86_64":
            assert facts["cpu_capability"] == "AVX2" and facts["pins"]["ATEN_CPU_CAPABILITY"] == "avx2"


def test_best_checkpoint_is_chosen_on_the_validation_seeds(tmp_path):
    """Every saved checkpoint is scored on the validation seeds (10000+); the test seeds then evaluate the last
    checkpoint and the best one (ties: the later); when they are the same checkpoint the record is copied."""
    grid = one_run_grid(
        tmp_path / "select.yaml",
        ("obs_spaces: [rgb]\nencoders: {rgb: [spatial_softmax]}", "obs_spaces: [none]"),  # nothing to render
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
        ("obs_spaces: [rgb]\nencoders: {rgb: [spatial_softmax]}", "obs_spaces: [pointcloud]"),
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
        ("obs_spaces: [rgb]\nencoders: {rgb: [spatial_softmax]}", "obs_spaces: [none]"),
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
