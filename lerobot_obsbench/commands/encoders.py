"""`obsbench encoders`: list the registered encoders and training augmentations, and the observation spaces each
accepts."""

from __future__ import annotations

import argparse
import sys

from lerobot_obsbench.commands import common
from lerobot_obsbench.schema import available_spaces, space_info

NAME = "encoders"
HELP = "list registered encoders and augmentations, and the observation spaces they accept"
EXAMPLE = """obsbench encoders --obs-space pointcloud"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--obs-space", choices=available_spaces(), help="only encoders and augmentations accepting this space"
    )


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.augmentations import augmentation_info, available_augmentations
    from lerobot_obsbench.encoders import available_encoders, default_encoder, encoder_info

    for name in available_encoders(args.obs_space):
        info = encoder_info(name)
        weights = f"; pretrained: {info.pretrained}" if info.pretrained else ""
        print(f"{name:10s} spaces: {', '.join(info.spaces):32s} {info.summary}{weights}")
    for space in available_spaces(lambda s: s.fused):
        if args.obs_space in (None, space):
            print(
                f"\n{space}: one encoder per part ({', '.join(space_info(space).parts)}) joined by '+', e.g. "
                f"--policy.encoder={default_encoder(space)} (the default)"
            )
    print("\naugmentations (--policy.augment=NAME[+NAME...], in training only):")
    for name in available_augmentations(args.obs_space):
        info = augmentation_info(name)
        print(f"{name:16s} spaces: {', '.join(info.spaces):26s} {info.summary}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
