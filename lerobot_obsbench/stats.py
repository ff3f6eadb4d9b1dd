"""Success-rate statistics."""

from __future__ import annotations

import math

import numpy as np

from lerobot_obsbench.errors import ConfigError


def success_summary(successes: list[bool]) -> dict:
    """The success line of an evaluation's result: episodes, successes, rate and its 95% Wilson interval (rate
    None and interval [0, 1] when no episode ran), rounded to 4 decimals."""
    n, wins = len(successes), int(sum(bool(s) for s in successes))
    low, high = wilson_interval(wins, n) if n else (0.0, 1.0)
    return {
        "episodes": n,
        "successes": wins,
        "success_rate": round(wins / n, 4) if n else None,
        "ci95": [round(low, 4), round(high, 4)],
    }


def per_seed(seeds: list[int], successes: list[bool], lengths: list[int]) -> dict:
    """Compact per-episode outcomes for results files: the seeds (or episode numbers), success as a string ('1'
    success, '.' failure) and the episode lengths, so two evaluations of one checkpoint compare seed by seed."""
    return {
        "seeds": list(seeds),
        "success": "".join("1" if s else "." for s in successes),
        "length": list(lengths),
    }


def wilson_interval(successes: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """95% Wilson score interval of a success rate (well behaved at 0 and n successes, unlike the normal one)."""
    if n <= 0:
        raise ConfigError("n must be positive")
    if not 0 <= successes <= n:
        raise ConfigError(f"successes must be in 0..{n}; got {successes}")
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # exact ends at 0/n and n/n, where rounding would leave the bound a hair off the rate itself
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == n else min(1.0, centre + half)
    return low, high


def _check_runs(runs: list[tuple[int, int]]) -> None:
    if not runs:
        raise ConfigError("runs must name at least one training seed")
    for k, n in runs:
        if n <= 0 or not 0 <= k <= n:
            raise ConfigError(f"each run needs 0 <= successes <= episodes and episodes > 0; got {k}/{n}")


def _replicates(runs: list[tuple[int, int]], rng: np.random.Generator, drawn: np.ndarray) -> np.ndarray:
    """A pooled success rate per bootstrap replicate: the training seeds `drawn` (replicates, seeds) of `runs`,
    each drawn seed's rate redrawn from its Jeffreys posterior Beta(k + 1/2, n - k + 1/2) and its episodes pooled."""
    successes, episodes = np.array(runs, dtype=float).T
    k, n = successes[drawn], episodes[drawn]
    return (rng.beta(k + 0.5, n - k + 0.5) * n).sum(axis=1) / n.sum(axis=1)


def seeds_and_episodes_interval(
    runs: list[tuple[int, int]], reps: int = 20000, level: float = 0.95, seed: int = 0
) -> tuple[float, float]:
    """Percentile interval of a pooled success rate that covers training-seed variance as well as evaluation
    episodes: a two-level bootstrap over `runs` [(successes, episodes) of each training seed]. Each replicate
    draws the training seeds with replacement, then redraws each drawn seed's rate from its own episodes, and
    pools the episodes as the point estimate does. The episode level draws from the seed's Jeffreys posterior
    Beta(k + 1/2, n - k + 1/2) rather than resampling its episodes, so a seed at 0/n or n/n still varies (the
    same reason a Wilson interval is not empty there). `seed`: the bootstrap's own seed (reproducible reports)."""
    _check_runs(runs)
    rng = np.random.default_rng(seed)
    rates = _replicates(runs, rng, rng.integers(0, len(runs), size=(reps, len(runs))))
    tail = (1 - level) / 2
    low, high = np.quantile(rates, [tail, 1 - tail])
    # as the Jeffreys interval does at 0/n and n/n: the posterior's tail would otherwise leave out the rate itself
    successes, episodes = np.array(runs, dtype=float).T
    if not successes.any():
        low = 0.0
    if (successes == episodes).all():
        high = 1.0
    return float(low), float(high)


def mean_over_tasks_interval(
    tasks: list[list[tuple[int, int]]], reps: int = 20000, level: float = 0.95, seed: int = 0
) -> tuple[float, float, float]:
    """(point, low, high) of the mean over `tasks` of each task's pooled success rate (each task: its training
    seeds' (successes, episodes)), the interval by `seeds_and_episodes_interval`'s bootstrap stratified by task."""
    for runs in tasks:
        _check_runs(runs)
    rng = np.random.default_rng(seed)
    replicates = [_replicates(r, rng, rng.integers(0, len(r), size=(reps, len(r)))) for r in tasks]
    point = np.mean([sum(k for k, _ in r) / sum(n for _, n in r) for r in tasks])
    tail = (1 - level) / 2
    low, high = np.quantile(np.mean(replicates, axis=0), [tail, 1 - tail])
    return float(point), float(low), float(high)


def relative_success(
    tasks: list[list[tuple[int, int, int, int]]], reps: int = 20000, level: float = 0.95, seed: int = 0
) -> tuple[float, float, float] | None:
    """How much of its unperturbed success a method keeps under a perturbation, over `tasks` — each task a list of
    its training seeds' (successes perturbed, episodes perturbed, successes unperturbed, episodes unperturbed) — as
    (point, low, high): the mean over tasks of each task's pooled perturbed rate over its pooled unperturbed rate
    (1: as often as unperturbed). The interval is `seeds_and_episodes_interval`'s bootstrap stratified by task, the
    same training seeds drawn for both rates of a replicate. None where some task never succeeds unperturbed (its
    ratio has no meaning)."""
    if not tasks:
        raise ConfigError("relative_success needs at least one task")
    for seeds in tasks:
        _check_runs([(kp, n) for kp, n, _, _ in seeds] + [(k0, n) for _, _, k0, n in seeds])
    if any(sum(k0 for _, _, k0, _ in seeds) == 0 for seeds in tasks):
        return None
    rng = np.random.default_rng(seed)
    point, replicates = [], []
    for seeds in tasks:
        perturbed, nominal = [(kp, n) for kp, n, _, _ in seeds], [(k0, n) for _, _, k0, n in seeds]
        point.append(
            (sum(k for k, _ in perturbed) / sum(n for _, n in perturbed))
            / (sum(k for k, _ in nominal) / sum(n for _, n in nominal))
        )
        drawn = rng.integers(0, len(seeds), size=(reps, len(seeds)))
        replicates.append(_replicates(perturbed, rng, drawn) / _replicates(nominal, rng, drawn))
    tail = (1 - level) / 2
    low, high = np.quantile(np.mean(replicates, axis=0), [tail, 1 - tail])
    return float(np.mean(point)), float(low), float(high)
