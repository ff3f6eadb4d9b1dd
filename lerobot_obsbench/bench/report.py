"""`obsbench report`: paper-style tables and plots from a results store and/or a published table.

Per task, the success rate of each method (columns) pools every training seed's evaluation episodes, with a
95% Wilson interval. Summary rows follow the paper: Mean S.R. is the mean over tasks of the per-task success
rates; Mean Rank ranks the methods on each task with competition ranking ("1224": tied methods share the best
rank of their group, the next rank skips) and averages the ranks over tasks. A method missing on a task is
left out of that task's ranking and mean (and marked).

Beyond the paper, checks that a method uses what it sees:
- the blind control (obs_space `none`, same policy type): a method whose 95% interval lies entirely above the
  blind control's on a task is marked ▲ there;
- the oracle control (obs_space `state`: the simulator's object poses): with the blind control it brackets every
  seeing space, which is read as the fraction of the oracle's gain over blind it recovers;
- per-seed outcomes of every column, and each run's diagnostics (loss curve, held-out open-loop action error,
  objects' pixel size, point tokens on the objects; bench/diagnostics.py);
- evaluation-only changes (camera moved, light, ...): per-seed agreement with the nominal evaluation of the same
  checkpoint on the same seeds — how many episodes keep their outcome, and how many are identical (outcome and
  length). A policy that ignores its observation repeats every episode exactly.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
from collections import defaultdict
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from lerobot_obsbench.bench.package_data import TABLES, path_or_shipped, shipped
from lerobot_obsbench.envs.perturbations import NOMINAL_VALUE, parse_perturbation
from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.rlbench.paper_tasks import PAPER_ROWS, grid_task_name
from lerobot_obsbench.schema import BLIND_SPACES, CONTROL_SPACES, ORACLE_SPACES
from lerobot_obsbench.stats import seeds_and_episodes_interval, wilson_interval

# Run-config fields that never split a method's column: the method itself, the task (a row), the training seed
# (what a column pools) and the demonstration count (the sample-efficiency axis). Every other field changes what
# is trained, so where it differs between runs of one method it becomes part of the column label.
NOT_LABEL_FIELDS = ("task", "policy", "obs_space", "encoder", "seed", "demos")


@dataclass(frozen=True)
class Cell:
    """One method on one task: (successes, episodes) of each of its training runs (seeds)."""

    runs: tuple[tuple[int, int], ...]

    @property
    def successes(self) -> int:
        return sum(k for k, _ in self.runs)

    @property
    def episodes(self) -> int:
        return sum(n for _, n in self.runs)

    @property
    def seeds(self) -> int:
        return len(self.runs)

    @property
    def rate(self) -> float:
        """Every run's episodes pooled (the paper's success rate)."""
        return self.successes / self.episodes

    @cached_property
    def ci95(self) -> tuple[float, float]:
        """Over training seeds and episodes (two-level bootstrap) with several seeds; with one seed the Wilson
        interval of its episodes, which cannot show training variance."""
        if self.seeds == 1:
            return wilson_interval(self.successes, self.episodes)
        return seeds_and_episodes_interval(list(self.runs))


class ReportError(ObsBenchError, ValueError):
    """Unreadable published table or empty input."""


def competition_ranks(values: dict[str, float]) -> dict[str, int]:
    """Higher is better; rank = 1 + the number of strictly better methods ("1224" ranking)."""
    return {m: 1 + sum(other > v for other in values.values()) for m, v in values.items()}


def summarize(table: dict[str, dict[str, float]]) -> dict[str, dict]:
    """Mean S.R. and Mean Rank per method of {task: {method: success rate}}."""
    rates, ranks = defaultdict(list), defaultdict(list)
    for row in table.values():
        for method, rank in competition_ranks(row).items():
            rates[method].append(row[method])
            ranks[method].append(rank)
    return {
        m: {
            "mean_sr": sum(rates[m]) / len(rates[m]),
            "mean_rank": sum(ranks[m]) / len(ranks[m]),
            "tasks": len(rates[m]),
        }
        for m in rates
    }


def published_tables() -> list[str]:
    """The paper's tables, typed from its LaTeX source, shipped with the package (`--table NAME`)."""
    return shipped(TABLES, ".csv")


def resolve_table(name_or_path: str | Path):
    """A CSV path, or the packaged paper table of that name."""
    found = path_or_shipped(name_or_path, TABLES, ".csv")
    if found is not None:
        return found
    raise ReportError(f"no table {str(name_or_path)!r}: give a CSV path or one of {', '.join(published_tables())}")


def read_published(path: Path) -> dict[str, dict[str, float]]:
    """A published table as CSV: first column the task, one column per method, success rates in [0, 1];
    empty cells are missing values."""
    rows = list(csv.reader(path.read_text().splitlines()))
    if len(rows) < 2 or len(rows[0]) < 2:
        raise ReportError(f"{path}: expected a header (task, method, ...) and at least one task row")
    methods = [m.strip() for m in rows[0][1:]]
    table = {}
    for number, row in enumerate(rows[1:], start=2):
        if not row or not row[0].strip():
            continue
        if len(row) != len(methods) + 1:
            raise ReportError(f"{path}:{number}: {len(row)} cells, the header has {len(methods) + 1}")
        values = {}
        for method, text in zip(methods, row[1:], strict=True):
            if not text.strip():
                continue
            try:
                value = float(text)
            except ValueError:
                raise ReportError(f"{path}:{number}: {method} = {text!r} is not a number") from None
            if not 0 <= value <= 1:
                raise ReportError(f"{path}:{number}: {method} = {value} is not a success rate in [0, 1]")
            values[method] = value
        table[row[0].strip()] = values
    return table


# ---- own results -----------------------------------------------------------------------------------------

CHECKPOINT_CHOICES = ("best", "last")
CHECKPOINT_TEXT = {
    "best": "best on the validation seeds (10000+, disjoint from the test seeds)",
    "last": "the last checkpoint",
}


def run_views(records: list[dict], checkpoint: str = "best") -> list[dict]:
    """One view per trained run from the results store's train and eval records: its config plus
    `evaluations` {perturbation: eval record} of its test evaluations of `checkpoint` — "best" (the
    best-on-validation checkpoint, where the run has one; else its last) or "last". Each view notes which
    checkpoint it shows under "shown"."""
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
            }
        )
    return views


def method_labels(records: list[dict]) -> dict[str, str]:
    """run_id -> column label: policy/space/encoder, plus every run-config field (but NOT_LABEL_FIELDS) that
    varies within that method."""
    by_method = defaultdict(list)
    for r in records:
        by_method[r["method"]].append(r)
    labels = {}
    for method, group in by_method.items():
        fields = dict.fromkeys(f for g in group for f in g["config"] if f not in NOT_LABEL_FIELDS)
        varying = [f for f in fields if len({json.dumps(g["config"].get(f), sort_keys=True) for g in group}) > 1]
        for r in group:
            suffix = " ".join(f"{f}={_short(r['config'].get(f))}" for f in varying)
            labels[r["run_id"]] = f"{method} {suffix}".strip()
    return labels


def _short(value) -> str:
    return f"{value:g}" if isinstance(value, float) else json.dumps(value) if isinstance(value, dict) else str(value)


def cells_by_task(
    records: list[dict], perturbation: str = "none", demos: int | None = None
) -> dict[str, dict[str, Cell]]:
    """{task: {label: Cell}}, one Cell per column holding each training seed's episodes; `demos` None = each
    task's largest demo count."""
    labels = method_labels(records)
    most = defaultdict(int)
    for r in records:
        most[r["task"]] = max(most[r["task"]], r["config"]["demos"])
    runs: dict[str, dict[str, list[tuple[int, int]]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        wanted = most[r["task"]] if demos is None else demos
        evaluation = r["evaluations"].get(perturbation)
        if r["config"]["demos"] != wanted or evaluation is None:
            continue
        runs[r["task"]][labels[r["run_id"]]].append((evaluation["successes"], evaluation["episodes"]))
    return {t: {m: Cell(tuple(c)) for m, c in row.items()} for t, row in runs.items()}


def rates(cells: dict[str, dict[str, Cell]]) -> dict[str, dict[str, float]]:
    return {t: {m: c.rate for m, c in row.items()} for t, row in cells.items()}


def _label_configs(records: list[dict]) -> dict[str, dict]:
    """column label -> the config of (one of) its runs."""
    labels = method_labels(records)
    return {labels[r["run_id"]]: r["config"] for r in records}


# Marks of a seeing method whose 95% interval lies above its blind control's.
ABOVE_ACROSS_SEEDS = "▲"  # both rest on >= 2 training seeds: the intervals cover training variance
ABOVE_ONE_SEED = "△"  # one side rests on one training seed: its interval covers evaluation episodes only


def beats_blind(records: list[dict], cells: dict[str, dict[str, Cell]]) -> dict[str, dict[str, dict]]:
    """{task: {label: {"above": interval above the blind control's, "mark": ▲ / △ / "", "seeds": training seeds
    of the method, "blind_seeds": of the control}}} for methods that have a blind control of their policy type on
    that task (the one with the highest upper bound when there are several). ▲ needs at least two training
    seeds on both sides; a comparison resting on one seed is at most △."""
    configs = _label_configs(records)
    out: dict[str, dict[str, dict]] = {}
    for task, row in cells.items():
        for method, cell in row.items():
            if configs[method]["obs_space"] in BLIND_SPACES:
                continue
            controls = _controls(row, configs, BLIND_SPACES, configs[method]["policy"])
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


def _control_labels(labels, configs: dict[str, dict], spaces: tuple[str, ...], policy: str) -> list[str]:
    """The column labels among `labels` whose space is one of `spaces` (a control) and policy type `policy`."""
    return [m for m in labels if configs[m]["obs_space"] in spaces and configs[m]["policy"] == policy]


def _controls(row: dict[str, Cell], configs: dict[str, dict], spaces: tuple[str, ...], policy: str) -> list[Cell]:
    """The cells of one task's row whose space is one of `spaces` (a control) and whose policy type is `policy`."""
    return [row[m] for m in _control_labels(row, configs, spaces, policy)]


def control_brackets(records: list[dict], cells: dict[str, dict[str, Cell]]) -> dict[str, dict[str, dict]]:
    """{task: {label: {"blind", "oracle", "rate", "gain_fraction"}}} for seeing methods with both controls of their
    policy type on the task (the best-scoring control of each kind): gain_fraction = (rate - blind) / (oracle -
    blind), None when the oracle does not beat blind (nothing to recover)."""
    configs = _label_configs(records)
    out: dict[str, dict[str, dict]] = {}
    for task, row in cells.items():
        for method, cell in row.items():
            policy = configs[method]["policy"]
            if configs[method]["obs_space"] in CONTROL_SPACES:
                continue
            best = {}
            for kind, spaces in (("blind", BLIND_SPACES), ("oracle", ORACLE_SPACES)):
                controls = _controls(row, configs, spaces, policy)
                best[kind] = max(c.rate for c in controls) if controls else None
            if best["blind"] is None or best["oracle"] is None:
                continue
            gain = best["oracle"] - best["blind"]
            fraction = (cell.rate - best["blind"]) / gain if gain > 0 else None
            out.setdefault(task, {})[method] = {**best, "rate": cell.rate, "gain_fraction": fraction}
    return out


def bracket_rows(brackets: dict[str, dict[str, dict]]):
    header = ["task", "method", "blind", "method's rate", "oracle", "fraction of the oracle's gain over blind"]
    rows = []
    for task, row in brackets.items():
        for method, b in row.items():
            fraction = (
                "— (the oracle does not beat blind)" if b["gain_fraction"] is None else f"{b['gain_fraction']:.2f}"
            )
            cells = [method, f"{b['blind']:.2f}", f"{b['rate']:.2f}", f"{b['oracle']:.2f}", fraction]
            rows.append((task, [(c, None) for c in cells]))
    return header, rows


def per_seed_rows(records: list[dict]):
    """Each run's nominal test episodes, seed by seed (1 = success), with its training seed."""
    labels = method_labels(records)
    rows = []
    for r in sorted(records, key=lambda r: (r["task"], labels[r["run_id"]], r["config"]["seed"])):
        nominal = r["evaluations"].get("none", {}).get("per_seed")
        if nominal is None:
            continue
        seeds = nominal["seeds"]
        span = f"{seeds[0]}..{seeds[-1]}" if seeds == list(range(seeds[0], seeds[0] + len(seeds))) else str(seeds)
        cells = [labels[r["run_id"]], str(r["config"]["seed"]), span, nominal["success"].replace(".", "0")]
        rows.append((r["task"], [(c, None) for c in cells]))
    return ["task", "method", "training seed", "test seeds", "outcome per test seed"], rows


def diagnostic_rows(records: list[dict]):
    """One row per run: final training loss, held-out open-loop error, objects' pixel size, point tokens on them."""
    labels = method_labels(records)
    rows = []
    for r in sorted(records, key=lambda r: (r["task"], labels[r["run_id"]], r["config"]["seed"])):
        d = r.get("diagnostics") or {}
        if not d:
            continue
        curve = d.get("loss_curve") or []
        pixels = d.get("object_pixels")
        share = d.get("object_token_share")
        cells = [
            labels[r["run_id"]],
            str(r["config"]["seed"]),
            f"{curve[-1][1]:.3f} (step {curve[-1][0]})" if curve else "—",
            f"{d['open_loop_error']:.3f}" if "open_loop_error" in d else d.get("error", "—"),
            ", ".join(f"{k} {v:.1f} px" for k, v in pixels.items()) if pixels else "—",
            f"{share:.2f}" if share is not None else "—",
        ]
        rows.append((r["task"], [(c, None) for c in cells]))
    header = [
        "task",
        "method",
        "training seed",
        "final training loss",
        "held-out open-loop action error (normalised L1)",
        "object diameter in the camera",
        "share of point tokens on the objects",
    ]
    return header, rows


def loss_chart(records: list[dict]) -> bytes | None:
    """Training loss against step, one line per run."""
    labels = method_labels(records)
    series = {
        f"{labels[r['run_id']]} seed {r['config']['seed']} ({r['task']})": [
            tuple(p) for p in r["diagnostics"]["loss_curve"]
        ]
        for r in records
        if (r.get("diagnostics") or {}).get("loss_curve")
    }
    return curve_chart(series, "optimizer step", "Training loss", log_y=True, ylabel="loss") if series else None


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
    most = defaultdict(int)
    for r in records:
        most[r["task"]] = max(most[r["task"]], r["config"]["demos"])
    # per key: each run's (successes, episodes) changed and nominal, then the episode counts pooled
    changed_runs, nominal_runs = defaultdict(list), defaultdict(list)
    same, identical = defaultdict(int), defaultdict(int)
    for r in records:
        nominal = r["evaluations"].get("none", {}).get("per_seed")
        if r["config"]["demos"] != most[r["task"]] or nominal is None:
            continue
        for name, evaluation in r["evaluations"].items():
            changed = evaluation.get("per_seed")
            if name == "none" or changed is None or changed["seeds"] != nominal["seeds"]:
                continue
            pairs = list(zip(nominal["success"], changed["success"], nominal["length"], changed["length"], strict=True))
            key = (r["task"], labels[r["run_id"]], name)
            changed_runs[key].append((changed["success"].count("1"), len(pairs)))
            nominal_runs[key].append((nominal["success"].count("1"), len(pairs)))
            same[key] += sum(a == b for a, b, _, _ in pairs)
            identical[key] += sum(a == b and la == lb for a, b, la, lb in pairs)
    return {
        key: Agreement(Cell(tuple(changed_runs[key])), Cell(tuple(nominal_runs[key])), same[key], identical[key])
        for key in sorted(changed_runs)
    }


def agreement_rows(found: dict[tuple[str, str, str], Agreement]):
    header = [
        "task",
        "method",
        "evaluation",
        "success",
        "nominal success",
        "same outcome as nominal",
        "identical episode (outcome and length)",
    ]
    rows = []
    for (task, method, name), a in found.items():
        lo, hi = a.changed.ci95
        n = a.changed.episodes
        cells = [
            f"{a.changed.rate:.2f} [{lo:.2f}, {hi:.2f}] ({a.changed.successes}/{n})",
            f"{a.nominal.rate:.2f} ({a.nominal.successes}/{n})",
            f"{a.same_outcome}/{n}",
            f"{a.identical}/{n}",
        ]
        rows.append((task, [(method, None), (name, None), *((c, None) for c in cells)]))
    return header, rows


def aggregate_section(records: list[dict], cells: dict[str, dict[str, Cell]], reference: str | None = None):
    """Mean S.R. and IQM over training seeds and tasks with stratified bootstrap intervals, and each method's
    probability of improvement over its blind control (same policy type) and over `reference` (a column label):
    ((header, rows), figures {name: (caption, png)}, checks, warnings)."""
    from lerobot_obsbench.bench import aggregates

    scores, left_out = aggregates.seed_scores(cells)
    if reference is not None and reference not in scores:
        known = ", ".join(sorted(scores)) or "none"
        why = f" ({left_out[reference]})" if reference in left_out else ""
        raise ReportError(f"--reference {reference!r} is not a column with scores on every task{why}; columns: {known}")
    estimates = aggregates.aggregate_estimates(scores)
    configs = _label_configs(records)
    over_blind, over_reference = {}, {}  # label -> (other label, P(improvement) estimate)
    for label in sorted(scores):
        if configs[label]["obs_space"] not in BLIND_SPACES:
            blinds = _control_labels(scores, configs, BLIND_SPACES, configs[label]["policy"])
            if blinds:
                blind = max(blinds, key=lambda m: estimates[m]["mean_sr"][0])
                over_blind[label] = (blind, aggregates.improvement_estimate(scores[label], scores[blind]))
        if reference is not None and label != reference:
            over_reference[label] = (reference, aggregates.improvement_estimate(scores[label], scores[reference]))
    pairs = {(x, y): e for found in (over_blind, over_reference) for x, (y, e) in found.items() if e is not None}
    header = ["method", "training seeds", "Mean S.R. [95% CI]", "IQM [95% CI]", "P(improvement over blind) [95% CI]"]
    if reference is not None:
        header.append(f"P(improvement over {reference}) [95% CI]")
    rows = []
    for label in sorted(scores):
        e = estimates[label]
        cells_text = [str(e["seeds"]), aggregates.interval_text(e["mean_sr"]), aggregates.interval_text(e["iqm"])]
        for found in (over_blind, over_reference) if reference is not None else (over_blind,):
            if label not in found:
                cells_text.append("—")
            elif found[label][1] is None:  # both columns rest on one training seed
                cells_text.append("— (one seed each)")
            else:
                cells_text.append(aggregates.interval_text(found[label][1]))
        rows.append((label, [(c, None) for c in cells_text]))
    figures = {}
    if estimates:
        figures["aggregates.png"] = (
            "Mean S.R. and IQM over training seeds and tasks",
            _figure_png(aggregates.interval_chart(estimates)),
        )
    if pairs:
        figures["probability_of_improvement.png"] = (
            "Probability of improvement (training seeds)",
            _figure_png(aggregates.improvement_chart(pairs)),
        )
    checks = {
        "aggregates": estimates,
        "probability_of_improvement": {f"{x} > {y}": list(e) for (x, y), e in pairs.items()},
    }
    warnings = [f"{label} is left out of the aggregates: {why}" for label, why in left_out.items()]
    return (header, rows), figures, checks, warnings


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


# ---- rendering -------------------------------------------------------------------------------------------


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
):
    """(header, rows) where each cell is (text, mark); the last two rows are Mean S.R. and Mean Rank. `blind`
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


def markdown_table(header, rows) -> str:
    def fmt(text, mark):
        return f"**{text}**" if mark == "best" else f"<u>{text}</u>" if mark == "second" else text

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join([task, *(fmt(*c) for c in cells)]) + " |" for task, cells in rows]
    return "\n".join(lines)


def html_table(header, rows) -> str:
    def fmt(text, mark):
        text = html.escape(text)
        return f"<b>{text}</b>" if mark == "best" else f"<u>{text}</u>" if mark == "second" else text

    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr><td>" + html.escape(task) + "</td>" + "".join(f"<td>{fmt(*c)}</td>" for c in cells) + "</tr>"
        for task, cells in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _figure_png(fig) -> bytes:
    """The figure as PNG bytes; the figure is closed."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def bar_chart(cells: dict[str, dict[str, Cell]]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(cells)
    cols = min(3, len(tasks))
    fig, axes = plt.subplots(
        math.ceil(len(tasks) / cols), cols, figsize=(4.5 * cols, 3.2 * math.ceil(len(tasks) / cols)), squeeze=False
    )
    for ax, task in zip(axes.flat, tasks, strict=False):
        methods = sorted(cells[task])
        values = [cells[task][m].rate for m in methods]
        errors = [
            [v - cells[task][m].ci95[0] for m, v in zip(methods, values, strict=True)],
            [cells[task][m].ci95[1] - v for m, v in zip(methods, values, strict=True)],
        ]
        ax.bar(range(len(methods)), values, yerr=errors, capsize=3, color=[f"C{i}" for i in range(len(methods))])
        ax.set_xticks(range(len(methods)), methods, rotation=30, ha="right", fontsize=7)
        ax.set_ylim(0, 1)
        ax.set_title(task, fontsize=9)
        ax.set_ylabel("success rate (95% CI)", fontsize=8)
    for ax in list(axes.flat)[len(tasks) :]:
        ax.axis("off")
    fig.tight_layout()
    return _figure_png(fig)


def curve_chart(
    series: dict[str, list[tuple[float, float]]],
    xlabel: str,
    title: str,
    log_x: bool = False,
    log_y: bool = False,
    ylabel: str = "mean success rate over tasks",
) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    for method, points in sorted(series.items()):
        xs, ys = zip(*sorted(points), strict=True)
        ax.plot(xs, ys, marker="o" if len(xs) < 20 else None, label=method)
    if log_x:
        ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if log_y:
        ax.set_yscale("log")
    else:
        ax.set_ylim(0, 1)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _figure_png(fig)


def perturbation_series(records: list[dict]) -> dict[str, dict[str, list[tuple[float, float]]]]:
    """{kind: {method: [(value, mean success rate over tasks)]}}, the nominal scene included at its value."""
    names = sorted({p for r in records for p in r["evaluations"] if p != "none"})
    curves: dict[str, dict[str, list[tuple[float, float]]]] = defaultdict(lambda: defaultdict(list))
    for name in names:
        pert = parse_perturbation(name)
        for method, value in _mean_over_tasks(cells_by_task(records, name)).items():
            curves[pert.kind][method].append((pert.scalar, value))
    nominal_rates = _mean_over_tasks(cells_by_task(records, "none")) if curves else {}
    for kind, by_method in curves.items():
        if NOMINAL_VALUE[kind] is not None:
            for method, value in nominal_rates.items():
                if method in by_method:
                    by_method[method].append((NOMINAL_VALUE[kind], value))
    return curves


def paper_row(task: str) -> str:
    """The row name the paper's tables give a task: RLBench's as Table 2 prints them, ManiSkill's without the
    version suffix (PickCube-v1 -> PickCube)."""
    name = grid_task_name(task)
    if name is not None:
        return PAPER_ROWS.get(name, name.replace("_", " "))
    return task.removesuffix("-v1")


def demo_counts(records: list[dict]) -> list[int]:
    """The demonstration counts of a sample-efficiency grid (none when every run trains on the same number)."""
    counts = sorted({r["config"]["demos"] for r in records})
    return counts if len(counts) > 1 else []


def series_at(series: dict[str, list[tuple[float, float]]], x: float) -> dict[str, float]:
    return {m: y for m, points in series.items() for px, y in points if px == x}


def demo_series(records: list[dict]) -> dict[str, list[tuple[float, float]]]:
    counts = sorted({r["config"]["demos"] for r in records})
    series = defaultdict(list)
    for n in counts:
        for method, value in _mean_over_tasks(cells_by_task(records, "none", demos=n)).items():
            series[method].append((n, value))
    return series


def _mean_over_tasks(cells: dict[str, dict[str, Cell]]) -> dict[str, float]:
    return {m: s["mean_sr"] for m, s in summarize(rates(cells)).items()}


def build_report(
    results: list[dict],
    published: dict[str, dict[str, float]] | None = None,
    published_name: str = "published",
    checkpoint: str = "best",
    reference: str | None = None,
) -> dict:
    """Everything the report shows: tables (header, rows), PNG figures, warnings and the JSON summary. `results`:
    the results store's records; `checkpoint`: which checkpoint's test evaluations the tables show
    (`run_views`); `reference`: a column every method's probability of improvement is also computed against."""
    records = run_views(results, checkpoint)
    if not records and not published:
        raise ReportError("nothing to report: no evaluated runs in the results and no --table")
    sections, figures, summary, checks, warnings = [], {}, {}, {}, []
    if reference is not None and not records:
        raise ReportError("--reference names a column of the results; there are no evaluated runs")
    if records:
        shown = sorted({r["shown"] for r in records})
        checks["checkpoint"] = {s: sum(r["shown"] == s for r in records) for s in shown}
        cells = cells_by_task(records)
        table = rates(cells)
        blind = beats_blind(records, cells)
        sections.append(
            (
                "Success rate per task (held-out test seeds, training seeds' episodes pooled; 95% interval over "
                "training seeds and episodes, or over episodes only (Wilson) for one seed; successes/episodes; "
                "▲ / △ = interval above the blind control's, across seeds / on one seed). Checkpoint shown: "
                + ", ".join(f"{CHECKPOINT_TEXT[s]} ({n} runs)" for s, n in checks["checkpoint"].items()),
                table_rows(table, cells, blind, methods=sorted({m for row in table.values() for m in row})),
            )
        )
        summary["results"] = summarize(table)
        checks["beats_blind"] = blind
        warnings += seed_warnings(cells)
        aggregate_table, aggregate_figures, aggregate_checks, aggregate_warnings = aggregate_section(
            records, cells, reference
        )
        if aggregate_table[1]:
            sections.append(
                (
                    "Across tasks and training seeds (rliable; each run's score is its success rate; 95% "
                    "stratified bootstrap over training seeds, so episode noise is in the per-task intervals "
                    "above, not here; IQM = interquartile mean of the runs' scores; P(improvement) = chance that "
                    "a training seed of the method beats one of the other, averaged over tasks)",
                    aggregate_table,
                )
            )
        figures.update(aggregate_figures)
        checks.update(aggregate_checks)
        warnings += aggregate_warnings
        brackets = control_brackets(records, cells)
        if brackets:
            sections.append(
                (
                    "Between the controls: each seeing space against the blind control (no observation) and the "
                    "oracle (the simulator's object poses), same policy type",
                    bracket_rows(brackets),
                )
            )
            checks["controls"] = brackets
        sections.append(("Outcome per test seed (1 = success), nominal evaluation", per_seed_rows(records)))
        diagnostics = diagnostic_rows(records)
        if diagnostics[1]:
            sections.append(("Diagnostics per run (bench/diagnostics.py)", diagnostics))
        found = agreements(records)
        if found:
            sections.append(
                (
                    "Does the policy react to what it sees? Evaluation-only changes against the nominal "
                    "evaluation of the same checkpoints, seed by seed",
                    agreement_rows(found),
                )
            )
            checks["agreement"] = {
                f"{task} | {method} | {name}": {
                    "success": a.changed.successes,
                    "nominal_success": a.nominal.successes,
                    "same_outcome": a.same_outcome,
                    "identical": a.identical,
                    "episodes": a.changed.episodes,
                }
                for (task, method, name), a in found.items()
            }
        figures["success_by_task.png"] = ("Success rate per task", bar_chart(cells))
        losses = loss_chart(records)
        if losses is not None:
            figures["training_loss.png"] = ("Training loss per run", losses)
        for kind, series in perturbation_series(records).items():
            figures[f"generalization_{kind}.png"] = (
                f"Zero-shot {kind}",
                curve_chart(series, kind, f"Zero-shot generalization: {kind}"),
            )
        if demo_counts(records):
            figures["sample_efficiency.png"] = (
                "Sample efficiency",
                curve_chart(demo_series(records), "demonstrations", "Sample efficiency", log_x=True),
            )
    if published:
        sections.append((f"Published table ({published_name})", table_rows(published)))
        summary["published"] = summarize(published)
        if records:
            ours = {paper_row(t): row for t, row in table.items()}
            # a table of demonstration counts (Table 5): the Mean S.R. over tasks per count, as the table gives it
            by_demos = demo_series(records)
            ours.update({f"{n} demos": series_at(by_demos, n) for n in demo_counts(records)})
            shared = [t for t in ours if t in published]
            if shared:
                combined = {
                    t: {**{f"{m} ({published_name})": v for m, v in published[t].items()}, **ours[t]} for t in shared
                }
                sections.append((f"Side by side on the shared rows ({', '.join(shared)})", table_rows(combined)))
    return {"sections": sections, "figures": figures, "summary": summary, "checks": checks, "warnings": warnings}


def write_report(report: dict, out: Path, title: str = "OBSBench report", notes: str = "") -> dict[str, Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, (_, png) in report["figures"].items():
        (out / name).write_bytes(png)
    md = [f"# {title}", "", notes, ""] if notes else [f"# {title}", ""]
    body = [f"<h1>{html.escape(title)}</h1>"] + ([f"<p>{html.escape(notes)}</p>"] if notes else [])
    for warning in report.get("warnings", []):
        md += [f"> **Note:** {warning}", ""]
        body.append(f"<p><b>Note:</b> {html.escape(warning)}</p>")
    for heading, (header, rows) in report["sections"]:
        md += [f"## {heading}", "", markdown_table(header, rows), ""]
        body += [f"<h2>{html.escape(heading)}</h2>", html_table(header, rows)]
    legend = (
        "Best per row in bold, second underlined. Mean Rank: competition ranking per task (ties share the "
        "best rank), averaged over tasks; * = the method lacks some tasks (means over its tasks). ▲: the "
        "method's 95% interval lies entirely above its blind control's (obs_space none, same policy type), both "
        "over at least two training seeds; △: the same, but one of them rests on one training seed, so the "
        "intervals cover evaluation episodes only."
    )
    md += [legend, ""]
    body.append(f"<p>{html.escape(legend)}</p>")
    for name, (caption, png) in report["figures"].items():
        md += [f"## {caption}", "", f"![{caption}]({name})", ""]
        data = base64.b64encode(png).decode()
        body += [
            f"<h2>{html.escape(caption)}</h2>",
            f'<img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">',
        ]
    style = (
        "body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
        "padding:4px 8px;text-align:right}td:first-child,th:first-child{text-align:left}"
    )
    (out / "report.md").write_text("\n".join(md))
    (out / "report.html").write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
        f"</title><style>{style}</style></head><body>{''.join(body)}</body></html>\n"
    )
    return {"markdown": out / "report.md", "html": out / "report.html"}


def summary_json(report: dict) -> dict:
    """Mean S.R. / Mean Rank per method and source, plus the blind-control and agreement checks."""
    out = {
        source: {
            m: {"mean_sr": round(s["mean_sr"], 4), "mean_rank": round(s["mean_rank"], 4), "tasks": s["tasks"]}
            for m, s in summary.items()
        }
        for source, summary in report["summary"].items()
    }
    if report.get("checks"):
        out["checks"] = report["checks"]
    return out
