"""`obsbench convert-results`: convert a results file of lerobot-obsbench 0.1 (one record per run) to the current
train + eval records."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common

NAME = "convert-results"
HELP = (
    "convert a results file written by lerobot-obsbench 0.1 (one record "
    "per run) into train + eval records; checkpoints and evaluations are kept"
)
EXAMPLE = """obsbench convert-results outputs/bench/old/results.jsonl"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("results", type=Path)


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.bench.results import convert_v1

    backup = convert_v1(args.results)
    print(f"{args.results}: converted to train + eval records; the original is kept as {backup}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
