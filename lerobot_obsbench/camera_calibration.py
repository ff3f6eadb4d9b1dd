"""Camera calibration attached to a dataset: what turns LeRobot's own depth recordings into point clouds.

LeRobot 0.6 records a RealSense's depth itself (`observation.images.<cam>_depth`, `info.is_depth_map`), but raw: in
the depth camera's own pixels (not registered to colour), with no intrinsics, no depth→colour extrinsic and no
camera pose. The plugin keeps what is missing in `meta/obsbench_cameras.json` beside LeRobot's own metadata (so a
Hub push carries it), one entry per camera; `obsbench attach-calibration` writes it after the fact.

The policies read the entries into their config (`spaces.CalibratedDepth` registers the depth into the colour camera
with them), `obsbench validate` checks them.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from lerobot_obsbench.geometry import rigidity_error
from lerobot_obsbench.schema import SchemaError, stock_depth_cameras
from lerobot_obsbench.spaces import RIGID_TOLERANCE

CALIBRATION_FILE = Path("meta") / "obsbench_cameras.json"
FORMAT_VERSION = 1


@dataclass
class CameraCalibration:
    """One RGB-D camera as recorded: OpenCV conventions, metres, camera frames x right / y down / z forward."""

    # Colour stream: (height, width) and 3x3 intrinsics K.
    color_size: list[int]
    color_intrinsics: list[list[float]]
    # Depth stream: (height, width) and 3x3 intrinsics K (LeRobot 0.6 stores depth in these pixels).
    depth_size: list[int]
    depth_intrinsics: list[list[float]]
    # 4x4 rigid transform from depth-camera coordinates to colour-camera coordinates (librealsense's
    # depth->color extrinsics).
    depth_to_color: list[list[float]]
    # 4x4 rigid transform from colour-camera coordinates to the world (robot base / ChArUco board) frame, as
    # `obsbench calibrate-cameras` measures it.
    cam2world: list[list[float]]
    # Millimetres per stored depth unit: LeRobot stores the RealSense's raw z16 values and calls them mm, which
    # holds for the D400 family's default depth scale (1 mm); an L515 (0.25 mm) needs 0.25 here.
    depth_unit_mm: float = 1.0
    # Stored depth values at or below this are holes: LeRobot's depth video codec returns its `depth_min`
    # (10 "mm" by default) where the camera measured nothing (0); images keep 0.
    depth_min_mm: float = 0.0
    # Where the values came from (a file, a recording, a camera serial), for the record.
    source: str = field(default="")

    def __post_init__(self) -> None:
        self.check()

    def check(self) -> None:
        problems = []
        for name, shape in (
            ("color_intrinsics", (3, 3)),
            ("depth_intrinsics", (3, 3)),
            ("depth_to_color", (4, 4)),
            ("cam2world", (4, 4)),
        ):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != shape or not np.isfinite(value).all():
                problems.append(f"{name} must be a finite {shape[0]}x{shape[1]} matrix, got shape {value.shape}")
                continue
            if shape == (3, 3) and not (value[0, 0] > 0 and value[1, 1] > 0 and value[2, 2] == 1):
                problems.append(f"{name} must have fx, fy > 0 and K[2][2] = 1")
            if shape == (4, 4) and float(rigidity_error(torch.from_numpy(value))) > RIGID_TOLERANCE:
                problems.append(f"{name} is not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)")
        for name in ("color_size", "depth_size"):
            size = list(getattr(self, name))
            if len(size) != 2 or not all(isinstance(v, int) and v > 0 for v in size):
                problems.append(f"{name} must be [height, width] in pixels, got {size}")
        if not (math.isfinite(self.depth_unit_mm) and self.depth_unit_mm > 0):
            problems.append(f"depth_unit_mm must be > 0, got {self.depth_unit_mm}")
        if not (math.isfinite(self.depth_min_mm) and self.depth_min_mm >= 0):
            problems.append(f"depth_min_mm must be >= 0, got {self.depth_min_mm}")
        if problems:
            raise SchemaError("camera calibration: " + "; ".join(problems) + ".")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict, where: str = "camera calibration") -> CameraCalibration:
        names = set(cls.__dataclass_fields__)
        if not isinstance(values, dict):
            raise SchemaError(f"{where}: expected an object of fields ({', '.join(sorted(names))}), got {values!r}.")
        unknown, missing = set(values) - names, {n for n in names if n not in values} - _OPTIONAL
        if unknown or missing:
            raise SchemaError(
                f"{where}: "
                + "; ".join(
                    part
                    for part in (
                        f"unknown fields {sorted(unknown)}" if unknown else "",
                        f"missing fields {sorted(missing)}" if missing else "",
                    )
                    if part
                )
                + f" (fields: {', '.join(sorted(names))})."
            )
        try:
            return cls(**values)
        except (TypeError, ValueError) as err:
            if isinstance(err, SchemaError):
                raise SchemaError(f"{where}: {str(err).removeprefix('camera calibration: ')}") from None
            raise SchemaError(f"{where}: {err}") from None


_OPTIONAL = {"depth_unit_mm", "depth_min_mm", "source"}


def calibration_path(root: str | Path) -> Path:
    return Path(root) / CALIBRATION_FILE


class CalibrationFileError(SchemaError):
    """A dataset's calibration file that cannot be read as a whole: not JSON, another layout or format version."""

    def __init__(self, path: Path, problem: str):
        self.path, self.problem = path, problem
        super().__init__(
            f"{path}: {problem}; replace it (what it holds is lost): obsbench attach-calibration --root "
            f"{path.parent.parent} --camera CAM (--from-recording FILE.bag | --serial SERIAL | --from-json FILE) "
            "--cam2world FILE --overwrite"
        )


def stored_calibration(root: str | Path) -> dict[str, object]:
    """The calibration file's entries as stored, camera -> fields, each unchecked ({} when there is no file);
    `CalibrationFileError` when the file as a whole cannot be read."""
    path = calibration_path(root)
    if not path.exists():
        return {}
    if not path.is_file():  # --overwrite cannot replace a folder: it is moved by hand
        raise SchemaError(f"{path} is not a file; move it out of the way, the calibration is written there")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise CalibrationFileError(path, f"cannot be read as JSON ({err})") from None
    layout = f'{{"version": {FORMAT_VERSION}, "cameras": {{name: calibration}}}}'
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), dict):
        raise CalibrationFileError(path, f"expected {layout}, found {json.dumps(data)[:60]}")
    if data.get("version") != FORMAT_VERSION:
        raise CalibrationFileError(
            path,
            f"format version {data.get('version')!r}, but this plugin reads format version {FORMAT_VERSION} (if a "
            "newer plugin wrote it, upgrade the plugin instead)",
        )
    return data["cameras"]


def read_calibration(root: str | Path) -> dict[str, CameraCalibration]:
    """The cameras calibrated in the dataset at `root` ({} when the file does not exist)."""
    path = calibration_path(root)
    cameras = {}
    for cam, values in stored_calibration(root).items():
        try:
            cameras[cam] = CameraCalibration.from_dict(values, where=f"{path} camera {cam!r}")
        except SchemaError as err:
            raise SchemaError(
                f"{str(err).rstrip('.')}; attach it again: obsbench attach-calibration --root {root} --camera {cam} "
                "(--from-recording FILE.bag | --serial SERIAL | --from-json FILE) --cam2world FILE"
            ) from None
    return cameras


def write_calibration(
    root: str | Path, cameras: dict[str, CameraCalibration], replace_unreadable: bool = False
) -> Path:
    """Add or replace `cameras` in the dataset's calibration file, written atomically; the other cameras' entries
    are kept as stored. A file that cannot be read is replaced only with `replace_unreadable`."""
    path = calibration_path(root)
    try:
        entries = dict(stored_calibration(root))
    except CalibrationFileError:
        if not replace_unreadable:
            raise
        entries = {}
    entries.update({cam: calib.to_dict() for cam, calib in cameras.items()})
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"version": FORMAT_VERSION, "cameras": entries}, indent=1) + "\n")
    os.replace(tmp, path)
    return path


def dataset_calibration(dataset_meta) -> dict[str, dict]:
    """The attached calibration (CameraCalibration fields) of each camera the dataset recorded LeRobot depth for."""
    if getattr(dataset_meta, "root", None) is None:
        return {}
    calibration = read_calibration(dataset_meta.root)
    return {cam: calibration[cam].to_dict() for cam in stock_depth_cameras(dataset_meta.features) if cam in calibration}
