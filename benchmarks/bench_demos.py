"""Expert demonstration speed against the worker count W (`obsbench demos --workers W`), side by side in one run.

Each W records the same episodes of the task into a fresh folder: the episode phase (workers started, every
episode simulated and staged) is timed apart from the dataset assembly that follows it (which does not depend on
W). Also reported: whether the first successful seeds are the same as with the first W.

    .venv/bin/python -m benchmarks.bench_demos [--task PickCube-v1] [--episodes 30] [--image-size 64]
        [--workers 1 2] [--out FILE]

Writes benchmarks/results/demos_cpu.json.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path
from unittest import mock

from benchmarks.common import write
from lerobot_obsbench.datasets import sim_demos


def record(task: str, episodes: int, image_size: int, workers: int, folder: Path) -> dict:
    assembled = {}
    original = sim_demos.assemble

    def timed_assemble(*args, **kwargs):  # the episode phase ends where assembly starts
        assembled["start"] = time.perf_counter()
        original(*args, **kwargs)
        assembled["end"] = time.perf_counter()

    start = time.perf_counter()
    with mock.patch.object(sim_demos, "assemble", timed_assemble):
        info = sim_demos.record_demos(task, episodes, folder, image_size=image_size, workers=workers)
    episode_s = assembled["start"] - start
    return {
        "workers": workers,
        "episodes_per_min": round(60 * episodes / episode_s, 1),
        "episode_phase_s": round(episode_s, 1),
        "assembly_s": round(assembled["end"] - assembled["start"], 1),
        "attempts": info["attempts"],
        "seeds": info["seeds"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="PickCube-v1")
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--image-size", type=int, default=64)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for workers in args.workers:
            folder = Path(tmp) / f"w{workers}"
            row = record(args.task, args.episodes, args.image_size, workers, folder)
            row["same_seeds_as_first"] = row["seeds"] == (rows[0]["seeds"] if rows else row["seeds"])
            rows.append(row)
            shutil.rmtree(folder)
            print(
                f"W={workers}: {row['episodes_per_min']} episodes/min ({row['episode_phase_s']} s, assembly "
                f"{row['assembly_s']} s), same seeds: {row['same_seeds_as_first']}"
            )
    write(
        "demos_cpu",
        {"task": args.task, "episodes": args.episodes, "image_size": args.image_size, "rows": rows},
        args.out,
    )


if __name__ == "__main__":
    main()
