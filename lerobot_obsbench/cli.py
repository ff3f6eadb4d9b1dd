"""`obsbench` command line: inspect encoders, check datasets against observation spaces, print presets.

Training and evaluation use stock LeRobot (`lerobot-train --policy.type=obs_act ...`); this tool covers what
LeRobot has no command for.
"""

from __future__ import annotations

import argparse
import sys

from lerobot_obsbench.datasets.schema import OBS_SPACES, SchemaError, validate_features


def cmd_encoders(args: argparse.Namespace) -> int:
    from lerobot_obsbench.encoders import available_encoders, encoder_info

    for name in available_encoders(args.obs_space):
        info = encoder_info(name)
        print(f"{name:10s} spaces: {', '.join(info.spaces):32s} {info.summary}")
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(args.repo_id, root=args.root)
    spaces = OBS_SPACES if args.obs_space == "all" else (args.obs_space,)
    failures = 0
    for space in spaces:
        try:
            cams = validate_features(meta.features, space, args.cameras or None)
            print(f"ok      {space:10s} cameras: {', '.join(cams)}")
        except SchemaError as err:
            failures += 1
            print(f"FAILED  {space:10s} {err}")
    print(f"{meta.total_episodes} episodes, {meta.total_frames} frames at {meta.fps} fps in {args.root}")
    return 1 if failures == len(spaces) or (args.obs_space != "all" and failures) else 0


def cmd_preset(args: argparse.Namespace) -> int:
    from lerobot_obsbench.presets import preset_args

    print(" ".join(preset_args(args.preset, args.policy, args.obs_space)))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="obsbench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("encoders", help="list registered encoders and the observation spaces they accept")
    p.add_argument("--obs-space", choices=OBS_SPACES, help="only encoders accepting this space")
    p.set_defaults(func=cmd_encoders)

    p = sub.add_parser("validate", help="check a LeRobotDataset against observation spaces (schema of DESIGN §3)")
    p.add_argument("--root", required=True, help="dataset directory")
    p.add_argument("--repo-id", default="local/dataset")
    p.add_argument("--obs-space", default="all", choices=("all", *OBS_SPACES))
    p.add_argument("--cameras", nargs="*", default=[], help="camera names (default: every camera found)")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("preset", help="print the --policy.* overrides of a named preset, to paste into lerobot-train")
    p.add_argument("--preset", default="cpu", choices=("paper", "cpu", "tiny"))
    p.add_argument("--policy", default="obs_act", choices=("obs_act", "obs_diffusion"))
    p.add_argument("--obs-space", default="pointcloud", choices=OBS_SPACES)
    p.set_defaults(func=cmd_preset)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import lerobot_obsbench  # noqa: F401  (registers policies and encoders)

    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
