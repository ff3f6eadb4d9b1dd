"""`obsbench refine-cameras`: after calibrate-cameras, align each extra camera's cloud to the first's (Open3D
coloured ICP, `robots.fusion`) and save the corrected poses."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.errors import UsageError
from lerobot_obsbench.outputs import check_output_file

NAME = "refine-cameras"
HELP = (
    "after calibrate-cameras: align each extra camera's cloud to the first's (Open3D coloured ICP on the "
    "shared table and objects) and save the corrected cam2world; refuses an implausibly large correction"
)
EXAMPLE = """obsbench refine-cameras --serial 123456789 987654321 --preset real-two-arms --dry-run"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--serial", nargs="*", default=[], help="live cameras; the first is the reference")
    p.add_argument("--playback", nargs="*", default=[], help="recorded .bag files instead (the first: reference)")
    p.add_argument("--width", type=common.positive_int, default=640)
    p.add_argument("--height", type=common.positive_int, default=480)
    p.add_argument("--fps", type=common.positive_int, default=30)
    p.add_argument("--downsample", type=common.positive_int, default=2)
    p.add_argument("--extrinsics-dir", default=None, help="where calibrate-cameras saved them (default: LeRobot's)")
    p.add_argument("--workspace", type=float, nargs=6, default=None, help="the region aligned (default: the preset's)")
    p.add_argument("--preset", default=None, help="take the region from this preset (e.g. real-two-arms)")
    p.add_argument(
        "--max-mm", type=common.positive_float, default=20.0, help="refuse a correction moving a camera further"
    )
    p.add_argument(
        "--max-deg", type=common.positive_float, default=2.0, help="refuse a correction turning a camera further"
    )
    p.add_argument(
        "--min-overlap", type=common.fraction, default=0.3, help="refuse when less of a cloud meets the reference"
    )
    p.add_argument("--voxel-size", type=common.positive_float, default=0.005, help="of the --ply cloud")
    p.add_argument("--ply", type=Path, default=None, help="write the fused cloud after the refinement as .ply")
    p.add_argument("--dry-run", action="store_true", help="report the corrections; save nothing")


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    import numpy as np

    from lerobot_obsbench.datasets.view import camera_cloud, clouds, crop_box, live_camera_configs, live_frame
    from lerobot_obsbench.robots.extrinsics import load_extrinsics, save_extrinsics
    from lerobot_obsbench.robots.fusion import align_clouds, write_ply
    from lerobot_obsbench.schema import cam2world_key

    common.crop_box_argument(args.workspace)
    configs = live_camera_configs(args.serial, args.playback, args.width, args.height, args.fps, args.downsample)
    if len(configs) < 2:
        raise UsageError("give two or more cameras; the first is the reference")
    if args.ply:
        check_output_file(args.ply, "--ply", overwrite=True, inputs=args.playback)
    workspace = crop_box(args.workspace, args.preset)
    frame, serials = live_frame(configs, args.extrinsics_dir)
    names = list(configs)
    reference = camera_cloud(frame, names[0], workspace)
    for name in names[1:]:
        before = np.asarray(frame[cam2world_key(name)], dtype=np.float64)
        alignment = align_clouds(
            reference, camera_cloud(frame, name, workspace), before, args.max_mm, args.max_deg, args.min_overlap
        )
        after = np.asarray(alignment.correction) @ before
        frame[cam2world_key(name)] = after.astype(np.float32)
        saved = load_extrinsics(serials[name], args.extrinsics_dir)
        refinement = {"reference_serial": serials[names[0]], "workspace": list(workspace), **alignment.as_dict()}
        where = "not saved (--dry-run)"
        if not args.dry_run:
            path = save_extrinsics(replace(saved, cam2world=after.tolist(), refinement=refinement), args.extrinsics_dir)
            where = f"saved to {path}"
        print(
            f"camera {serials[name]}: moved {alignment.translation_mm:.2f} mm and {alignment.rotation_deg:.3f} degrees "
            f"onto camera {serials[names[0]]} ({alignment.overlap:.0%} of its points overlap, rmse "
            f"{alignment.rmse_mm:.2f} mm); {where}"
        )
    if args.ply:
        _, xyz, rgb = clouds(frame, names, workspace, args.voxel_size)
        print(f"fused cloud of {len(names)} cameras, {len(xyz)} points: {write_ply(args.ply, xyz, rgb)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
