"""Rows of the bad-input table (`tests/commands/test_bad_inputs.py`) for outputs: each `(setup, fragments)`, where
`setup(root) -> argv` builds its inputs in a fresh folder and `fragments` are what the one error line must hold.

An output that would replace a file the command did not write (or another evaluation's or report's file, or its own
file edited since) is refused with --overwrite named; a dataset's calibration file that cannot be read is refused by
`attach-calibration` with --overwrite named, and by the commands that read it with the command that replaces it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tests.support import stock_depth_scene as scene

TASK = "PushCube-v1"
CHECKPOINT = "/nonexistent/pretrained_model"  # never read: the outputs are checked first


def _eval_with_videos(root: Path) -> list[str]:
    return ["eval", "--policy.path", CHECKPOINT, "--env.task", TASK, "--episodes", "2", "--videos", str(root / "v")]


def _videos_of(root: Path, checkpoint: str, perturbation: str | None = None, episode_length: int | None = None) -> None:
    """The two episodes' videos as `obsbench eval` writes them (its own writer) for `checkpoint`."""
    from lerobot_obsbench.envs.evaluate import _write_videos, videos_made_by

    frames = [np.full((32, 32, 3), shade, np.uint8) for shade in (0, 128, 255)]
    records = {seed: {"frames": list(frames)} for seed in (0, 1)}
    made_by = videos_made_by(checkpoint, TASK, perturbation, episode_length)
    _write_videos(root / "v", TASK, [0, 1], records, made_by, fps=20)


def eval_videos_over_files_it_did_not_write(root: Path) -> list[str]:
    """Used to replace them after the episodes ran."""
    (root / "v").mkdir()
    (root / "v" / f"{TASK}_seed0.mp4").write_bytes(b"last week's video")
    return _eval_with_videos(root)


def eval_videos_over_another_checkpoints_videos(root: Path) -> list[str]:
    """Used to replace the earlier evaluation's videos."""
    _videos_of(root, str(root / "other" / "pretrained_model"))
    return _eval_with_videos(root)


def eval_videos_over_another_perturbations_videos(root: Path) -> list[str]:
    _videos_of(root, CHECKPOINT, perturbation="camera_yaw:10")
    return _eval_with_videos(root)


def eval_videos_over_another_episode_budgets_videos(root: Path) -> list[str]:
    """Used to replace them when only --env.episode_length differed."""
    _videos_of(root, CHECKPOINT, episode_length=20)
    return _eval_with_videos(root)


def eval_videos_over_its_own_video_edited_since(root: Path) -> list[str]:
    """Its own file is recognised by content, not by name: once edited it is no longer the command's."""
    _videos_of(root, CHECKPOINT)
    (root / "v" / f"{TASK}_seed1.mp4").write_bytes(b"trimmed by hand")
    return _eval_with_videos(root)


def _results(root: Path) -> Path:
    config = {"task": "T", "policy": "act", "obs_space": "rgb", "encoder": "resnet18", "seed": 1, "demos": 10}
    train = {"kind": "train", "run_id": "r", "config": config, "method": "m", "task": "T", "checkpoint": "c"}
    test = {"eval_id": "e", "run_id": "r", "checkpoint": "last", "split": "test", "perturbation": "none"}
    evaluation = {"kind": "eval", **test, "episodes": 50, "successes": 3}
    (root / "results.jsonl").write_text(json.dumps(train) + "\n" + json.dumps(evaluation) + "\n")
    return root / "results.jsonl"


def report_json_over_a_file_it_did_not_write(root: Path) -> list[str]:
    """Used to be replaced by the summary (exit 0)."""
    (root / "summary.json").write_text('{"my": "notes"}\n')
    return ["report", str(_results(root)), "--out", str(root / "report"), "--json", str(root / "summary.json")]


def report_json_over_the_report_it_writes(root: Path) -> list[str]:
    """Used to write report.md, then replace it with the summary (exit 0)."""
    return ["report", str(_results(root)), "--out", str(root / "report"), "--json", str(root / "report" / "report.md")]


def report_out_over_a_report_it_did_not_write(root: Path) -> list[str]:
    """Used to replace report.md (exit 0)."""
    (root / "report").mkdir()
    (root / "report" / "report.md").write_text("# my own write-up\n")
    return ["report", str(_results(root)), "--out", str(root / "report")]


def _stock_dataset_with_calibration_file(root: Path, content: str) -> Path:
    dataset = scene.write_stock_dataset(root / "koch_pick", video=False, episodes=1, frames=2)
    (dataset / "meta" / "obsbench_cameras.json").write_text(content)
    return dataset


def _attach(root: Path, content: str) -> list[str]:
    dataset = _stock_dataset_with_calibration_file(root, content)
    calibration = scene.write_calibration_json(root / "front.json")
    return ["attach-calibration", "--root", str(dataset), "--camera", "front", "--from-json", str(calibration)]


def attach_calibration_over_a_truncated_file(root: Path) -> list[str]:
    """Used to say 'write it again with obsbench attach-calibration', which refused the same way."""
    return _attach(root, '{"version": 1, "cameras": {"front": {"color_si')


def attach_calibration_over_an_empty_file(root: Path) -> list[str]:
    return _attach(root, "")


def attach_calibration_over_a_list(root: Path) -> list[str]:
    return _attach(root, "[]")


def attach_calibration_over_another_layout(root: Path) -> list[str]:
    return _attach(root, '{"front": 5}')


def attach_calibration_over_another_format_version(root: Path) -> list[str]:
    """Used to be rewritten as version 1 (exit 0), losing what the other version held."""
    return _attach(root, '{"version": 2, "cameras": {}}')


def validate_a_truncated_calibration_file(root: Path) -> list[str]:
    """Used to name `obsbench attach-calibration`, which refused the same file."""
    dataset = _stock_dataset_with_calibration_file(root, '{"version": 1, "cam')
    return ["validate", "--root", str(dataset), "--quick"]


def validate_a_camera_entry_that_is_not_an_object(root: Path) -> list[str]:
    """Used to end in a TypeError traceback."""
    dataset = _stock_dataset_with_calibration_file(root, '{"version": 1, "cameras": {"front": 5}}')
    return ["validate", "--root", str(dataset), "--quick"]


REPLACE = "add --overwrite to replace the file (what it holds is lost), or delete it"
ROWS: list = [
    (eval_videos_over_files_it_did_not_write, ["--videos", f"{TASK}_seed0.mp4", "not this command's own output"]),
    (eval_videos_over_another_checkpoints_videos, ["--videos", f"{TASK}_seed0.mp4, {TASK}_seed1.mp4", "--overwrite"]),
    (eval_videos_over_another_perturbations_videos, ["--videos", "not this command's own output", "--overwrite"]),
    (eval_videos_over_another_episode_budgets_videos, ["--videos", "not this command's own output", "--overwrite"]),
    (eval_videos_over_its_own_video_edited_since, ["--videos", f"already holds {TASK}_seed1.mp4,", "--overwrite"]),
    (report_json_over_a_file_it_did_not_write, ["--json", "summary.json already exists and is not this command's"]),
    (report_out_over_a_report_it_did_not_write, ["--out", "already holds report.md", "add --overwrite"]),
    (report_json_over_the_report_it_writes, ["--json", "the report writes report.md in --out", "summary.json"]),
    (attach_calibration_over_a_truncated_file, ["obsbench_cameras.json: cannot be read as JSON", REPLACE]),
    (attach_calibration_over_an_empty_file, ["obsbench_cameras.json: cannot be read as JSON", REPLACE]),
    (attach_calibration_over_a_list, ['expected {"version": 1, "cameras": {name: calibration}}, found []', REPLACE]),
    (attach_calibration_over_another_layout, ['found {"front": 5}', REPLACE]),
    (attach_calibration_over_another_format_version, ["format version 2, but this plugin reads format version 1"]),
    (
        validate_a_truncated_calibration_file,
        [
            "cannot be read as JSON",
            "replace it (what it holds is lost): obsbench attach-calibration --root",
            "--overwrite",
        ],
    ),
    (
        validate_a_camera_entry_that_is_not_an_object,
        ["camera 'front': expected an object of fields", "attach it again: obsbench attach-calibration --root"],
    ),
]
