"""`obsbench find-cameras`: list the connected RealSense cameras and whether each has saved extrinsics."""

from __future__ import annotations

import argparse
import sys

from lerobot_obsbench.commands import common

NAME = "find-cameras"
HELP = "list connected RealSense cameras (serials) and their calibration"
EXAMPLE = """obsbench find-cameras"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--extrinsics-dir", default=None, help="where calibrate-cameras saved extrinsics (default: LeRobot's)"
    )


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.robots.extrinsics import extrinsics_path
    from lerobot_obsbench.robots.realsense.realsense_rgbd import RealSenseRGBDCamera

    found = RealSenseRGBDCamera.find_cameras()
    if not found:
        print("no RealSense camera found (check the USB 3 cable and that libusb-1.0-0 is installed)")
    for camera in found:
        path = extrinsics_path(camera["id"], args.extrinsics_dir)
        calibrated = f"extrinsics: {path}" if path.is_file() else "not calibrated: obsbench calibrate-cameras"
        print(f"{camera['id']}  {camera['name']}  {camera.get('usb_type', '')}  {calibrated}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
