"""ReportData: what one report is built from, and what several of its sections and figures share, each computed
once on first use."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

from lerobot_obsbench.bench.report.comparisons import SeedAggregates, demo_curves, robustness, seed_aggregates
from lerobot_obsbench.bench.report.runs import (
    cells_by_task,
    curve_cells,
    demo_cells,
    demo_counts,
    labelled_runs,
    perturbations,
)
from lerobot_obsbench.bench.report.statistics import Cell, rates


@dataclass(frozen=True)
class ReportData:
    """`records`: the run views of the checkpoint shown (`run_views`); `published`: a published table
    {task: {method: success rate}}, named `published_name` in the report; `reference`: a column every method's
    probability of improvement is also computed against."""

    records: list[dict]
    published: dict[str, dict[str, float]] | None = None
    published_name: str = "published"
    reference: str | None = None

    @cached_property
    def cells(self) -> dict[str, dict[str, Cell]]:
        """{task: {label: Cell}} of the nominal evaluation at each task's largest demonstration count."""
        return cells_by_task(self.records)

    @cached_property
    def table(self) -> dict[str, dict[str, float]]:
        """{task: {label: success rate}} of `cells`."""
        return rates(self.cells)

    @cached_property
    def aggregates(self) -> SeedAggregates:
        return seed_aggregates(self.records, self.cells, self.reference)

    @cached_property
    def labelled_runs(self) -> list[tuple[str, dict]]:
        return labelled_runs(self.records)

    @cached_property
    def demo_counts(self) -> list[int]:
        return demo_counts(self.records)

    @cached_property
    def demo_cells(self) -> dict[int, dict[str, dict[str, Cell]]]:
        """{demonstration count: {task: {label: Cell}}} of a sample-efficiency grid (empty otherwise)."""
        return demo_cells(self.records)

    @cached_property
    def demo_curves(self) -> dict[str, dict[str, dict[int, tuple]]]:
        """{task, and the aggregate: {label: {demonstrations: (rate, low, high)}}} (`comparisons.demo_curves`)."""
        return demo_curves(self.demo_cells)

    @cached_property
    def perturbations(self) -> list[str]:
        return perturbations(self.records)

    @cached_property
    def robustness(self) -> dict[str, dict[str, dict[str, tuple | None]]]:
        """{perturbation: {task, and the aggregate: {label: share of the unperturbed success kept, interval}}}."""
        return robustness(self.records, self.perturbations)

    @cached_property
    def curves(self) -> dict[str, dict[str, dict[int, Cell]]]:
        """{task: {label: {step: Cell}}} of the learning curves (runs evaluated at several checkpoints)."""
        return curve_cells(self.records)
