"""The output rule (`lerobot_obsbench.outputs`) for `obsbench eval --videos` and `obsbench report --out / --json`:
a command regenerates its own earlier output of the same inputs in place, recognised by content; it replaces
anything else only with --overwrite, and then does."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from lerobot_obsbench.cli import main
from lerobot_obsbench.outputs import OUTPUTS_RECORD
from tests.commands import bad_inputs_outputs as rows


def _report(results: Path, out: Path, summary: Path, *options: str) -> list[str]:
    return ["report", str(results), "--out", str(out), "--json", str(summary), *options]


def test_report_regenerates_its_own_files_and_replaces_others_only_with_overwrite(tmp_path, capsys):
    results = rows._results(tmp_path)
    out, summary = tmp_path / "report", tmp_path / "summary.json"
    assert main(_report(results, out, summary)) == 0
    written = {p.name: p.read_bytes() for p in out.iterdir()}
    assert {"report.md", "report.html", "success_by_task.png", OUTPUTS_RECORD} <= set(written)
    assert main(_report(results, out, summary, "--title", "again")) == 0  # its own files, regenerated in place
    assert "# again" in (out / "report.md").read_text()
    capsys.readouterr()

    (out / "report.md").write_text("# edited by hand\n")  # no longer what the report wrote
    assert main(_report(results, out, summary)) == 2
    assert "already holds report.md" in capsys.readouterr().err
    assert (out / "report.md").read_text() == "# edited by hand\n"
    assert main(_report(results, out, summary, "--overwrite")) == 0
    assert (out / "report.md").read_text().startswith("# OBSBench report")

    other = tmp_path / "other" / "results.jsonl"  # another results store's report may not replace this one
    other.parent.mkdir()
    shutil.copy(results, other)
    before = summary.read_bytes()
    assert main(_report(other, out, tmp_path / "other" / "summary.json")) == 2
    assert "--out" in capsys.readouterr().err
    assert main(_report(other, tmp_path / "other" / "report", summary)) == 2
    assert "--json" in capsys.readouterr().err and summary.read_bytes() == before
    assert main(_report(other, tmp_path / "other" / "report", summary, "--overwrite")) == 0


def test_eval_videos_check_lets_its_own_videos_through_and_overwrite_through_any(tmp_path, capsys):
    """The check alone (the checkpoint does not exist, so the run then stops on it, not on the videos)."""
    argv = rows._eval_with_videos(tmp_path)
    rows._videos_of(tmp_path, rows.CHECKPOINT)  # an earlier evaluation of the same checkpoint, task, perturbation
    assert main(argv) == 2
    assert "--videos" not in capsys.readouterr().err
    (tmp_path / "v" / f"{rows.TASK}_seed0.mp4").write_bytes(b"my own video")
    assert main(argv) == 2
    assert "--videos" in capsys.readouterr().err
    assert main([*argv, "--overwrite"]) == 2
    assert "--videos" not in capsys.readouterr().err


def _blind_checkpoint(root: Path) -> Path:
    """A blind obs_act checkpoint of the simulator's state and action sizes (untrained: only its videos matter)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_obsbench.envs.maniskill import ACTION_DIMS, DEFAULT_CONTROL_MODE, STATE_DIM
    from tests.support.helpers import training_setup

    action_dim = ACTION_DIMS[DEFAULT_CONTROL_MODE]
    features = {
        "observation.state": {"dtype": "float32", "shape": (STATE_DIM,), "names": None},
        "action": {"dtype": "float32", "shape": (action_dim,), "names": None},
    }
    dataset = LeRobotDataset.create("local/blind", fps=20, features=features, root=root / "ds", use_videos=False)
    rng = np.random.default_rng(0)
    for _ in range(4):
        state, action = rng.normal(size=STATE_DIM), rng.normal(size=action_dim)
        dataset.add_frame(
            {"observation.state": state.astype(np.float32), "action": action.astype(np.float32), "task": "t"}
        )
    dataset.save_episode()
    dataset.finalize()
    policy, pre, post, _ = training_setup("obs_act", "none", root / "ds")
    for part in (policy, pre, post):
        part.save_pretrained(root / "pretrained_model")
    return root / "pretrained_model"


@pytest.mark.slow
def test_eval_writes_its_videos_again_and_another_evaluations_only_with_overwrite(tmp_path, capsys):
    """Real evaluations into one --videos folder: the same one again is allowed (its videos are rewritten), the
    same checkpoint with another episode budget is refused before the simulator starts (it used to replace them),
    and --overwrite lets it write."""
    checkpoint, videos = _blind_checkpoint(tmp_path), tmp_path / "videos"
    argv = ["eval", "--policy.path", str(checkpoint), "--env.task", rows.TASK, "--episodes", "2"]
    argv += ["--env.episode_length", "3", "--eval.batch_size", "1", "--videos", str(videos)]
    names = [f"{rows.TASK}_seed0.mp4", f"{rows.TASK}_seed1.mp4"]
    assert main(argv) == 0
    first = json.loads((videos / OUTPUTS_RECORD).read_text())["files"]
    assert sorted(first) == names and all(entry["perturbation"] == "none" for entry in first.values())
    (videos / names[0]).unlink()  # rewritten by the second run
    assert main(argv) == 0
    assert (videos / names[0]).stat().st_size > 0
    capsys.readouterr()

    longer = [*argv[: argv.index("3")], "4", *argv[argv.index("3") + 1 :]]  # --env.episode_length 4
    before = {name: (videos / name).read_bytes() for name in names}
    assert main(longer) == 2
    assert "--videos" in capsys.readouterr().err
    assert {name: (videos / name).read_bytes() for name in names} == before
    assert main([*longer, "--overwrite"]) == 0
    record = json.loads((videos / OUTPUTS_RECORD).read_text())["files"]
    assert all(record[name]["episode_length"] == 4 for name in names)
