"""`obsbench replay`: replay recorded scripted demonstrations open-loop in the evaluation env, from their seeds, and
check each succeeds where its recording did (`datasets.replay`)."""

from __future__ import annotations

import argparse
import sys

from lerobot_obsbench.commands import common

NAME = "replay"
HELP = (
    "replay an `obsbench demos` dataset's episodes open-loop in the evaluation env from their recorded seeds: each "
    "must succeed at its last recorded action (controller, seeds and simulator agree); exit code 1 when one does not"
)
EXAMPLE = """obsbench replay --root data/pickcube --episodes 20"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--root", required=True, help="dataset directory written by `obsbench demos`")
    p.add_argument("--episodes", type=common.positive_int, default=None, help="the first N episodes (default: all)")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.replay import replay_demonstrations

    found = replay_demonstrations(args.root, args.episodes)
    for episode in found["per_episode"]:
        if episode["success_at"] != episode["length"]:
            where = "never" if episode["success_at"] is None else f"at step {episode['success_at']}"
            print(
                f"  episode {episode['episode']} (seed {episode['seed']}): recorded {episode['length']} steps, "
                f"replayed success {where}"
            )
    print(
        f"{found['task']}: {found['reproduced']} of {found['episodes']} episodes replayed open-loop succeed at their "
        "last recorded action"
    )
    return 0 if found["reproduced"] == found["episodes"] else 1


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
