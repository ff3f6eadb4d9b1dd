"""`obsbench preset`: print a named preset's `--policy.*` overrides, to paste into `lerobot-train`."""

from __future__ import annotations

import argparse
import sys

from lerobot_obsbench.commands import common
from lerobot_obsbench.schema import OBS_SPACES, POLICY_TYPES

NAME = "preset"
HELP = "print the --policy.* overrides of a named preset, to paste into lerobot-train"
EXAMPLE = """obsbench preset --preset real-one-arm --policy obs_act --obs-space pointcloud"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lerobot_obsbench.presets import PRESETS

    p.add_argument("--preset", default="cpu", choices=tuple(PRESETS))
    p.add_argument("--policy", default=POLICY_TYPES[0], choices=POLICY_TYPES)
    p.add_argument("--obs-space", default="pointcloud", choices=OBS_SPACES)
    p.add_argument("--encoder", default=None, help="the encoder you train with (default: the preset's for the space)")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.presets import preset_args

    print(" ".join(preset_args(args.preset, args.policy, args.obs_space, args.encoder)))
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
