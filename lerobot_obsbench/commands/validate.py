"""`obsbench validate`: check that a LeRobotDataset serves each observation space, from its metadata and every
frame the asked spaces train from, decoded as training decodes it (`datasets.validation`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.errors import MissingFileError
from lerobot_obsbench.schema import available_spaces

NAME = "validate"
HELP = (
    "check that a LeRobotDataset serves each observation space: keys and shapes, then every frame the asked spaces "
    "train from (depth, intrinsics and camera pose arrays; colour and LeRobot's depth maps decoded), saying what it "
    "read (docs/observation-spaces.md); exit code 1 when an asked space fails, 2 when a file cannot be decoded or "
    "LeRobot depth holds no millimetres"
)
EXAMPLE = """obsbench validate --root data/pickcube --obs-space pointcloud"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--root", required=True, help="dataset directory")
    p.add_argument("--repo-id", default="local/dataset")
    p.add_argument("--obs-space", default="all", choices=("all", *available_spaces()))
    p.add_argument("--cameras", nargs="*", default=[], help="camera names (default: every camera found)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="check the metadata only (default: also read every frame the asked spaces train from)",
    )


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.validation import validate_dataset

    if not (Path(args.root) / "meta" / "info.json").is_file():
        raise MissingFileError(f"{args.root} is not a LeRobot dataset (no meta/info.json)")
    return validate_dataset(args.root, args.repo_id, args.obs_space, args.cameras or None, quick=args.quick)


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
