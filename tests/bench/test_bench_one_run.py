"""End to end on the simulator (slow): one run of a tiny grid, trained with stock lerobot-train and evaluated.

- a run killed mid-training resumes from its last checkpoint (LeRobot's training state) and trains the weights,
  and plays the episodes, of the same run trained straight through (so the same run on the same machine is
  bit-identical); a run killed mid-evaluation keeps its checkpoint; the records name the machine facts and CPU
  kernel pin they were made under;
- the best checkpoint is chosen on the validation seeds, and a learning curve is one run evaluated at its listed
  checkpoints, reused when run again.

The diagnostics on held-out demonstrations are read off test_bench_run.py's grid.
"""

from __future__ import annotations

import json
import platform
import shutil
from pathlib import Path

import pytest

from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.bench.results import by_kind
from lerobot_obsbench.bench.units import resumable_step
from tests.support.grid_cli import finish, kill, obsbench, one_run_grid, quiet, wait_for

pytestmark = pytest.mark.slow


def evaluation_running(out: Path) -> bool:
    """Whether an evaluation under `out` has started its episodes (it writes its .progress file then)."""
    return any(out.glob("runs/*/eval/*.progress"))


def test_killed_training_resumes_to_the_uninterrupted_run_and_evaluation_keeps_it(tmp_path):
    # rgb: the kills need a run that renders (an evaluation long enough to be killed in)
    grid = one_run_grid(
        tmp_path / "one.yaml",
        ("steps: 3", "steps: 80"),
        ("checkpoints: 1", "checkpoints: 8"),
        ("eval_episodes: 2", "eval_episodes: 4"),
        # one episode at a time, each of 50 steps: the kill as the evaluation starts lands well before its end
        ("episode_length: 10", "episode_length: 50\neval_batch_size: 1"),
        ("perturbations: [light:0.05]\n", ""),
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
    wait_for(lambda: evaluation_running(out), proc)
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
    assert len(by_kind(quiet(out / "results.jsonl"), "eval")) == 1
    # the same grid from nothing (the same recording), never killed: the same weights, byte for byte, and episodes
    straight = tmp_path / "straight"
    shutil.copytree(out / "demos", straight / "demos")
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


def test_the_best_checkpoint_is_chosen_on_validation_seeds_and_a_learning_curve_is_reused_when_run_again(tmp_path):
    """One run keeps its evenly spaced checkpoints (3, 6) and its learning curve's (`eval_checkpoints` 2 and 4), and
    no other it saved on the way. Every saved checkpoint is scored on the validation seeds (10000+); the test seeds
    then evaluate the last checkpoint, the best one (ties: the later; the last's record copied when they are the
    same) and the curve's, and the report draws the curve. Run again, the grid trains and evaluates nothing; a step
    listed after the run was trained is reported missing, with how to get it, not retrained."""
    grid = one_run_grid(
        tmp_path / "curve.yaml",
        ("obs_spaces: [rgb]\nencoders: {rgb: [spatial_softmax]}", "obs_spaces: [none]"),  # nothing to render
        ("steps: 3", "steps: 6\nvalidation_episodes: 2\neval_checkpoints: [2, 4]"),
        ("checkpoints: 1", "checkpoints: 2"),
        ("perturbations: [light:0.05]\n", ""),
    )
    out = tmp_path / "out"
    finish("run", str(grid), "--out", str(out))
    (train,) = by_kind(quiet(out / "results.jsonl"), "train")
    assert sorted(int(s) for s in train["checkpoints"]) == [2, 3, 4, 6]
    evals = by_kind(quiet(out / "results.jsonl"), "eval")
    validation = [r for r in evals if r["split"] == "validation"]
    assert sorted(r["checkpoint_step"] for r in validation) == [2, 3, 4, 6]
    assert all(r["per_seed"]["seeds"] == [10000, 10001] for r in validation)
    best_step = max((r["success_rate"], r["checkpoint_step"]) for r in validation)[1]
    tests = {r["checkpoint"]: r for r in evals if r["split"] == "test"}
    assert set(tests) == {"last", "best", "step:2", "step:4"}
    assert tests["last"]["checkpoint_step"] == 6 and tests["best"]["checkpoint_step"] == best_step
    assert tests["last"]["per_seed"]["seeds"] == [0, 1]
    if best_step == 6:
        assert tests["best"]["copied_from"] == tests["last"]["eval_id"]
        assert tests["best"]["per_seed"] == tests["last"]["per_seed"]
    else:
        assert "copied_from" not in tests["best"]
    finish("report", str(out / "results.jsonl"))
    md = (out / "report" / "report.md").read_text()
    assert "Learning curves" in md and "step 2" in md and "step 6" in md
    assert (out / "report" / "learning_curves.png").is_file()
    again = finish("run", str(grid), "--out", str(out))
    assert "1 already trained, 0 to train" in again and "4 of 4 test evaluations done" in again
    grid.write_text(grid.read_text().replace("eval_checkpoints: [2, 4]", "eval_checkpoints: [2, 4, 5]"))
    later = finish("run", str(grid), "--out", str(out))
    assert "kept no checkpoint at steps [5] of eval_checkpoints" in later and "4 of 4 test evaluations done" in later
    assert "\ntrained " not in later and len(by_kind(quiet(out / "results.jsonl"), "eval")) == len(evals)
