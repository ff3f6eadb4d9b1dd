"""Across-task aggregates over training seeds, as Agarwal et al. (NeurIPS 2021, "Deep RL at the Edge of the
Statistical Precipice") recommend and their `rliable` library computes: Mean S.R. and the interquartile mean
(IQM) with stratified bootstrap intervals, and the probability that a method improves on another (per task, the
chance that a random training seed of one beats a random seed of the other; averaged over tasks), with its
interval. A run's score is its success rate on its test episodes; runs are training seeds.

rliable's bootstrap resamples runs within each task, so a method enters only with the same number of training
seeds on every task of the table (its score matrix is seeds x tasks); one with one seed per task gets point
estimates and no interval (nothing to resample). Every bootstrap draws from its own fixed seed, so a report
is reproducible and one method's interval does not depend on which others are in it.
"""

from __future__ import annotations

import warnings

import numpy as np

BOOTSTRAP_REPS = 2000
BOOTSTRAP_SEED = 0
AGGREGATE_NAMES = ("Mean S.R.", "IQM")


def seed_scores(cells: dict) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """({label: (training seeds x tasks) success rates}, {label: why it is left out}) from report cells
    ({task: {label: Cell}}), tasks in the table's order."""
    tasks = list(cells)
    labels = list(dict.fromkeys(m for row in cells.values() for m in row))
    scores, left_out = {}, {}
    for label in labels:
        missing = [t for t in tasks if label not in cells[t]]
        if missing:
            left_out[label] = f"not evaluated on {', '.join(missing)}"
            continue
        counts = {cells[t][label].seeds for t in tasks}
        if len(counts) > 1:
            left_out[label] = f"different numbers of training seeds across tasks ({sorted(counts)})"
            continue
        scores[label] = np.array([[k / n for k, n in cells[t][label].runs] for t in tasks]).T
    return scores, left_out


def _interval(data, func) -> tuple[float, np.ndarray]:
    """rliable's stratified bootstrap (percentile, 95%) of `func` over `data` (one matrix, or a pair)."""
    from rliable import library as rly

    caller_state = np.random.get_state()
    # rliable's stratified bootstrap draws its indices from NumPy's global generator whatever random_state says:
    # seeding it (and giving the caller's state back) makes the intervals reproducible
    np.random.seed(BOOTSTRAP_SEED)
    try:
        with warnings.catch_warnings():
            # arch deprecates the RandomState rliable hands it; the draws stay the same
            warnings.simplefilter("ignore", FutureWarning)
            point, interval = rly.get_interval_estimates(
                {"x": data}, func, reps=BOOTSTRAP_REPS, random_state=np.random.RandomState(BOOTSTRAP_SEED)
            )
    finally:
        np.random.set_state(caller_state)
    return point["x"], interval["x"]


def aggregate_estimates(scores: dict[str, np.ndarray]) -> dict[str, dict]:
    """{label: {"seeds", "mean_sr": (point, low, high), "iqm": (point, low, high)}}; low/high None with one seed."""
    from rliable import metrics

    def both(matrix):
        return np.array([metrics.aggregate_mean(matrix), metrics.aggregate_iqm(matrix)])

    out = {}
    for label, matrix in scores.items():
        point, interval = _interval(matrix, both)
        one_seed = matrix.shape[0] == 1
        out[label] = {
            "seeds": int(matrix.shape[0]),
            **{
                key: (
                    float(point[i]),
                    None if one_seed else float(interval[0][i]),
                    None if one_seed else float(interval[1][i]),
                )
                for i, key in enumerate(("mean_sr", "iqm"))
            },
        }
    return out


def improvement_estimate(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float] | None:
    """P(x > y) of two score matrices over the same tasks, with its 95% interval; None when both have one
    training seed (one run against one run gives 0, 1/2 or 1 per task: not an estimate)."""
    from rliable import metrics

    if x.shape[0] == 1 and y.shape[0] == 1:
        return None
    point, interval = _interval([x, y], metrics.probability_of_improvement)
    return float(point), float(interval[0]), float(interval[1])


def interval_text(estimate: tuple[float, float | None, float | None]) -> str:
    point, low, high = estimate
    return f"{point:.2f}" if low is None else f"{point:.2f} [{low:.2f}, {high:.2f}]"
