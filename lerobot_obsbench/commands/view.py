"""`obsbench view`: see what the policy sees, for a dataset frame or live cameras, in rerun (`datasets.view`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.errors import UsageError
from lerobot_obsbench.outputs import check_output_file

NAME = "view"
HELP = (
    "see what the policy sees: colour, depth, the fused point cloud before and after the crop, the "
    "workspace box and the world axes, in rerun (an .rrd file when there is no display)"
)
EXAMPLE = """obsbench view --root data/pickcube --frame 0 --out view.rrd"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--root", default=None, help="a LeRobotDataset (simulated or real)")
    p.add_argument("--repo-id", default="local/dataset")
    p.add_argument("--frame", type=common.non_negative_int, default=0, help="global frame index in the dataset")
    p.add_argument("--serial", nargs="*", default=[], help="live RealSense cameras instead of a dataset")
    p.add_argument("--playback", nargs="*", default=[], help="recorded .bag files instead of a dataset")
    p.add_argument("--width", type=common.positive_int, default=640)
    p.add_argument("--height", type=common.positive_int, default=480)
    p.add_argument("--fps", type=common.positive_int, default=30)
    p.add_argument("--downsample", type=common.positive_int, default=2)
    p.add_argument("--extrinsics-dir", default=None)
    p.add_argument("--cameras", nargs="*", default=[], help="cameras to fuse (default: all with depth)")
    p.add_argument("--workspace", type=float, nargs=6, default=None, help="crop box (default: the preset's)")
    p.add_argument("--preset", default=None, help="take the crop box from this preset (e.g. real-one-arm)")
    p.add_argument("--voxel-size", type=common.positive_float, default=0.005)
    p.add_argument("--out", type=Path, default=None, help="save an .rrd file (default without a display)")
    p.add_argument("--ply", type=Path, default=None, help="also write the policy's fused cloud as .ply (Open3D)")
    p.add_argument("--overwrite", action="store_true", help="replace existing --out / --ply files")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.view import crop_box, dataset_frame, live_camera_configs, live_frame, log_frame

    inputs = [*([args.root] if args.root else []), *args.playback]
    for path, flag in ((args.out, "--out"), (args.ply, "--ply")):  # before the dataset or the cameras are opened
        if path:
            check_output_file(path, flag, overwrite=args.overwrite, inputs=inputs)
    common.crop_box_argument(args.workspace)
    workspace = crop_box(args.workspace, args.preset)
    if args.root:
        frame = dataset_frame(args.root, args.frame, args.repo_id)
    elif args.serial or args.playback:
        frame, _ = live_frame(
            live_camera_configs(args.serial, args.playback, args.width, args.height, args.fps, args.downsample),
            args.extrinsics_dir,
        )
    else:
        raise UsageError("give --root DATASET, or --serial SERIAL ... / --playback FILE.bag ... for cameras")
    shown = log_frame(frame, workspace, args.voxel_size, args.cameras or None, args.out, ply=args.ply)
    where = f"saved to {shown['rrd']} (open with `rerun {shown['rrd']}`)" if shown["rrd"] else "sent to the viewer"
    print(
        f"cameras {', '.join(shown['cameras'])}: {shown['points_all']} points, {shown['points_policy']} after the "
        f"workspace {list(workspace)} and {args.voxel_size * 1000:g} mm voxels; {where}"
        + (f"; cloud written to {shown['ply']}" if shown["ply"] else "")
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
