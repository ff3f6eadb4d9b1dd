"""From the results store's records to the report's columns: one view per trained run (the checkpoint shown),
each run's column label, the per-task Cells of a perturbation and demonstration count, and the curves over
perturbation values and demonstration counts."""

from __future__ import annotations

import json
from collections import defaultdict

from lerobot_obsbench.bench.report.statistics import Cell, ReportError
from lerobot_obsbench.envs.perturbations import parse_perturbation

# Run-config fields that never split a method's column: the method itself, the task (a row), the training seed
# (what a column pools) and the demonstration count (the sample-efficiency axis). Every other field changes what
# is trained, so where it differs between runs of one method it becomes part of the column label.
NOT_LABEL_FIELDS = ("task", "policy", "obs_space", "encoder", "seed", "demos")

CHECKPOINT_CHOICES = ("best", "last")


def run_views(records: list[dict], checkpoint: str = "best") -> list[dict]:
    """One view per trained run from the results store's train and eval records: its config plus
    `evaluations` {perturbation: eval record} of its test evaluations of `checkpoint` — "best" (the
    best-on-validation checkpoint, where the run has one; else its last) or "last". Each view notes which
    checkpoint it shows under "shown", and holds its learning curve under "curve": {step: nominal eval record} of
    the grid's `eval_checkpoints` and the last checkpoint (empty without those)."""
    if checkpoint not in CHECKPOINT_CHOICES:
        raise ReportError(f"checkpoint must be one of {CHECKPOINT_CHOICES}; got {checkpoint!r}")
    tests = defaultdict(dict)  # run_id -> checkpoint -> perturbation -> record
    for r in records:
        if r["kind"] == "eval" and r["split"] == "test":
            tests[r["run_id"]].setdefault(r["checkpoint"], {})[r["perturbation"]] = r
    views = []
    for r in records:
        if r["kind"] != "train" or r["run_id"] not in tests:
            continue
        shown = checkpoint if checkpoint in tests[r["run_id"]] else "last"
        if shown not in tests[r["run_id"]]:
            continue
        views.append(
            {
                "run_id": r["run_id"],
                "config": r["config"],
                "method": r["method"],
                "task": r["task"],
                "shown": shown,
                "evaluations": tests[r["run_id"]][shown],
                "diagnostics": r.get("diagnostics", {}),
                "curve": _curve(tests[r["run_id"]], r.get("train_steps")),
                "machine": r.get("machine"),
                "resumed_from": r.get("resumed_from"),
                "resumed_exactly": r.get("resumed_exactly", False),
            }
        )
    return views


def _curve(tests: dict[str, dict[str, dict]], last_step: int | None) -> dict[int, dict]:
    """{step: nominal test record} of a run's learning-curve checkpoints ("step:N") and, with them, its last."""
    curve = {
        int(checkpoint.removeprefix("step:")): by_perturbation["none"]
        for checkpoint, by_perturbation in tests.items()
        if checkpoint.startswith("step:") and "none" in by_perturbation
    }
    if curve and last_step is not None and "none" in tests.get("last", {}):
        curve[int(last_step)] = tests["last"]["none"]
    return dict(sorted(curve.items()))


def method_labels(records: list[dict]) -> dict[str, str]:
    """run_id -> column label: policy/space/encoder, plus every run-config field (but NOT_LABEL_FIELDS) that
    varies within that method on one task. A field that differs only from task to task (a task's own crop box)
    belongs to the task, so the method stays one column across tasks."""
    by_method = defaultdict(list)
    for r in records:
        by_method[r["method"]].append(r)
    labels = {}
    for method, group in by_method.items():
        fields = dict.fromkeys(f for g in group for f in g["config"] if f not in NOT_LABEL_FIELDS)
        by_task = defaultdict(list)
        for g in group:
            by_task[g["task"]].append(g)
        varying = [f for f in fields if any(_differs(runs, f) for runs in by_task.values())]
        for r in group:
            suffix = " ".join(f"{f}={_short(r['config'].get(f))}" for f in varying)
            labels[r["run_id"]] = f"{method} {suffix}".strip()
    return labels


def _differs(runs: list[dict], field: str) -> bool:
    return len({json.dumps(r["config"].get(field), sort_keys=True) for r in runs}) > 1


def _short(value) -> str:
    return f"{value:g}" if isinstance(value, float) else json.dumps(value) if isinstance(value, dict) else str(value)


def label_configs(records: list[dict]) -> dict[str, dict]:
    """column label -> the config of (one of) its runs."""
    labels = method_labels(records)
    return {labels[r["run_id"]]: r["config"] for r in records}


def labelled_runs(records: list[dict]) -> list[tuple[str, dict]]:
    """(column label, run view) of every run, by task, label and training seed: the order of the per-run tables."""
    labels = method_labels(records)
    ordered = sorted(records, key=lambda r: (r["task"], labels[r["run_id"]], r["config"]["seed"]))
    return [(labels[r["run_id"]], r) for r in ordered]


def most_demos(records: list[dict]) -> dict[str, int]:
    """task -> its largest demonstration count, the one the per-task tables show."""
    most = defaultdict(int)
    for r in records:
        most[r["task"]] = max(most[r["task"]], r["config"]["demos"])
    return dict(most)


def cells_by_task(
    records: list[dict], perturbation: str = "none", demos: int | None = None
) -> dict[str, dict[str, Cell]]:
    """{task: {label: Cell}}, one Cell per column holding each training seed's episodes; `demos` None = each
    task's largest demo count."""
    labels = method_labels(records)
    most = most_demos(records)
    runs: dict[str, dict[str, list[tuple[int, int]]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        wanted = most[r["task"]] if demos is None else demos
        evaluation = r["evaluations"].get(perturbation)
        if r["config"]["demos"] != wanted or evaluation is None:
            continue
        runs[r["task"]][labels[r["run_id"]]].append((evaluation["successes"], evaluation["episodes"]))
    return {t: {m: Cell(tuple(c)) for m, c in row.items()} for t, row in runs.items()}


def curve_cells(records: list[dict]) -> dict[str, dict[str, dict[int, Cell]]]:
    """{task: {label: {step: Cell}}} of the runs' learning curves (`run_views`' "curve"), at each task's largest
    demo count: one Cell per checkpoint step, holding every training seed's episodes at that step."""
    labels = method_labels(records)
    most = most_demos(records)
    found: dict[str, dict[str, dict[int, list]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for r in records:
        if r["config"]["demos"] == most[r["task"]]:
            for step, evaluation in r.get("curve", {}).items():
                found[r["task"]][labels[r["run_id"]]][step].append((evaluation["successes"], evaluation["episodes"]))
    return {
        task: {
            label: {step: Cell(tuple(runs)) for step, runs in sorted(by_step.items())} for label, by_step in row.items()
        }
        for task, row in found.items()
    }


def perturbations(records: list[dict]) -> list[str]:
    """The perturbations the runs were evaluated under, by kind and value."""
    names = {p for r in records for p in r["evaluations"] if p != "none"}
    return sorted(names, key=lambda name: (parse_perturbation(name).kind, parse_perturbation(name).value))


def paired_with_nominal(records: list[dict], perturbation: str) -> dict[str, dict[str, list[tuple[int, ...]]]]:
    """{task: {label: [(successes, episodes) under `perturbation` and unperturbed on the same test seeds
    (`nominal_on_seeds_of`), of each training seed evaluated under both]}} at each task's largest demo count."""
    labels = method_labels(records)
    most = most_demos(records)
    pairs: dict[str, dict[str, list[tuple[int, ...]]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        perturbed, nominal = r["evaluations"].get(perturbation), r["evaluations"].get("none")
        if r["config"]["demos"] != most[r["task"]] or perturbed is None or nominal is None:
            continue
        pairs[r["task"]][labels[r["run_id"]]].append(
            (perturbed["successes"], perturbed["episodes"], *nominal_on_seeds_of(nominal, perturbed))
        )
    return {task: dict(row) for task, row in pairs.items()}


def nominal_on_seeds_of(nominal: dict, perturbed: dict) -> tuple[int, int]:
    """(successes, episodes) of the `nominal` evaluation on the test seeds `perturbed` ran (`nominal_prefix`), so a
    share kept compares the same episodes; the whole nominal evaluation where that cannot be told."""
    first = nominal_prefix(nominal.get("per_seed"), perturbed.get("per_seed"))
    if first is None:
        return nominal["successes"], nominal["episodes"]
    return first["success"].count("1"), len(first["seeds"])


def nominal_prefix(nominal: dict | None, changed: dict | None) -> dict | None:
    """The per-seed outcomes (`per_seed`) of a nominal evaluation on the seeds a changed one ran — the first of them
    (`perturbed_episodes`) — or None where either lacks per-seed outcomes or the seeds are not its first ones."""
    if nominal is None or changed is None:
        return None
    n = len(changed["seeds"])
    if nominal["seeds"][:n] != changed["seeds"]:
        return None
    return {k: nominal[k][:n] for k in ("seeds", "success", "length")}


def demo_counts(records: list[dict]) -> list[int]:
    """The demonstration counts of a sample-efficiency grid (none when every run trains on the same number)."""
    counts = sorted({r["config"]["demos"] for r in records})
    return counts if len(counts) > 1 else []


def demo_cells(records: list[dict]) -> dict[int, dict[str, dict[str, Cell]]]:
    """{demonstration count: {task: {label: Cell}}} of the nominal evaluations over `demo_counts`."""
    return {n: cells_by_task(records, "none", demos=n) for n in demo_counts(records)}
