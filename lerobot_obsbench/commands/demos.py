"""`obsbench demos`: successful scripted-expert demonstrations of a ManiSkill or Meta-World task into a
LeRobotDataset (`datasets.sim_demos`; resumable)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.commands.common import frame_size, positive_int
from lerobot_obsbench.numeric import number_argument

NAME = "demos"
HELP = (
    "record successful scripted-expert demonstrations into a LeRobotDataset "
    "(resumable: rerun the same command after an interruption)"
)
EXAMPLE = """obsbench demos --task PickCube-v1 --episodes 100 --out data/pickcube"""
INTERRUPTED = "the recorded episodes are kept in --out; run the same command to go on"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lerobot_obsbench.envs.base_task import DEMO_SEED_START

    p.add_argument("--task", required=True, help="a ManiSkill task (PickCube-v1) or a Meta-World one (drawer-open-v3)")
    p.add_argument("--episodes", type=positive_int, required=True)
    p.add_argument("--out", type=Path, required=True, help="dataset folder: new, empty, or this recording's (resumed)")
    p.add_argument("--overwrite", action="store_true", help="delete what --out holds first")
    p.add_argument("--image-size", type=frame_size, default=128)
    p.add_argument(
        "--cameras", nargs="+", default=None, help="default: ManiSkill's base_camera, Meta-World's corner2 (LeRobot's)"
    )
    p.add_argument(
        "--seed-start",
        type=number_argument(whole=True, minimum=DEMO_SEED_START),
        default=DEMO_SEED_START,
        help=f"first demonstration seed (>= "
        f"{DEMO_SEED_START}; lower seeds are reserved for evaluation and checkpoint selection)",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        default=1,
        help="processes recording episodes side by side, one env each (the same dataset as 1)",
    )


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.sim_demos import record_demos

    info = record_demos(
        args.task,
        args.episodes,
        args.out,
        image_size=args.image_size,
        cameras=args.cameras,
        seed_start=args.seed_start,
        overwrite=args.overwrite,
        workers=args.workers,
    )
    print(
        f"{args.out}: {len(info['seeds'])} episodes of {args.task}; expert success rate "
        f"{info['expert_success_rate']:.0%} over {info['attempts']} attempts (seeds {info['seeds'][0]}..)"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
