"""`obsbench push-dataset`: upload a LeRobotDataset to the Hugging Face Hub."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common

NAME = "push-dataset"
HELP = "upload a LeRobotDataset (e.g. from obsbench demos) to the Hub"
EXAMPLE = """obsbench push-dataset data/pickcube me/obsbench-pickcube"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("root", type=Path, help="dataset directory")
    p.add_argument("repo_id", help="ORG/NAME on the Hub")
    p.add_argument("--private", action="store_true")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.bench.hub import push_dataset

    push_dataset(args.root, args.repo_id, args.private)
    print(f"{args.root} -> {args.repo_id} (LeRobotDataset({args.repo_id!r}) downloads it)")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
