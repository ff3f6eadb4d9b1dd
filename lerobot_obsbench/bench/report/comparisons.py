"""Comparisons between columns, to check that a method uses what it sees: its interval against the blind
control's, its rate between the blind and oracle controls, its episodes seed by seed against the nominal
evaluation, and rliable's aggregates over training seeds with its probability of improvement over the blind
control (or a chosen reference column)."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from functools import cached_property

from lerobot_obsbench.bench import aggregates
from lerobot_obsbench.bench.report.runs import (
    label_configs,
    method_labels,
    most_demos,
    nominal_prefix,
    paired_with_nominal,
)
from lerobot_obsbench.bench.report.statistics import Cell, ReportError
from lerobot_obsbench.schema import available_spaces, space_info
from lerobot_obsbench.stats import mean_over_tasks_interval, relative_success

# Marks of a seeing method whose 95% interval lies above its blind control's.
ABOVE_ACROSS_SEEDS = "▲"  # both rest on >= 2 training seeds: the intervals cover training variance
ABOVE_ONE_SEED = "△"  # one side rests on one training seed: its interval covers evaluation episodes only


def control_kind(obs_space: str) -> str:
    """ "blind" or "oracle" for a control space, "" for a seeing space or one this process has not registered (a
    results file may hold spaces another installation registered)."""
    return space_info(obs_space).control if obs_space in available_spaces() else ""


def _control_labels(labels, configs: dict[str, dict], kind: str, policy: str) -> list[str]:
    """The column labels among `labels` of a `kind` control ("blind" / "oracle") and policy type `policy`."""
    return [m for m in labels if control_kind(configs[m]["obs_space"]) == kind and configs[m]["policy"] == policy]


def _controls(row: dict[str, Cell], configs: dict[str, dict], kind: str, policy: str) -> list[Cell]:
    """The cells of one task's row of a `kind` control ("blind" / "oracle") and policy type `policy`."""
    return [row[m] for m in _control_labels(row, configs, kind, policy)]


def beats_blind(records: list[dict], cells: dict[str, dict[str, Cell]]) -> dict[str, dict[str, dict]]:
    """{task: {label: {"above": interval above the blind control's, "mark": ▲ / △ / "", "seeds": training seeds
    of the method, "blind_seeds": of the control}}} for methods that have a blind control of their policy type on
    that task (the one with the highest upper bound when there are several). ▲ needs at least two training
    seeds on both sides; a comparison resting on one seed is at most △."""
    configs = label_configs(records)
    out: dict[str, dict[str, dict]] = {}
    for task, row in cells.items():
        for method, cell in row.items():
            if control_kind(configs[method]["obs_space"]) == "blind":
                continue
            controls = _controls(row, configs, "blind", configs[method]["policy"])
            if not controls:
                continue
            blind = max(controls, key=lambda c: c.ci95[1])
            above = cell.ci95[0] > blind.ci95[1]
            across_seeds = min(cell.seeds, blind.seeds) >= 2
            mark = (ABOVE_ACROSS_SEEDS if across_seeds else ABOVE_ONE_SEED) if above else ""
            out.setdefault(task, {})[method] = {
                "above": above,
                "mark": mark,
                "seeds": cell.seeds,
                "blind_seeds": blind.seeds,
            }
    return out


def control_brackets(records: list[dict], cells: dict[str, dict[str, Cell]]) -> dict[str, dict[str, dict]]:
    """{task: {label: {"blind", "oracle", "rate", "gain_fraction"}}} for seeing methods with both controls of their
    policy type on the task (the best-scoring control of each kind): gain_fraction = (rate - blind) / (oracle -
    blind), None when the oracle does not beat blind (nothing to recover)."""
    configs = label_configs(records)
    out: dict[str, dict[str, dict]] = {}
    for task, row in cells.items():
        for method, cell in row.items():
            policy = configs[method]["policy"]
            if control_kind(configs[method]["obs_space"]):
                continue
            best = {}
            for kind in ("blind", "oracle"):
                controls = _controls(row, configs, kind, policy)
                best[kind] = max(c.rate for c in controls) if controls else None
            if best["blind"] is None or best["oracle"] is None:
                continue
            gain = best["oracle"] - best["blind"]
            fraction = (cell.rate - best["blind"]) / gain if gain > 0 else None
            out.setdefault(task, {})[method] = {**best, "rate": cell.rate, "gain_fraction": fraction}
    return out


@dataclass
class Agreement:
    """Seed-by-seed comparison of an evaluation-only change with the nominal evaluation of the same checkpoints."""

    changed: Cell  # successes under the change
    nominal: Cell
    same_outcome: int  # episodes whose success / failure is the nominal one
    identical: int  # episodes with the nominal outcome and length


def agreements(records: list[dict]) -> dict[tuple[str, str, str], Agreement]:
    """{(task, label, perturbation): Agreement}, pooling the runs of each label (largest demo count)."""
    labels = method_labels(records)
    most = most_demos(records)
    # per key: each run's (successes, episodes) changed and nominal, then the episode counts pooled
    changed_runs, nominal_runs = defaultdict(list), defaultdict(list)
    same, identical = defaultdict(int), defaultdict(int)
    for r in records:
        nominal = r["evaluations"].get("none", {}).get("per_seed")
        if r["config"]["demos"] != most[r["task"]] or nominal is None:
            continue
        for name, evaluation in r["evaluations"].items():
            changed = evaluation.get("per_seed")
            # a perturbed evaluation runs the nominal's test seeds or the first of them (`perturbed_episodes`)
            first = nominal_prefix(nominal, changed)
            if name == "none" or first is None:
                continue
            pairs = list(zip(first["success"], changed["success"], first["length"], changed["length"], strict=True))
            key = (r["task"], labels[r["run_id"]], name)
            changed_runs[key].append((changed["success"].count("1"), len(pairs)))
            nominal_runs[key].append((first["success"].count("1"), len(pairs)))
            same[key] += sum(a == b for a, b, _, _ in pairs)
            identical[key] += sum(a == b and la == lb for a, b, la, lb in pairs)
    return {
        key: Agreement(Cell(tuple(changed_runs[key])), Cell(tuple(nominal_runs[key])), same[key], identical[key])
        for key in sorted(changed_runs)
    }


Estimate = tuple[float, float, float]  # point, low, high


@dataclass(frozen=True)
class SeedAggregates:
    """rliable's Mean S.R. and IQM of every column with scores on every task, and its probability of
    improvement over its blind control and over the reference column: {label: (other label, estimate)}, the
    estimate None where both rest on one training seed."""

    estimates: dict[str, dict]
    over_blind: dict[str, tuple[str, Estimate | None]]
    over_reference: dict[str, tuple[str, Estimate | None]]
    left_out: dict[str, str]  # label -> why it has no aggregates

    @cached_property
    def pairs(self) -> dict[tuple[str, str], Estimate]:
        """{(label, other label): estimate} of every probability of improvement that is an estimate."""
        return {
            (x, y): e
            for found in (self.over_blind, self.over_reference)
            for x, (y, e) in found.items()
            if e is not None
        }


def seed_aggregates(
    records: list[dict], cells: dict[str, dict[str, Cell]], reference: str | None = None
) -> SeedAggregates:
    """Mean S.R. and IQM over training seeds and tasks with stratified bootstrap intervals, and each method's
    probability of improvement over its blind control (same policy type) and over `reference` (a column label)."""
    scores, left_out = aggregates.seed_scores(cells)
    if reference is not None and reference not in scores:
        known = ", ".join(sorted(scores)) or "none"
        why = f" ({left_out[reference]})" if reference in left_out else ""
        raise ReportError(f"--reference {reference!r} is not a column with scores on every task{why}; columns: {known}")
    estimates = aggregates.aggregate_estimates(scores)
    configs = label_configs(records)
    over_blind, over_reference = {}, {}
    for label in sorted(scores):
        if control_kind(configs[label]["obs_space"]) != "blind":
            blinds = _control_labels(scores, configs, "blind", configs[label]["policy"])
            if blinds:
                blind = max(blinds, key=lambda m: estimates[m]["mean_sr"][0])
                over_blind[label] = (blind, aggregates.improvement_estimate(scores[label], scores[blind]))
        if reference is not None and label != reference:
            over_reference[label] = (reference, aggregates.improvement_estimate(scores[label], scores[reference]))
    return SeedAggregates(estimates, over_blind, over_reference, left_out)


ALL_TASKS = "all tasks"  # the aggregate's key beside the tasks'


def robustness(records: list[dict], names: list[str]) -> dict[str, dict[str, dict[str, tuple | None]]]:
    """{perturbation: {task, and ALL_TASKS: {label: (point, low, high) or None}}}: the share of its unperturbed
    success each column keeps under each of `names` (`stats.relative_success`, intervals over training seeds and
    episodes); the aggregate over the tasks where the column was evaluated under it. None: the column never succeeds
    unperturbed there."""
    out = {}
    for name in names:
        pairs = paired_with_nominal(records, name)
        found = {
            task: {label: relative_success([seeds]) for label, seeds in row.items()} for task, row in pairs.items()
        }
        labels = sorted({label for row in pairs.values() for label in row})
        found[ALL_TASKS] = {
            label: relative_success([row[label] for row in pairs.values() if label in row]) for label in labels
        }
        out[name] = found
    return out


def demo_curves(demo_cells: dict[int, dict[str, dict[str, Cell]]]) -> dict[str, dict[str, dict[int, tuple]]]:
    """{task, and ALL_TASKS: {label: {demonstrations: (success rate, low, high)}}} over the demonstration counts,
    intervals over training seeds and episodes; the aggregate is the mean over the tasks that have the column at
    every count (`stats.mean_over_tasks_interval`)."""
    out: dict[str, dict[str, dict[int, tuple]]] = defaultdict(lambda: defaultdict(dict))
    for n, cells in sorted(demo_cells.items()):
        for task, row in cells.items():
            for label, cell in row.items():
                out[task][label][n] = (cell.rate, *cell.ci95)
    counts = sorted(demo_cells)
    labels = sorted({label for cells in demo_cells.values() for row in cells.values() for label in row})
    for label in labels:
        tasks = [t for t in out if t != ALL_TASKS and all(label in demo_cells[n].get(t, {}) for n in counts)]
        for n in counts if tasks else ():
            out[ALL_TASKS][label][n] = mean_over_tasks_interval([list(demo_cells[n][t][label].runs) for t in tasks])
    return {task: dict(row) for task, row in out.items()}
