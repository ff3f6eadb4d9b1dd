"""The report's tables: the Section dataclass (a table with the summary, checks and notes it adds to the report)
and one builder per section, each taking the ReportData and returning its Section, or None when it has nothing
to show."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot_obsbench.bench import aggregates
from lerobot_obsbench.bench.machine import fingerprint
from lerobot_obsbench.bench.report.comparisons import ALL_TASKS, agreements, beats_blind, control_brackets
from lerobot_obsbench.bench.report.data import ReportData
from lerobot_obsbench.bench.report.published import paper_row
from lerobot_obsbench.bench.report.statistics import Cell, mean_over_tasks, summarize

Entry = tuple[str, str | None]  # a cell's text and its mark: "best", "second" or None
Row = tuple[str, list[Entry]]  # the first column's text (a task, a method) and the row's other cells

CHECKPOINT_TEXT = {
    "best": "best on the validation seeds (10000+, disjoint from the test seeds)",
    "last": "the last checkpoint",
}


@dataclass(frozen=True)
class Section:
    """One table of the report, and what it adds to the report: `summary` {source: Mean S.R. / Mean Rank per
    method} and `checks` for the JSON summary, `warnings` printed under the title. With `shown` False the
    section adds only those (its table has no rows)."""

    title: str
    header: list[str]
    rows: list[Row]
    summary: dict[str, dict] = field(default_factory=dict)
    checks: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    shown: bool = True

    def __iter__(self):
        """Unpacks as (title, (header, rows)), the form `obsbench report` prints the first section from."""
        return iter((self.title, (self.header, self.rows)))


def _plain(texts: list[str]) -> list[Entry]:
    return [(text, None) for text in texts]


def _marks(row: dict[str, float]) -> dict[str, str]:
    """'best' / 'second' per method of one task (ties share the mark)."""
    distinct = sorted(set(row.values()), reverse=True)
    marks = {}
    for method, value in row.items():
        if value == distinct[0]:
            marks[method] = "best"
        elif len(distinct) > 1 and value == distinct[1]:
            marks[method] = "second"
    return marks


def _summary_marks(summary: dict[str, dict], key: str, lower_is_better: bool) -> dict[str, str]:
    sign = -1 if lower_is_better else 1
    return _marks({m: sign * round(s[key], 2) for m, s in summary.items()})


def table_rows(
    table: dict[str, dict[str, float]],
    cells: dict[str, dict[str, Cell]] | None = None,
    blind: dict[str, dict[str, dict]] | None = None,
    methods: list[str] | None = None,
) -> tuple[list[str], list[Row]]:
    """(header, rows) of a table of success rates; the last two rows are Mean S.R. and Mean Rank. `blind`
    (`beats_blind`) marks the cells whose interval lies above the blind control's with ▲ or △. Columns:
    `methods`, else in the order the table names them (a published table keeps its own column order)."""
    methods = methods or list(dict.fromkeys(m for row in table.values() for m in row))
    summary = summarize(table)
    n_tasks = len(table)
    rows = []
    for task, row in table.items():
        marks = _marks(row)
        out = []
        for m in methods:
            if m not in row:
                out.append(("—", None))
                continue
            text = f"{row[m]:.2f}"
            if cells is not None:
                cell = cells[task][m]
                lo, hi = cell.ci95
                seeds = f", {cell.seeds} seeds" if cell.seeds > 1 else ""
                text += f" [{lo:.2f}, {hi:.2f}] ({cell.successes}/{cell.episodes}{seeds})"
            mark = (blind or {}).get(task, {}).get(m, {}).get("mark")
            if mark:
                text += f" {mark}"
            out.append((text, marks.get(m)))
        rows.append((task, out))
    for key, title, lower in (("mean_sr", "Mean S.R.", False), ("mean_rank", "Mean Rank", True)):
        marks = _summary_marks(summary, key, lower)
        rows.append(
            (
                title,
                [
                    (f"{summary[m][key]:.2f}" + ("*" if summary[m]["tasks"] < n_tasks else ""), marks.get(m))
                    for m in methods
                ],
            )
        )
    return ["task", *methods], rows


def seed_warnings(cells: dict[str, dict[str, Cell]]) -> list[str]:
    """One line naming the columns that rest on one training seed (their intervals cover episodes only)."""
    one_seed = sorted({m for row in cells.values() for m, c in row.items() if c.seeds == 1})
    if not one_seed:
        return []
    return [
        f"One training seed behind {', '.join(one_seed)}: their intervals cover evaluation episodes only, not "
        "training variance (which moves a seeing policy's success rate by more than its episode interval on "
        "another machine or seed), so a comparison with them is marked △, never ▲. Train at least 3 seeds "
        "(the grid's `seeds`) to measure it."
    ]


# ---- sections of a results store -------------------------------------------------------------------------


def success_section(data: ReportData) -> Section:
    """Each method's success rate per task with its interval, marked where it lies above the blind control's."""
    shown = sorted({r["shown"] for r in data.records})
    checkpoints = {s: sum(r["shown"] == s for r in data.records) for s in shown}
    blind = beats_blind(data.records, data.cells)
    methods = sorted({m for row in data.table.values() for m in row})
    return Section(
        "Success rate per task (held-out test seeds, training seeds' episodes pooled; 95% interval over "
        "training seeds and episodes, or over episodes only (Wilson) for one seed; successes/episodes; "
        "▲ / △ = interval above the blind control's, across seeds / on one seed). Checkpoint shown: "
        + ", ".join(f"{CHECKPOINT_TEXT[s]} ({n} runs)" for s, n in checkpoints.items()),
        *table_rows(data.table, data.cells, blind, methods=methods),
        summary={"results": summarize(data.table)},
        checks={"checkpoint": checkpoints, "beats_blind": blind},
        warnings=seed_warnings(data.cells),
    )


def aggregate_section(data: ReportData) -> Section:
    """Mean S.R., IQM and probability of improvement per column over training seeds and tasks (rliable)."""
    found = data.aggregates
    header = ["method", "training seeds", "Mean S.R. [95% CI]", "IQM [95% CI]", "P(improvement over blind) [95% CI]"]
    improvements = (found.over_blind,)
    if data.reference is not None:
        header.append(f"P(improvement over {data.reference}) [95% CI]")
        improvements += (found.over_reference,)
    rows = []
    for label in sorted(found.estimates):
        e = found.estimates[label]
        texts = [str(e["seeds"]), aggregates.interval_text(e["mean_sr"]), aggregates.interval_text(e["iqm"])]
        for over in improvements:
            if label not in over:
                texts.append("—")
            elif over[label][1] is None:  # both columns rest on one training seed
                texts.append("— (one seed each)")
            else:
                texts.append(aggregates.interval_text(over[label][1]))
        rows.append((label, _plain(texts)))
    return Section(
        "Across tasks and training seeds (rliable; each run's score is its success rate; 95% stratified bootstrap "
        "over training seeds, so episode noise is in the per-task intervals above, not here; IQM = interquartile "
        "mean of the runs' scores; P(improvement) = chance that a training seed of the method beats one of the "
        "other, averaged over tasks)",
        header,
        rows,
        checks={
            "aggregates": found.estimates,
            "probability_of_improvement": {f"{x} > {y}": list(e) for (x, y), e in found.pairs.items()},
        },
        warnings=[f"{label} is left out of the aggregates: {why}" for label, why in found.left_out.items()],
        shown=bool(rows),
    )


def control_section(data: ReportData) -> Section | None:
    """Each seeing space between its blind and oracle controls."""
    brackets = control_brackets(data.records, data.cells)
    if not brackets:
        return None
    rows = []
    for task, row in brackets.items():
        for method, b in row.items():
            fraction = (
                "— (the oracle does not beat blind)" if b["gain_fraction"] is None else f"{b['gain_fraction']:.2f}"
            )
            rows.append(
                (task, _plain([method, f"{b['blind']:.2f}", f"{b['rate']:.2f}", f"{b['oracle']:.2f}", fraction]))
            )
    return Section(
        "Between the controls: each seeing space against the blind control (no observation) and the oracle (the "
        "simulator's object poses), same policy type",
        ["task", "method", "blind", "method's rate", "oracle", "fraction of the oracle's gain over blind"],
        rows,
        checks={"controls": brackets},
    )


def curve_section(data: ReportData) -> Section | None:
    """Each method's success rate per task at every evaluated checkpoint: its learning curve over training steps."""
    if not data.curves:
        return None
    steps = sorted({step for row in data.curves.values() for curve in row.values() for step in curve})
    rows = []
    for task, row in sorted(data.curves.items()):
        for label, curve in sorted(row.items()):
            entries = []
            for step in steps:
                cell = curve.get(step)
                if cell is None:
                    entries.append(("—", None))
                    continue
                lo, hi = cell.ci95
                entries.append((f"{cell.rate:.2f} [{lo:.2f}, {hi:.2f}] ({cell.seeds} seeds)", None))
            rows.append((task, [(label, None), *entries]))
    return Section(
        "Learning curves: success rate on the test seeds at each evaluated checkpoint (training steps), nominal "
        "scene, training seeds' episodes pooled (95% interval over training seeds and episodes)",
        ["task", "method", *(f"step {step}" for step in steps)],
        rows,
        checks={
            "curves": {
                task: {label: {str(step): cell.rate for step, cell in curve.items()} for label, curve in row.items()}
                for task, row in data.curves.items()
            }
        },
    )


def _estimate(estimate: tuple | None) -> str:
    if estimate is None:
        return "—"
    point, low, high = estimate
    return f"{point:.2f} [{low:.2f}, {high:.2f}]"


def _json(estimate: tuple | None) -> list[float] | None:
    return None if estimate is None else [round(v, 4) for v in estimate]


def robustness_section(data: ReportData) -> Section | None:
    """The share of its unperturbed success each column keeps under each perturbation, over all tasks (95% intervals
    over training seeds and episodes); every task's own in the JSON summary and the robustness plots."""
    if not data.perturbations:
        return None
    labels = sorted({label for found in data.robustness.values() for label in found[ALL_TASKS]})
    rows = [
        (label, _plain([_estimate(data.robustness[name][ALL_TASKS].get(label)) for name in data.perturbations]))
        for label in labels
    ]
    return Section(
        "Robustness: the share of the unperturbed success kept under each perturbation (mean over tasks, 95% CI "
        "over training seeds and episodes; 1 = as often as unperturbed)",
        ["method", *data.perturbations],
        rows,
        checks={
            "robustness": {
                name: {task: {label: _json(e) for label, e in row.items()} for task, row in found.items()}
                for name, found in data.robustness.items()
            }
        },
    )


def sample_efficiency_section(data: ReportData) -> Section | None:
    """Success against the number of demonstrations: the mean over tasks per column (95% intervals over training
    seeds and episodes); every task's own in the JSON summary and the sample-efficiency plot."""
    if not data.demo_counts:
        return None
    aggregate = data.demo_curves.get(ALL_TASKS, {})
    rows = [
        (label, _plain([_estimate(aggregate[label].get(n)) for n in data.demo_counts])) for label in sorted(aggregate)
    ]
    return Section(
        "Sample efficiency: success rate against the number of demonstrations (mean over tasks, 95% CI over training "
        "seeds and episodes)",
        ["method", *(f"{n} demos" for n in data.demo_counts)],
        rows,
        checks={
            "sample_efficiency": {
                task: {label: {str(n): _json(e) for n, e in curve.items()} for label, curve in row.items()}
                for task, row in data.demo_curves.items()
            }
        },
    )


def provenance_section(data: ReportData) -> Section:
    """No table: notes on runs whose numbers another machine or an uninterrupted run would not repeat — runs
    pooled from processes with other machine facts (`machine.fingerprint`: CPU kernels, processor, library
    builds, threads), and runs resumed by a version whose resume did not continue the uninterrupted run."""
    machines: dict[str, list[str]] = {}
    for label, r in data.labelled_runs:
        records = [r["machine"], *(e.get("machine") for e in r["evaluations"].values())]
        facts = " + ".join(sorted({fingerprint(f) for f in records}))
        machines.setdefault(facts, []).append(f"{r['task']} {label} seed {r['config']['seed']}")
    warnings = []
    if list(machines) == [fingerprint(None)]:
        warnings.append(
            "The machine facts of these runs were not recorded (their records predate them), so whether they were "
            "made under the same CPU kernels and library builds cannot be told from the results."
        )
    elif len(machines) > 1:
        counts = "; ".join(f"{len(runs)} run(s) under {facts}" for facts, runs in machines.items())
        warnings.append(
            "These results pool runs trained or evaluated on machines with different facts, and the same run gives "
            f"other numbers under other CPU kernels or library builds: {counts} (each run's facts are in its "
            "records' `machine` field)."
        )
    inexact = [
        f"{r['task']} {label} seed {r['config']['seed']} (at step {r['resumed_from']})"
        for label, r in data.labelled_runs
        if r["resumed_from"] and not r["resumed_exactly"]
    ]
    if inexact:
        warnings.append(
            f"{len(inexact)} run(s) were resumed from a checkpoint by a version whose resume did not continue the "
            "uninterrupted run (LeRobot 0.6.1's own resume: its data order and random stream part there), so the "
            f"same command run from nothing trains other weights: {', '.join(inexact)}."
        )
    return Section(
        "Provenance",
        [],
        [],
        checks={"machines": {facts: len(runs) for facts, runs in machines.items()}, "inexact_resumes": inexact},
        warnings=warnings,
        shown=False,
    )


def per_seed_section(data: ReportData) -> Section:
    """Each run's nominal test episodes, seed by seed (1 = success), with its training seed."""
    rows = []
    for label, r in data.labelled_runs:
        nominal = r["evaluations"].get("none", {}).get("per_seed")
        if nominal is None:
            continue
        seeds = nominal["seeds"]
        span = f"{seeds[0]}..{seeds[-1]}" if seeds == list(range(seeds[0], seeds[0] + len(seeds))) else str(seeds)
        rows.append((r["task"], _plain([label, str(r["config"]["seed"]), span, nominal["success"].replace(".", "0")])))
    return Section(
        "Outcome per test seed (1 = success), nominal evaluation",
        ["task", "method", "training seed", "test seeds", "outcome per test seed"],
        rows,
    )


def diagnostic_section(data: ReportData) -> Section | None:
    """One row per run: final training loss, held-out open-loop error, objects' pixel size, point tokens on them."""
    rows = []
    for label, r in data.labelled_runs:
        d = r.get("diagnostics") or {}
        if not d:
            continue
        curve = d.get("loss_curve") or []
        pixels = d.get("object_pixels")
        share = d.get("object_token_share")
        texts = [
            label,
            str(r["config"]["seed"]),
            f"{curve[-1][1]:.3f} (step {curve[-1][0]})" if curve else "—",
            f"{d['open_loop_error']:.3f}" if "open_loop_error" in d else d.get("error", "—"),
            ", ".join(f"{k} {v:.1f} px" for k, v in pixels.items()) if pixels else "—",
            f"{share:.2f}" if share is not None else "—",
        ]
        rows.append((r["task"], _plain(texts)))
    if not rows:
        return None
    header = [
        "task",
        "method",
        "training seed",
        "final training loss",
        "held-out open-loop action error (normalised L1)",
        "object diameter in the camera",
        "share of point tokens on the objects",
    ]
    return Section("Diagnostics per run (bench/diagnostics.py)", header, rows)


def agreement_section(data: ReportData) -> Section | None:
    """Evaluation-only changes against the nominal evaluation of the same checkpoints, seed by seed."""
    found = agreements(data.records)
    if not found:
        return None
    rows = []
    for (task, method, name), a in found.items():
        lo, hi = a.changed.ci95
        n = a.changed.episodes
        texts = [
            method,
            name,
            f"{a.changed.rate:.2f} [{lo:.2f}, {hi:.2f}] ({a.changed.successes}/{n})",
            f"{a.nominal.rate:.2f} ({a.nominal.successes}/{n})",
            f"{a.same_outcome}/{n}",
            f"{a.identical}/{n}",
        ]
        rows.append((task, _plain(texts)))
    header = [
        "task",
        "method",
        "evaluation",
        "success",
        "nominal success",
        "same outcome as nominal",
        "identical episode (outcome and length)",
    ]
    checks = {
        f"{task} | {method} | {name}": {
            "success": a.changed.successes,
            "nominal_success": a.nominal.successes,
            "same_outcome": a.same_outcome,
            "identical": a.identical,
            "episodes": a.changed.episodes,
        }
        for (task, method, name), a in found.items()
    }
    return Section(
        "Does the policy react to what it sees? Evaluation-only changes against the nominal evaluation of the "
        "same checkpoints, seed by seed",
        header,
        rows,
        checks={"agreement": checks},
    )


# ---- sections of a published table -----------------------------------------------------------------------


def published_section(data: ReportData) -> Section:
    return Section(
        f"Published table ({data.published_name})",
        *table_rows(data.published),
        summary={"published": summarize(data.published)},
    )


def side_by_side_section(data: ReportData) -> Section | None:
    """The published table's rows that the results also have (its tasks, or its demonstration counts), beside
    the results' columns."""
    if not data.records:
        return None
    ours = {paper_row(t): row for t, row in data.table.items()}
    # a table of demonstration counts (Table 5): the Mean S.R. over tasks per count, as the table gives it
    ours.update({f"{n} demos": mean_over_tasks(data.demo_cells[n]) for n in data.demo_counts})
    shared = [t for t in ours if t in data.published]
    if not shared:
        return None
    name = data.published_name
    combined = {t: {**{f"{m} ({name})": v for m, v in data.published[t].items()}, **ours[t]} for t in shared}
    return Section(f"Side by side on the shared rows ({', '.join(shared)})", *table_rows(combined))
