"""`obsbench push`: upload a grid run or a checkpoint to the Hugging Face Hub with a model card (`bench.hub`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common

NAME = "push"
HELP = (
    "upload a grid run (OUT/runs/<run_id>) or a pretrained_model directory to the Hugging Face Hub, with a "
    "model card: space, encoder, policy, task, dataset, budget, evaluation, install line"
)
EXAMPLE = """obsbench push outputs/bench/quick/runs/RUN_ID me/act-pcd-pickcube"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", type=Path, help="OUT/runs/<run_id> of `obsbench run`, or a pretrained_model directory")
    p.add_argument("repo_id", help="ORG/NAME on the Hub")
    p.add_argument(
        "--checkpoint", default="best", choices=("best", "last"), help="for a grid run: which evaluated checkpoint"
    )
    p.add_argument("--eval", type=Path, default=None, help="for a checkpoint directory: an `obsbench eval --out` file")
    p.add_argument("--private", action="store_true")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.bench.hub import push_checkpoint

    url = push_checkpoint(args.path, args.repo_id, args.checkpoint, args.private, args.eval)
    print(f"{args.path} -> {url} (load it with --policy.path={args.repo_id}; the model card names the install line)")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
