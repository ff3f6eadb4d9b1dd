"""`obsbench attach-calibration`: make a dataset recorded by stock `lerobot-record` with RealSense depth usable by every
observation space, by writing its cameras' intrinsics, depth scale and poses beside it."""

from __future__ import annotations

import argparse
import sys

from lerobot_obsbench.commands import common

NAME = "attach-calibration"
HELP = (
    "attach a camera's calibration to a dataset recorded by stock lerobot-record with RealSense depth "
    "(use_depth: true), so that depth, rgbd, pointmap and point-cloud policies train on it"
)
EXAMPLE = """obsbench attach-calibration --root data/koch_pick --camera front --serial 123456789 \\
    --cam2world ~/.cache/huggingface/lerobot/calibration/obsbench_extrinsics/123456789.json"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--root", required=True, help="dataset directory (its meta/obsbench_cameras.json is written)")
    p.add_argument("--camera", required=True, help="camera name: the <cam> of observation.images.<cam>_depth")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--serial", help="read intrinsics and depth->colour extrinsics from this connected RealSense")
    source.add_argument("--from-recording", help="read them from a RealSense recording (.bag) of the same streams")
    source.add_argument(
        "--from-json",
        help="read them from a JSON object: color_intrinsics, depth_intrinsics (3x3, pixel centres at integers), "
        "depth_to_color (4x4, metres) and optionally cam2world, depth_unit_mm, depth_min_mm (every field, its frame "
        "and an example: docs/real-robot.md, 'The calibration files, field by field')",
    )
    p.add_argument(
        "--cam2world",
        help="the colour camera's pose in the world frame (4x4, metres): obsbench calibrate-cameras' saved file or a "
        "bare 4x4 JSON matrix",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace meta/obsbench_cameras.json if it cannot be read (not JSON, another layout or format version; "
        "what it holds is lost); a readable file keeps its other cameras either way",
    )


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.calibration import attach_calibration

    path, calibration = attach_calibration(
        args.root, args.camera, args.from_json, args.from_recording, args.serial, args.cam2world, args.overwrite
    )
    print(
        f"camera {args.camera}: colour {calibration.color_size[1]}x{calibration.color_size[0]}, depth "
        f"{calibration.depth_size[1]}x{calibration.depth_size[0]} ({calibration.depth_unit_mm:g} mm per unit, holes "
        f"<= {calibration.depth_min_mm:g}), from {calibration.source}; written to {path}"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
