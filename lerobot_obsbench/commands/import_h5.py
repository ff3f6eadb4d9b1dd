"""`obsbench import-h5`: official ManiSkill trajectories (.h5 + .json) into the schema, by replaying their env
states with this plugin's cameras (`datasets.maniskill_import`; resumable)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.commands.common import frame_size, positive_int

NAME = "import-h5"
HELP = "convert official ManiSkill trajectories (.h5 + .json) into the schema by replaying their env states"
EXAMPLE = """obsbench import-h5 --h5 demos/PickCube-v1/motionplanning/trajectory.h5 --out data/pickcube_h5"""
INTERRUPTED = "the replayed episodes are kept in --out; run the same command to go on"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--h5", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True, help="dataset folder: new, empty, or this import's (resumed)")
    p.add_argument("--overwrite", action="store_true", help="delete what --out holds first")
    p.add_argument("--image-size", type=frame_size, default=128)
    p.add_argument("--cameras", nargs="+", default=["base_camera"])
    p.add_argument("--max-episodes", type=positive_int, default=None)
    p.add_argument("--all", action="store_true", help="also import unsuccessful episodes")
    p.add_argument("--asset-dir", default=None, help="ManiSkill asset directory, for tasks with assets (TurnFaucet)")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.maniskill_import import import_trajectories

    info = import_trajectories(
        args.h5,
        args.out,
        image_size=args.image_size,
        cameras=args.cameras,
        max_episodes=args.max_episodes,
        only_success=not args.all,
        asset_dir=args.asset_dir,
        overwrite=args.overwrite,
    )
    print(f"{args.out}: {len(info['episode_ids'])} {info['task']} episodes imported from {args.h5}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
