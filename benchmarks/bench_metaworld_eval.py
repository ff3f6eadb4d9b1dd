"""What a Meta-World evaluation costs on this machine, per env step with the policy, by what the policy makes the
env render: nothing (the blind and oracle controls), depth (`depth`), colour (`rgb`), colour and depth (`rgbd`,
`pointcloud`, `pointmap`). The cost model prices Meta-World evaluations and demonstrations with these rates, as
it prices ManiSkill's with `bench_eval`'s.

Each space's policy is the `cpu` preset's obs_act (the main job's sizes), trained as a grid's run is (the grid's
lerobot-train command) for a few steps on a few scripted demonstrations (its success does not matter: the rate is
per env step); each is then evaluated by `envs.evaluate.evaluate` (what `obsbench eval` and a grid's evaluation
units run) on the same seeds with a short episode budget, and timed from the env's start to its last episode.
Spaces are evaluated in turn, `--rounds` times over, so whatever else the machine does falls on all alike; a
space's rate is its env steps over its seconds summed over the rounds.

    .venv/bin/python -m benchmarks.bench_metaworld_eval [--task drawer-open-v3] [--image-size 64] [--episodes 4]
        [--episode-length 50] [--rounds 2] [--work DIR] [--out FILE]

`--work DIR` keeps the demonstrations and checkpoints (made again only where missing), so the timed part can be
rerun alone. Writes benchmarks/results/metaworld_eval_cpu.json.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
import time
from pathlib import Path

from benchmarks.common import write
from lerobot_obsbench.bench.cost import rendered_for
from lerobot_obsbench.bench.grid import parse_grid
from lerobot_obsbench.bench.units import train_command
from lerobot_obsbench.cli import main as obsbench
from lerobot_obsbench.envs.evaluate import evaluate
from lerobot_obsbench.numeric import number_argument
from lerobot_obsbench.schema import MIN_IMAGE_SIZE

SPACES = ("none", "state", "depth", "rgb", "rgbd", "pointcloud")


def checkpoint(work: Path, dataset: Path, run) -> Path:
    """The checkpoint of `run` (a grid's run) under `work`, trained as the grid trains it, by stock lerobot-train,
    unless it is there."""
    out = work / f"train-{run.obs_space}"
    model = out / "checkpoints" / "last" / "pretrained_model"
    if model.exists():
        return model
    environment = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
    print(f"training {run.obs_space} ...", flush=True)
    command = train_command(run, dataset, out, run.steps(), "cpu", save_every=run.steps())
    subprocess.run(command, env=environment, check=True, capture_output=True, text=True)
    return model


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="drawer-open-v3")
    parser.add_argument("--image-size", type=number_argument(whole=True, minimum=MIN_IMAGE_SIZE), default=64)
    parser.add_argument("--episodes", type=number_argument(whole=True, minimum=1), default=4)
    parser.add_argument("--episode-length", type=number_argument(whole=True, minimum=1), default=50)
    parser.add_argument("--rounds", type=number_argument(whole=True, minimum=1), default=2)
    parser.add_argument("--work", type=Path, help="keep demonstrations and checkpoints here (default: a temp dir)")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as scratch:
        work = args.work or Path(scratch)
        dataset = work / "demos"
        demos = ["demos", "--task", args.task, "--episodes", "2", "--out", str(dataset)]
        if obsbench([*demos, "--image-size", str(args.image_size)]) != 0:
            raise SystemExit("recording the demonstrations failed")
        grid = parse_grid(
            {"tasks": [args.task], "obs_spaces": list(SPACES), "preset": "cpu", "demos": [2], "batch_size": 4}
            | {"steps": 4, "checkpoints": 1, "image_size": args.image_size}
        )
        runs = {run.obs_space: run for run in grid.expand()}
        models = {space: checkpoint(work, dataset, run) for space, run in runs.items()}
        totals = {space: [0, 0.0] for space in SPACES}
        for _ in range(args.rounds):
            for space, model in models.items():
                start = time.perf_counter()
                result = evaluate(
                    model,
                    args.task,
                    args.episodes,
                    progress=False,
                    image_size=args.image_size,
                    episode_length=args.episode_length,
                )
                totals[space][0] += sum(record["length"] for record in result["per_episode"])
                totals[space][1] += time.perf_counter() - start
    rows = [
        {
            "obs_space": space,
            "rendered": rendered_for(space, runs[space].point_features),
            "env_steps": steps,
            "seconds": round(seconds, 2),
            "env_steps_per_s": round(steps / seconds, 2),
        }
        for space, (steps, seconds) in totals.items()
    ]
    for row in rows:
        print(f"{row['obs_space']:>10} ({row['rendered']}): {row['env_steps_per_s']} env steps/s", flush=True)
    write(
        "metaworld_eval_cpu",
        {
            "task": args.task,
            "image_size": args.image_size,
            "episodes": args.episodes,
            "episode_length": args.episode_length,
            "rounds": args.rounds,
            "preset": "cpu",
            "rows": rows,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
