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
- learning curves: each method's success rate at every checkpoint a grid's `eval_checkpoints` evaluates;
- per-seed outcomes of every column, and each run's diagnostics (loss curve, held-out open-loop action error,
  objects' pixel size, point tokens on the objects; bench/diagnostics.py);
- evaluation-only changes (camera moved, light, depth noise, ...): per-seed agreement with the nominal evaluation of
  the same checkpoint on the same seeds — how many episodes keep their outcome, and how many are identical (outcome
  and length; a policy that ignores its observation repeats every episode exactly) — and the share of its
  unperturbed success each column keeps under each, per task and over tasks, with intervals over training seeds;
- sample efficiency: success against the number of demonstrations, per task and over tasks, with intervals.

The package, bottom-up: `statistics` (pooled cells, ranking, summaries), `runs` (run views, column labels,
cells per task), `published` (the paper's tables), `comparisons` (controls, agreement, rliable's aggregates),
`data` (ReportData: what sections and figures share, computed once), `tables` (the Section of each table and
its builder), `figures` (one matplotlib set-up, one builder per figure) and `render` (Markdown, HTML, JSON).
"""

from __future__ import annotations

from lerobot_obsbench.bench.report import figures, tables
from lerobot_obsbench.bench.report.data import ReportData
from lerobot_obsbench.bench.report.published import published_tables, read_published, resolve_table
from lerobot_obsbench.bench.report.render import markdown_table, summary_json, write_report
from lerobot_obsbench.bench.report.runs import CHECKPOINT_CHOICES, NOT_LABEL_FIELDS, cells_by_task, run_views
from lerobot_obsbench.bench.report.statistics import ReportError, competition_ranks, summarize

__all__ = [
    "CHECKPOINT_CHOICES",
    "NOT_LABEL_FIELDS",
    "ReportError",
    "build_report",
    "cells_by_task",
    "competition_ranks",
    "markdown_table",
    "published_tables",
    "read_published",
    "resolve_table",
    "summarize",
    "summary_json",
    "write_report",
]

# The report's tables in order: those of a results store, then those of a published table.
RESULT_SECTIONS = (
    tables.success_section,
    tables.aggregate_section,
    tables.control_section,
    tables.curve_section,
    tables.per_seed_section,
    tables.diagnostic_section,
    tables.agreement_section,
    tables.robustness_section,
    tables.sample_efficiency_section,
    tables.provenance_section,
)
PUBLISHED_SECTIONS = (tables.published_section, tables.side_by_side_section)
# The figures of a results store, in the order the report shows them.
FIGURES = (
    figures.aggregate_figures,
    figures.success_figure,
    figures.learning_curve_figure,
    figures.loss_figure,
    figures.robustness_figures,
    figures.sample_efficiency_figure,
)


def build_report(
    results: list[dict],
    published: dict[str, dict[str, float]] | None = None,
    published_name: str = "published",
    checkpoint: str = "best",
    reference: str | None = None,
) -> dict:
    """Everything the report shows: its sections (tables.Section), PNG figures {name: (caption, png)}, warnings
    and the JSON summary. `results`: the results store's records; `checkpoint`: which checkpoint's test
    evaluations the tables show (`run_views`); `reference`: a column every method's probability of improvement
    is also computed against."""
    data = ReportData(run_views(results, checkpoint), published, published_name, reference)
    if not data.records and not published:
        raise ReportError("nothing to report: no evaluated runs in the results and no --table")
    if reference is not None and not data.records:
        raise ReportError("--reference names a column of the results; there are no evaluated runs")
    builders = (RESULT_SECTIONS if data.records else ()) + (PUBLISHED_SECTIONS if published else ())
    sections = [section for build in builders if (section := build(data)) is not None]
    return {
        "sections": [s for s in sections if s.shown],
        "figures": {name: f for draw in (FIGURES if data.records else ()) for name, f in draw(data).items()},
        "summary": {source: s for section in sections for source, s in section.summary.items()},
        "checks": {key: check for section in sections for key, check in section.checks.items()},
        "warnings": [warning for section in sections for warning in section.warnings],
    }
