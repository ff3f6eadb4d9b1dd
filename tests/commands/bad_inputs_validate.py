"""Rows of the bad-input table (`tests/commands/test_bad_inputs.py`) for validate: each `(setup, fragments)`, where
`setup(root) -> argv` builds its inputs in a fresh folder and `fragments` are what the one error line must hold.

The datasets are written as stock `lerobot-record` writes a RealSense with `use_depth: true`
(`tests/support/stock_depth_scene.py`), with the camera's calibration attached; `tests/robots/test_validate_decodes.py`
builds its datasets with the same helpers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lerobot_obsbench.cli import main
from tests.support import stock_depth_scene as scene

CAMERA = "front"
COLOUR_KEY, DEPTH_KEY = "observation.images.front", "observation.images.front_depth"
FIRST_DATA_FILE = "data/chunk-000/file-000.parquet"


def first_video(key: str) -> str:
    return f"videos/{key}/chunk-000/file-000.mp4"


def zero_depth(depth_mm: np.ndarray) -> np.ndarray:
    """A depth stream that delivered nothing (a camera opened without its depth sensor)."""
    return np.zeros_like(depth_mm)


def depth_in_metres(depth_mm: np.ndarray) -> np.ndarray:
    """Metres rounded into LeRobot's uint16 depth, which LeRobot stores as millimetres: values 0 and 1."""
    return np.rint(depth_mm / 1000).astype(np.uint16)


def calibrated_stock_dataset(root: Path, video: bool, depth=None, episodes: int = 2, frames: int = 12) -> Path:
    """A dataset of the stock-depth scene whose depth maps (uint16 mm) are `depth(scene's)`, calibration attached."""
    render = scene.render

    def rendered():
        colour, depth_mm, truth = render()
        return colour, depth(depth_mm), truth

    with pytest.MonkeyPatch.context() as patch:
        if depth is not None:
            patch.setattr(scene, "render", rendered)
        scene.write_stock_dataset(root, video=video, episodes=episodes, frames=frames)
    calibration = scene.write_calibration_json(root.parent / f"{root.name}_{CAMERA}.json")
    assert main(["attach-calibration", "--root", str(root), "--camera", CAMERA, "--from-json", str(calibration)]) == 0
    return root


def truncate(path: Path) -> Path:
    """Cut a file to half its bytes, as an interrupted copy or download leaves it."""
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


def validate_all_zero_depth_images(root: Path) -> list[str]:
    """Used to say "ok" for every space; training then stopped on empty clouds after 15 steps."""
    return ["validate", "--root", str(calibrated_stock_dataset(root / "koch", video=False, depth=zero_depth))]


def validate_depth_in_metres_in_a_video(root: Path) -> list[str]:
    """Used to say "ok": LeRobot's depth video stores 0 and 1 mm at its hole value, so no frame has depth."""
    return ["validate", "--root", str(calibrated_stock_dataset(root / "koch", video=True, depth=depth_in_metres))]


def validate_a_truncated_colour_video(root: Path) -> list[str]:
    """Used to say "ok"; rgb training then died in a torchcodec traceback that did not name the file."""
    dataset = calibrated_stock_dataset(root / "koch", video=True)
    truncate(dataset / first_video(COLOUR_KEY))
    return ["validate", "--root", str(dataset), "--obs-space", "rgb"]


def validate_a_truncated_depth_video(root: Path) -> list[str]:
    dataset = calibrated_stock_dataset(root / "koch", video=True)
    truncate(dataset / first_video(DEPTH_KEY))
    return ["validate", "--root", str(dataset), "--obs-space", "depth"]


ROWS: list = [
    (
        validate_all_zero_depth_images,
        [f"camera {CAMERA}: {DEPTH_KEY}", FIRST_DATA_FILE, "no frame holds valid depth", "record again"],
    ),
    (
        validate_depth_in_metres_in_a_video,
        [f"camera {CAMERA}: {DEPTH_KEY}", first_video(DEPTH_KEY), "no frame holds valid depth", "in metres"],
    ),
    (validate_a_truncated_colour_video, [first_video(COLOUR_KEY), "cannot be decoded", "copy it again"]),
    (validate_a_truncated_depth_video, [first_video(DEPTH_KEY), "cannot be decoded", "copy it again"]),
]
