"""The report's figures as PNG bytes: one matplotlib set-up (`pyplot`, `figure_png`), the bar and curve charts,
rliable's interval and improvement charts, and one builder per figure, each taking the ReportData and returning
{file name: (caption, PNG)}, empty when it has nothing to draw."""

from __future__ import annotations

import io
import math

import numpy as np

from lerobot_obsbench.bench import aggregates
from lerobot_obsbench.bench.report.comparisons import ALL_TASKS
from lerobot_obsbench.bench.report.data import ReportData
from lerobot_obsbench.bench.report.runs import method_labels
from lerobot_obsbench.bench.report.statistics import Cell
from lerobot_obsbench.envs.perturbations import NOMINAL_VALUE, parse_perturbation

Figure = tuple[str, bytes]  # caption, PNG


def pyplot():
    """matplotlib.pyplot on the Agg backend: the report draws into files, never onto a display."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_png(fig) -> bytes:
    """The figure as PNG bytes; the figure is closed."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    pyplot().close(fig)
    return buffer.getvalue()


def bar_chart(cells: dict[str, dict[str, Cell]]) -> bytes:
    """One panel per task: each method's success rate with its 95% interval."""
    plt = pyplot()
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
    return figure_png(fig)


def curve_chart(
    series: dict[str, list[tuple[float, float]]],
    xlabel: str,
    title: str,
    log_x: bool = False,
    log_y: bool = False,
    ylabel: str = "mean success rate over tasks",
) -> bytes:
    """One line per method through its (x, y) points."""
    plt = pyplot()
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
    return figure_png(fig)


def _bounds(estimate: tuple[float, float | None, float | None]) -> tuple[float, float]:
    """(low, high), the point itself where there is no interval (one seed)."""
    point, low, high = estimate
    return (point, point) if low is None else (low, high)


def interval_chart(estimates: dict[str, dict]):
    """rliable's interval plot of Mean S.R. and IQM per method (one-seed methods: the point only), as a
    matplotlib figure."""
    pyplot()  # rliable draws with pyplot: on the Agg backend
    from rliable import plot_utils

    labels = sorted(estimates)
    points = {m: np.array([estimates[m]["mean_sr"][0], estimates[m]["iqm"][0]]) for m in labels}
    intervals = {m: np.array([_bounds(estimates[m]["mean_sr"]), _bounds(estimates[m]["iqm"])]).T for m in labels}
    fig, _ = plot_utils.plot_interval_estimates(
        points,
        intervals,
        metric_names=list(aggregates.AGGREGATE_NAMES),
        algorithms=labels,
        xlabel="success rate (95% CI over training seeds)",
        xlabel_y_coordinate=-0.35,
        subfigure_width=4.0,
    )
    return fig


def improvement_chart(estimates: dict[tuple[str, str], tuple[float, float, float]]):
    """rliable's probability-of-improvement plot, one bar per (method, reference) pair, as a matplotlib figure."""
    plt = pyplot()
    from rliable import plot_utils

    separator = "\t"  # split back into the two labels by rliable; labels never hold a tab
    points = {f"{x}{separator}{y}": e[0] for (x, y), e in estimates.items()}
    intervals = {f"{x}{separator}{y}": np.array(e[1:]) for (x, y), e in estimates.items()}
    fig, ax = plt.subplots(figsize=(4.5, 0.5 + 0.45 * len(points)))
    plot_utils.plot_probability_of_improvement(
        points,
        intervals,
        pair_separator=separator,
        ax=ax,
        xticks=[0.0, 0.25, 0.5, 0.75, 1.0],
        ticklabelsize="small",
        labelsize="small",
    )
    return fig


def aggregate_figures(data: ReportData) -> dict[str, Figure]:
    """rliable's interval plot of Mean S.R. and IQM, and its probability-of-improvement plot."""
    found = data.aggregates
    figures = {}
    if found.estimates:
        figures["aggregates.png"] = (
            "Mean S.R. and IQM over training seeds and tasks",
            figure_png(interval_chart(found.estimates)),
        )
    if found.pairs:
        figures["probability_of_improvement.png"] = (
            "Probability of improvement (training seeds)",
            figure_png(improvement_chart(found.pairs)),
        )
    return figures


def success_figure(data: ReportData) -> dict[str, Figure]:
    return {"success_by_task.png": ("Success rate per task", bar_chart(data.cells))}


Curve = list[tuple[float, float, float, float]]  # (x, y, low, high) points, sorted by x


def panel_chart(panels: dict[str, dict[str, Curve]], xlabel: str, ylabel: str, ylim=(0, 1), log_x: bool = False):
    """One panel per key of `panels` (a task, the aggregate), one line per method with its interval band; a method
    keeps its colour in every panel and the legend names every method."""
    plt = pyplot()
    methods = sorted({label for curves in panels.values() for label in curves})
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colour = {label: palette[i % len(palette)] for i, label in enumerate(methods)}
    cols = min(4, len(panels))
    rows = math.ceil(len(panels) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.0 * cols, 3.4 * rows), squeeze=False)
    for ax, (title, curves) in zip(axes.flat, panels.items(), strict=False):
        for label, points in sorted(curves.items()):
            xs, ys, lows, highs = zip(*points, strict=True)
            ax.plot(xs, ys, marker="o", color=colour[label])
            ax.fill_between(xs, lows, highs, color=colour[label], alpha=0.15)
        if ylim is not None:
            ax.set_ylim(*ylim)
        if log_x:
            ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_title(title, fontsize=10)
    for ax in list(axes.flat)[len(panels) :]:
        ax.axis("off")
    handles = [plt.Line2D([], [], color=colour[label], marker="o", label=label) for label in methods]
    list(axes.flat)[len(panels) - 1].legend(handles=handles, fontsize=7)
    fig.tight_layout()
    return figure_png(fig)


def learning_curve_figure(data: ReportData) -> dict[str, Figure]:
    """Success rate against training steps, one panel per task, one line per method with its interval band."""
    if not data.curves:
        return {}
    panels = {
        task: {
            label: [(step, cell.rate, *cell.ci95) for step, cell in curve.items()]
            for label, curve in sorted(data.curves[task].items())
        }
        for task in sorted(data.curves)
    }
    chart = panel_chart(panels, "training step", "success rate (test seeds)")
    return {"learning_curves.png": ("Learning curves: success against training steps", chart)}


def loss_figure(data: ReportData) -> dict[str, Figure]:
    """Training loss against step, one line per run."""
    labels = method_labels(data.records)
    series = {
        f"{labels[r['run_id']]} seed {r['config']['seed']} ({r['task']})": [
            tuple(p) for p in r["diagnostics"]["loss_curve"]
        ]
        for r in data.records
        if (r.get("diagnostics") or {}).get("loss_curve")
    }
    if not series:
        return {}
    chart = curve_chart(series, "optimizer step", "Training loss", log_y=True, ylabel="loss")
    return {"training_loss.png": ("Training loss per run", chart)}


def robustness_figures(data: ReportData) -> dict[str, Figure]:
    """Per kind of perturbation, the share of its unperturbed success each method keeps against the perturbation's
    value (the unperturbed scene at 1, where the kind has a nominal value), one panel per task and one over all
    tasks, with intervals over training seeds and episodes."""
    by_kind: dict[str, list[str]] = {}
    for name in data.perturbations:
        by_kind.setdefault(parse_perturbation(name).kind, []).append(name)
    figures = {}
    for kind, names in by_kind.items():
        nominal = NOMINAL_VALUE[kind]
        tasks = sorted({task for name in names for task in data.robustness[name]} - {ALL_TASKS}) + [ALL_TASKS]
        panels = {}
        for task in tasks:
            curves: dict[str, Curve] = {}
            for name in names:
                for label, estimate in data.robustness[name].get(task, {}).items():
                    if estimate is not None:
                        curves.setdefault(label, []).append((parse_perturbation(name).scalar, *estimate))
            panels[task] = {
                label: sorted(points + ([(nominal, 1.0, 1.0, 1.0)] if nominal is not None else []))
                for label, points in curves.items()
            }
        chart = panel_chart(panels, kind, "share of unperturbed success kept", ylim=(0, 1.25))
        figures[f"robustness_{kind}.png"] = (f"Robustness to {kind}: success kept against its value", chart)
    return figures


def sample_efficiency_figure(data: ReportData) -> dict[str, Figure]:
    """Success rate against the number of demonstrations, one panel per task and one over all tasks."""
    if not data.demo_counts:
        return {}
    panels = {
        task: {label: [(n, *estimate) for n, estimate in sorted(curve.items())] for label, curve in row.items()}
        for task, row in sorted(data.demo_curves.items(), key=lambda item: item[0] == ALL_TASKS)
    }
    chart = panel_chart(panels, "demonstrations", "success rate (test seeds)", log_x=True)
    return {"sample_efficiency.png": ("Sample efficiency: success against the number of demonstrations", chart)}
