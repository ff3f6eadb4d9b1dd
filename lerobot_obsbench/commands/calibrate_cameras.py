"""`obsbench calibrate-cameras`: each camera's pose in the world frame from a ChArUco board on the table, averaged over
several views and saved per camera serial (`robots.extrinsics`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.errors import UsageError
from lerobot_obsbench.numeric import number_argument
from lerobot_obsbench.outputs import OutputPathError, check_output_file, check_output_folder

NAME = "calibrate-cameras"
HELP = (
    "camera -> world extrinsics from a ChArUco board on the table, averaged over several views, saved per "
    "camera serial (the robot records cam2world from it)"
)
EXAMPLE = """obsbench calibrate-cameras --serial 123456789 --views 10"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--serial", default=None, help="camera serial (obsbench find-cameras)")
    p.add_argument("--playback", default=None, help="a recorded .bag instead of a live camera")
    p.add_argument("--width", type=common.positive_int, default=1280)
    p.add_argument("--height", type=common.positive_int, default=720)
    p.add_argument("--fps", type=common.positive_int, default=30)
    p.add_argument("--views", type=common.positive_int, default=10, help="frames to average")
    p.add_argument(
        "--interval",
        type=common.non_negative_float,
        default=0.1,
        help="seconds between views (a recording's: in its own time, at --fps)",
    )
    p.add_argument("--min-views", type=common.positive_int, default=5)
    p.add_argument(
        "--min-corners",
        type=number_argument(whole=True, minimum=4),
        default=12,
        help="refuse a view with fewer ChArUco corners",
    )
    p.add_argument(
        "--max-reprojection", type=common.positive_float, default=1.0, help="refuse a view above this RMS error (px)"
    )
    p.add_argument(
        "--squares", type=number_argument(whole=True, minimum=2), nargs=2, default=(5, 7), metavar=("X", "Y")
    )
    p.add_argument("--square-length", type=common.positive_float, default=0.035, help="metres, as printed")
    p.add_argument("--marker-length", type=common.positive_float, default=0.026, help="metres, as printed")
    p.add_argument("--dictionary", default="DICT_4X4_50")
    p.add_argument(
        "--board-pose",
        type=float,
        nargs=6,
        default=(0, 0, 0, 0, 0, 0),
        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
        help="the board frame's pose in the robot-base frame (metres, degrees); default: the board is the world",
    )
    p.add_argument("--out", default=None, help="extrinsics directory (default: LeRobot's calibration dir)")
    p.add_argument("--print-board", type=Path, default=None, help="write the board image to print, and exit")


def run(args: argparse.Namespace) -> int:
    import time

    import cv2
    import numpy as np
    from scipy.spatial.transform import Rotation

    from lerobot_obsbench.robots.extrinsics import BoardSpec, calibrate, save_extrinsics
    from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig
    from lerobot_obsbench.robots.realsense.realsense_rgbd import RealSenseRGBDCamera

    spec = BoardSpec(*args.squares, args.square_length, args.marker_length, args.dictionary)
    if args.print_board:
        check_output_file(args.print_board, "--print-board", overwrite=True)
        unwritable = OutputPathError(
            f"--print-board {args.print_board}: OpenCV could not write it; give an image file name ending in .png"
        )
        if not cv2.haveImageWriter(str(args.print_board)):
            raise unwritable
        args.print_board.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(args.print_board), spec.image()):  # OpenCV returns False instead of raising
            raise unwritable
        print(f"{args.print_board}: print at 100 % and check that a square measures {args.square_length * 1000:g} mm")
        return 0
    if not args.serial and not args.playback:
        raise UsageError("give --serial (see `obsbench find-cameras`) or --playback FILE")
    if args.out:  # before the camera starts
        check_output_folder(Path(args.out), "--out")
    board_to_world = np.eye(4)
    x, y, z, roll, pitch, yaw = args.board_pose
    board_to_world[:3, :3] = Rotation.from_euler("xyz", [roll, pitch, yaw], degrees=True).as_matrix()
    board_to_world[:3, 3] = [x, y, z]
    config = RealSenseRGBDCameraConfig(
        serial_number=args.serial or "",
        playback_file=args.playback,
        width=args.width,
        height=args.height,
        fps=args.fps,
        downsample=1,
        warmup_s=0.0 if args.playback else 1.0,  # a recording needs no auto-exposure to settle
        # a recording's every frameset, in order, however slowly this machine reads them
        playback_real_time=not args.playback,
    )
    camera = RealSenseRGBDCamera(config)
    camera.connect()
    try:
        images = []
        if args.playback:  # views `interval` apart in the recording's own time
            stride = max(1, round(args.interval * args.fps))
            for _ in range(args.views):
                for _ in range(stride):
                    image = camera.async_read(timeout_ms=60_000)  # bounds a hang: a recording's frames come
                images.append(image)
        else:
            for _ in range(args.views):
                images.append(camera.async_read(timeout_ms=2000))
                time.sleep(args.interval)
        K, serial = camera.K, camera.serial_number
    finally:
        camera.disconnect()
    result = calibrate(
        images,
        K,
        serial,
        spec,
        board_to_world,
        min_views=args.min_views,
        min_corners=args.min_corners,
        max_reprojection_px=args.max_reprojection,
    )
    path = save_extrinsics(result, args.out)
    height = result.matrix()[2, 3]
    print(
        f"camera {serial}: {result.views_used}/{args.views} views, reprojection {result.reprojection_px:.2f} px, "
        f"spread {result.spread_mm:.2f} mm; camera {height:.3f} m above the board plane -> {path}"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
