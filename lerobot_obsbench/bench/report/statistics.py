"""The report's arithmetic on success rates: a column's pooled Cell with its interval, competition ranking, the
Mean S.R. / Mean Rank summary of a table, and means over tasks; and ReportError, the report's one error type."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from functools import cached_property

from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.stats import seeds_and_episodes_interval, wilson_interval


class ReportError(ObsBenchError, ValueError):
    """Unreadable published table or empty input."""


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


def rates(cells: dict[str, dict[str, Cell]]) -> dict[str, dict[str, float]]:
    return {t: {m: c.rate for m, c in row.items()} for t, row in cells.items()}


def mean_over_tasks(cells: dict[str, dict[str, Cell]]) -> dict[str, float]:
    return {m: s["mean_sr"] for m, s in summarize(rates(cells)).items()}
