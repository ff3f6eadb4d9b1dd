"""The results store: JSON lines, one record per finished unit of work, appended by one writer (the grid's
driver).

- `{"kind": "train", "run_id", "config", "method", "task", "train_steps", "samples", "checkpoints": {step:
  path}, "checkpoint" (the last), "timings", "versions", "machine", "device", "finished_at"}` — one per trained
  run; a run trained again because its checkpoints were gone (`"retrained": true`) replaces its earlier record;
- `{"kind": "eval", "eval_id", "run_id", "checkpoint" ("last" | "best" | "step:N"), "checkpoint_step", "split"
  ("test" | "validation"), "perturbation", "episodes", "successes", "success_rate", "ci95", "sub_success",
  "episode_length_mean", "per_seed", "max_steps", ...}` — one per evaluation of a run's checkpoint.

Each record is one line, flushed and fsynced before the next is announced, so a kill leaves at most a truncated
last line. Reading reports every unreadable line with its line number and skips it (its work simply runs
again), instead of dropping it silently. Files written by lerobot-obsbench 0.1 (one record per run holding its
evaluations) are refused with the command that converts them (`obsbench convert-results`).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
from pathlib import Path

from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.outputs import write_text_atomic

RESULTS_FILE = "results.jsonl"  # OUT/results.jsonl of a grid run
KINDS = ("train", "eval")
REQUIRED = {
    "train": ("run_id", "config", "method", "task", "checkpoint"),
    "eval": ("eval_id", "run_id", "checkpoint", "split", "perturbation", "episodes", "successes"),
}
# run-config fields the report places a run by (its table, column and training seed), with their types
CONFIG_FIELDS = {"task": str, "policy": str, "obs_space": str, "encoder": str, "seed": int, "demos": int}
# fields of a 0.1 record's config that described its evaluations, not its training
V1_EVAL_FIELDS = ("eval_episodes", "perturbations")


class ResultsFormatError(ObsBenchError, ValueError):
    """A results file in a format this version does not read."""


def read_results(path: Path, warn=None) -> list[dict]:
    """Records of `path` (missing file: none). Bad lines are reported through `warn` (default: stderr)."""
    warn = warn or (lambda message: print(message, file=sys.stderr))
    path = Path(path)
    if not path.is_file():
        return []
    records, seen, duplicates = [], set(), []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as err:
            warn(
                f"{path}:{number}: corrupted results line skipped ({err.msg} at column {err.colno}); "
                "its work will be redone"
            )
            continue
        if not isinstance(record, dict):
            warn(f"{path}:{number}: results line is {json.dumps(record)[:40]}, not a record (a JSON object): skipped")
            continue
        if "kind" not in record and "evaluations" in record:
            raise ResultsFormatError(
                f"{path} was written by lerobot-obsbench 0.1 (one record per run with its evaluations). Convert it "
                f"once, keeping every checkpoint and evaluation: obsbench convert-results {path}"
            )
        missing = [k for k in REQUIRED.get(record.get("kind"), ("kind",)) if k not in record]
        if missing:
            warn(f"{path}:{number}: results line without {missing} skipped")
            continue
        problem = impossible_counts(record) if record["kind"] == "eval" else config_problem(record["config"])
        if problem:
            redone = "its evaluation" if record["kind"] == "eval" else "its run"
            warn(f"{path}:{number}: results line skipped: {problem}; {redone} will be redone")
            continue
        identity = (record["kind"], record["run_id"] if record["kind"] == "train" else record["eval_id"])
        if identity in seen and record.get("retrained") and identity[0] == "train":
            # a run trained again after its checkpoints were gone: its new record replaces the earlier one
            records = [
                r
                for r in records
                if (r["kind"], r.get("run_id"), r.get("eval_id")) != ("train", record["run_id"], None)
            ]
            records.append(record)
            continue
        if identity in seen:
            duplicates.append(number)
            continue
        seen.add(identity)
        records.append(record)
    if duplicates:  # one run counted twice would pass for two training seeds
        warn(
            f"{path}: {len(duplicates)} repeated record(s) skipped (lines {', '.join(map(str, duplicates[:5]))}"
            f"{', ...' if len(duplicates) > 5 else ''}: a run or evaluation id seen before, e.g. from concatenated "
            "files); the first of each is kept"
        )
    return records


def _whole(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def config_problem(config) -> str | None:
    """What makes a train record's run config unusable for the report (None: nothing): not a mapping, or one of
    `CONFIG_FIELDS` missing or of another type."""
    if not isinstance(config, dict):
        return f"config = {json.dumps(config)[:40]} is not a mapping of the run's settings"
    for name, kind in CONFIG_FIELDS.items():
        value = config.get(name)
        if not (_whole(value) if kind is int else isinstance(value, kind)):
            return f"config.{name} = {json.dumps(value)[:40]} is not a {'whole number' if kind is int else 'string'}"
    return None


def impossible_counts(record: dict) -> str | None:
    """What is impossible in an eval record's counts (None: nothing): episodes a whole number >= 1, successes a
    whole number in 0..episodes, success_rate (where given) a finite number in [0, 1], and the per-seed outcomes
    (where given) one per episode, as many successes as `successes` says."""
    episodes, successes = record["episodes"], record["successes"]
    if not _whole(episodes) or episodes < 1:
        return f"episodes = {episodes!r} is not a whole number >= 1"
    if not _whole(successes) or not 0 <= successes <= episodes:
        return f"successes = {successes!r} is not a whole number in 0..{episodes}"
    rate = record.get("success_rate")
    if rate is not None and not (
        isinstance(rate, (int, float)) and not isinstance(rate, bool) and math.isfinite(rate) and 0 <= rate <= 1
    ):
        return f"success_rate = {rate!r} is not a finite number in [0, 1]"
    outcomes = record.get("per_seed")
    if outcomes is not None:
        fields = outcomes if isinstance(outcomes, dict) else {}
        seeds, success, length = fields.get("seeds"), fields.get("success"), fields.get("length")
        if not (
            isinstance(seeds, list)
            and isinstance(length, list)
            and isinstance(success, str)
            and set(success) <= {"1", "."}
            and len(seeds) == len(success) == len(length) == episodes
        ):
            return f"per_seed is not {episodes} episodes' seeds, success ('1' or '.') and length"
        if success.count("1") != successes:
            return f"per_seed holds {success.count('1')} successes where successes = {successes}"
    return None


def append_result(path: Path, record: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    line = json.dumps(record, sort_keys=True) + "\n"
    with open(path, "a+b") as f:
        # A previous kill may have left a truncated line without its newline: start on a fresh line.
        if f.seek(0, os.SEEK_END):
            f.seek(-1, os.SEEK_END)
            if f.read(1) != b"\n":
                f.write(b"\n")
        f.write(line.encode())
        f.flush()
        os.fsync(f.fileno())


def by_kind(records: list[dict], kind: str) -> list[dict]:
    return [r for r in records if r["kind"] == kind]


def upgrade_v1(record: dict) -> list[dict]:
    """A 0.1 record -> its train record and one eval record per evaluation (the last checkpoint, test seeds,
    each task's own episode budget, which is what 0.1 ran)."""
    from lerobot_obsbench.bench.specs import EvalSpec, RunSpec
    from lerobot_obsbench.envs.catalog import task_record

    old = dict(record["config"])
    for key in V1_EVAL_FIELDS:
        old.pop(key, None)
    steps, epochs = old.pop("steps", None), old.pop("epochs", None)
    unit, budget = ("steps", steps) if steps is not None else ("frame_epochs", epochs)
    run = RunSpec.from_config({**old, "budget_unit": unit, "budget": budget})
    checkpoint = record["checkpoint"]
    train = {
        "kind": "train",
        "run_id": run.run_id,
        "config": run.config(),
        "method": run.method,
        "task": run.task,
        "train_steps": record["train_steps"],
        "samples": record["train_steps"] * run.batch_size,
        "checkpoint": checkpoint,
        "checkpoints": {str(record["train_steps"]): checkpoint},
        "timings": {"train_s": record.get("timings", {}).get("train_s")},
        "versions": record.get("versions", {}),
        "device": record.get("device"),
        "finished_at": record.get("finished_at"),
        "upgraded_from": record["run_id"],
    }
    evals = []
    for perturbation, summary in record["evaluations"].items():
        spec = EvalSpec(run.run_id, "last", "test", summary["episodes"], perturbation, task_record(run.task).max_steps)
        evals.append(
            {
                "kind": "eval",
                "eval_id": spec.eval_id,
                **spec.config(),
                "task": run.task,
                "method": run.method,
                "checkpoint_step": record["train_steps"],
                **summary,
            }
        )
    return [train, *evals]


def convert_v1(path: Path) -> Path:
    """Rewrite a 0.1 results file in the current format; the original is kept as `<name>.v1` (`.v1.2`, ... when
    an earlier backup is there: a backup is never replaced). A file with no 0.1 record is refused, unchanged."""
    path = Path(path)
    converted, old = [], 0
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            print(f"{path}:{number}: corrupted line dropped", file=sys.stderr)
            continue
        if not isinstance(record, dict):
            print(f"{path}:{number}: line that is not a record (a JSON object) dropped", file=sys.stderr)
            continue
        if "kind" in record:
            converted.append(record)
        else:
            converted += upgrade_v1(record)
            old += 1
    if not old:
        raise ResultsFormatError(f"{path} holds no lerobot-obsbench 0.1 records: nothing to convert (file unchanged)")
    backup = path.with_name(path.name + ".v1")
    copy = 1
    while backup.exists():  # an earlier conversion's backup is the only copy of its original
        copy += 1
        backup = path.with_name(f"{path.name}.v1.{copy}")
    shutil.copy2(path, backup)
    write_text_atomic(path, "".join(json.dumps(r, sort_keys=True) + "\n" for r in converted))
    return backup
