"""The cost model's measured rates, derived from the benchmarks' results and written into the package's rates file.

`lerobot_obsbench/bench/rates.json` holds every rate `obsbench run --dry-run` prices a grid with. The measured ones
come from benchmark results under `benchmarks/results/`; this tool derives them again and rewrites them in the file
(the bounds and guesses it holds beside them, docs/performance.md#the-cost-model, are left as they are):

- cpu evaluation env steps/s per lockstep batch size: `bench_eval` (`eval_cpu.json`), every row summed;
- cpu per-task evaluation factors: `bench_grid_cost` on the cpu-suite's clean run (`grid_cost_cpu-suite.json`);
- the scripted experts' mean episode length per task: `bench_experts` (`experts.json`, ManiSkill's tasks, and
  `experts_metaworld.json`, Meta-World's);
- cpu Meta-World evaluation env steps/s by what the env renders for the policy: `bench_metaworld_eval`
  (`metaworld_eval_cpu.json`), the slowest space of each kind;
- cuda evaluation env steps/s: the device check's rerun (`device_check_cuda_rerun.json`);
- cuda training samples/s: the device check's quick-grid steps (cpu and tiny presets; the tiny one is bounded by
  them) and its ACT rows at the paper's sizes (image: their mean; point: PointNet there and SpUNet-34 from
  `train_step_cuda_paper.json`; none: not measured, the image rate bounds it); the dp3 preset's are not measured
  on a GPU: the paper preset's stand in.

    .venv/bin/python -m benchmarks.refresh_rates            # rewrite the measured rates
    .venv/bin/python -m benchmarks.refresh_rates --check    # exit 1, naming each rate that differs
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path
from statistics import mean

from benchmarks.common import RESULTS
from lerobot_obsbench.bench.cost import RATES

RATES_FILE = Path(__file__).resolve().parents[1] / "lerobot_obsbench" / "bench" / "rates.json"


class RatesError(ValueError):
    """A benchmark result the rates cannot be derived from."""


def _load(results: Path, name: str) -> dict:
    return json.loads((results / name).read_text())


def cpu_eval_totals(results: Path = RESULTS) -> dict[int, tuple[int, float]]:
    """lockstep batch size -> (env steps, seconds) over every row of `eval_cpu.json`; refuses a row whose seeds'
    outcomes differ from the first batch size's (its rate would time different episodes)."""
    totals = {}
    for rows in _load(results, "eval_cpu.json")["with_policy"].values():
        for row in rows:
            if not row["same_results_as_first"]:
                raise RatesError(f"eval_cpu.json: batch size {row['batch_size']} changed the episodes' outcomes")
            steps, seconds = totals.get(row["batch_size"], (0, 0.0))
            totals[row["batch_size"]] = (steps + row["env_steps"], seconds + row["seconds"])
    return totals


def cuda_evaluations(results: Path = RESULTS) -> list[dict]:
    """The GPU device check's evaluation rows: one env on the CPU simulation, and the lockstep batch."""
    rerun = _load(results, "device_check_cuda_rerun.json")
    if rerun["device"] != "cuda":
        raise RatesError("device_check_cuda_rerun.json was not run on a GPU")
    return [rerun["stages"]["cpu_simulation"]["with_policy_one_env"], rerun["stages"]["success"]["physx_cpu"]]


def cuda_train_rates(results: Path = RESULTS) -> dict[str, dict[str, float]]:
    """preset -> space kind -> training samples/s on the GPU, from the device check (and SpUNet-34's earlier row)."""
    check = _load(results, "device_check_cuda.json")
    if "H200" not in check["stages"]["machine"]["nvidia_smi"]:
        raise RatesError("device_check_cuda.json did not run on an H200, the card the cuda rates name")
    train = check["stages"]["train_step"]
    quick = {row["obs_space"]: row["samples_per_s"] for row in train["quick_grid"]}
    small = {"image": quick["rgb"], "point": quick["pointcloud"], "none": min(quick["none"], quick["state"])}
    act = [row for row in train["rows"] if row["policy"] == "obs_act" and "@" not in row["encoder"]]
    images = [row["steps_per_s"] * row["batch"] for row in act if row["obs_space"] != "pointcloud"]
    points = [row["steps_per_s"] * row["batch"] for row in act if row["encoder"] == "pointnet"]
    earlier = _load(results, "train_step_cuda_paper.json")["rows"]
    points += [
        r["steps_per_s"] * r["batch"] for r in earlier if r["policy"] == "obs_act" and r["encoder"] == "spunet34"
    ]
    if not images or not points:
        raise RatesError("the device check has no ACT rows at the paper's sizes for images and point clouds")
    small = {kind: round(rate, -1) for kind, rate in small.items()}
    image = round(mean(images), -1)
    paper = {"image": image, "point": round(mean(points), -1), "none": image}
    return {"tiny": small, "cpu": small, "paper": paper, "dp3": paper}


def metaworld_eval_rates(results: Path = RESULTS) -> dict[str, float]:
    """What the env renders for the policy -> Meta-World env steps/s, the slowest space rendering it."""
    rates: dict[str, float] = {}
    for row in _load(results, "metaworld_eval_cpu.json")["rows"]:
        rates[row["rendered"]] = min(rates.get(row["rendered"], row["env_steps_per_s"]), row["env_steps_per_s"])
    return rates


def expert_mean_steps(results: Path = RESULTS) -> dict[str, float]:
    """task -> its scripted expert's mean episode length (a task whose expert never succeeded is left out)."""
    rows = [row for name in ("experts.json", "experts_metaworld.json") for row in _load(results, name)["rows"]]
    return {row["task"]: row["mean_steps"] for row in rows if row["mean_steps"] is not None}


# benchmark result -> the rates derived from it
SOURCES = {
    "eval_cpu.json": ["eval_steps_per_second.cpu", "eval_rate_image_size"],
    "metaworld_eval_cpu.json": ["metaworld_eval_steps_per_second.cpu"],
    "experts.json": ["expert_mean_steps"],
    "experts_metaworld.json": ["expert_mean_steps"],
    "grid_cost_cpu-suite.json": ["eval_task_factor.cpu"],
    "device_check_cuda_rerun.json": ["eval_steps_per_second.cuda"],
    "device_check_cuda.json": ["train_samples_per_second.cuda"],
    "train_step_cuda_paper.json": ["train_samples_per_second.cuda.paper.point"],
}


def provenance(results: Path, name: str, known: dict) -> dict:
    """Where a rate came from: the result file (its content's hash), the machine it names, the date it was
    measured (the result's own, else the day this file first took that content: `known` is the rates file's
    earlier record)."""
    data = _load(results, name)
    machine = data.get("machine") or data["stages"]["machine"]
    digest = hashlib.sha256((results / name).read_bytes()).hexdigest()[:16]
    earlier = known.get(name, {})
    date = machine.get("date") or (earlier["date"] if earlier.get("sha256") == digest else time.strftime("%Y-%m-%d"))
    return {
        "gives": SOURCES[name],
        "sha256": digest,
        "machine": f"{machine['cpu_count']}-core CPU" + (f", {machine['cuda']}" if machine.get("cuda") else ""),
        "date": date,
    }


def measured_rates(results: Path = RESULTS, known: dict | None = None) -> dict:
    """The rates file's measured entries, as the benchmarks' results under `results` give them, with each result's
    provenance (`known`: the rates file's `sources`, whose dates carry over while a result is unchanged)."""
    totals = cpu_eval_totals(results)
    factors = _load(results, "grid_cost_cpu-suite.json")["evaluation"]
    known = RATES.get("sources", {}) if known is None else known
    return {
        "sources": {name: provenance(results, name, known) for name in SOURCES},
        "eval_steps_per_second": {
            "cpu": {str(n): round(steps / seconds, 1) for n, (steps, seconds) in sorted(totals.items())},
            "cuda": {str(r["batch_size"]): r["env_steps_per_s"] for r in cuda_evaluations(results)},
        },
        "eval_rate_image_size": _load(results, "eval_cpu.json")["image_size"],
        "metaworld_eval_steps_per_second": {"cpu": metaworld_eval_rates(results)},
        "expert_mean_steps": expert_mean_steps(results),
        "eval_task_factor": {"cpu": {task: row["factor"] for task, row in factors.items()}},
        "train_samples_per_second": {"cuda": cuda_train_rates(results)},
    }


def merged(rates: dict, measured: dict) -> dict:
    """`rates` with each of `measured`'s entries replaced (nested mappings merged key by key)."""
    out = dict(rates)
    for key, value in measured.items():
        out[key] = merged(rates.get(key, {}), value) if isinstance(value, dict) and key in rates else value
    return out


def differences(old, new, where: str = "") -> list[str]:
    """Each rate that differs between two rates mappings, as `path: old -> new`."""
    if isinstance(old, dict) and isinstance(new, dict):
        return [
            d for key in sorted(set(old) | set(new)) for d in differences(old.get(key), new.get(key), f"{where}.{key}")
        ]
    return [] if old == new else [f"{where.lstrip('.')}: {old} -> {new}"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if a measured rate differs")
    args = parser.parse_args(argv)
    refreshed = merged(RATES, measured_rates())
    changed = differences(RATES, refreshed)
    for line in changed:
        print(line)
    if args.check:
        print(f"{len(changed)} rates differ from the benchmarks' results" if changed else "rates up to date")
        return 1 if changed else 0
    RATES_FILE.write_text(json.dumps(refreshed, indent=2) + "\n")
    print(f"{len(changed)} rates changed in {RATES_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
