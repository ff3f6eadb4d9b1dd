"""`obsbench preset`: print a named preset's `--policy.*` overrides, to paste into `lerobot-train`."""

from __future__ import annotations

import argparse
import sys

from lerobot_obsbench.commands import common
from lerobot_obsbench.errors import UsageError
from lerobot_obsbench.schema import POLICY_TYPES, available_spaces

NAME = "preset"
HELP = "print the --policy.* overrides of a named preset, to paste into lerobot-train"
EXAMPLE = """obsbench preset --preset real-one-arm --policy obs_act --obs-space pointcloud"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lerobot_obsbench.policies.named import NAMED_POLICIES
    from lerobot_obsbench.presets import PRESETS

    p.add_argument("--preset", default="cpu", choices=tuple(PRESETS))
    p.add_argument(
        "--policy", default=POLICY_TYPES[0], choices=(*POLICY_TYPES, *NAMED_POLICIES), help="policy type or named type"
    )
    p.add_argument(
        "--obs-space", default=None, choices=available_spaces(), help="default: pointcloud, or the named type's"
    )
    p.add_argument("--encoder", default=None, help="the encoder you train with (default: the preset's for the space)")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.policies.named import NAMED_POLICIES
    from lerobot_obsbench.presets import policy_flags, preset_overrides

    policy, obs_space, encoder = args.policy, args.obs_space or "pointcloud", args.encoder
    if args.policy in NAMED_POLICIES:  # act_pcd = obs_act + pointcloud + pointnet
        policy, obs_space, named_encoder = NAMED_POLICIES[args.policy]
        if args.obs_space not in (None, obs_space):
            raise UsageError(f"--policy {args.policy} fixes the observation space to {obs_space}; drop --obs-space")
        encoder = encoder or named_encoder
    fields = preset_overrides(args.preset, policy, obs_space, encoder)
    if args.encoder and "encoder" in fields:  # the user's wins: the preset's, pasted after it, would replace it
        fields["encoder"] = args.encoder
    print(" ".join(policy_flags(fields)))
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
