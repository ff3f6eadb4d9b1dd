"""Camera extrinsics from a ChArUco board: cam2world per camera serial (docs/real-robot.md).

The paper's set-up puts one ChArUco board (5 x 7 squares of 35 mm, 26 mm markers, DICT_4X4_50) on the table and
takes the board as the world frame. Here the board pose is found with OpenCV's own detector in several frames,
frames with too few corners or a high reprojection error are refused, the accepted poses are averaged, and
cam2world = board_to_world @ camera->board is saved per camera serial for the robot to record.

World (board) frame, on the board as `obsbench calibrate-cameras --print-board` prints it (mN: ArUco marker N,
##: black square, digits on the grid: ChArUco corner ids), lying face up on the table:

    +-----+-----+-----+-----+-----+      top edge of the printed image
    |#####| m0  |#####| m1  |#####|
    +-----0-----1-----2-----3-----+
    | m2  |#####| m3  |#####| m4  |              y
    +-----4-----5-----6-----7-----+              ^
    |#####| m5  |#####| m6  |#####|              |
    +-----8-----9----10----11-----+              0----> x      z: out of the board, up from the table
    | m7  |#####| m8  |#####| m9  |
    +----12----13----14----15-----+
    |#####| m10 |#####| m11 |#####|
    +----16----17----18----19-----+
    | m12 |#####| m13 |#####| m14 |
    +----20----21----22----23-----+
    |#####| m15 |#####| m16 |#####|
    +-----+-----+-----+-----+-----+

- origin: ChArUco corner 0, the board's first inner chessboard corner: the inner corner of the top-left black
  square, between markers 0 and 2 (a sharp point to measure, unlike the print's trimmed outer edge);
- x: along the 5-square side, from corner 0 through corners 1, 2, 3;
- y: towards the top edge (markers 0 and 1), so the rest of the board lies at negative y: corner k of this
  board is at (k % 4, -(k // 4), 0) x 35 mm, and its squares span x in [-35, 140] mm, y in [-210, 35] mm;
- z: up out of the table, so heights above the table are positive.
This is OpenCV's board frame (origin at the outer corner of the top-left square, y down the print, z into it)
moved to corner 0 and turned 180 degrees about x: `BoardSpec.board_to_cv_board()`. Where the robot base is
elsewhere, `board_to_world` (this frame's pose in the robot-base frame: measure corner 0 and the x direction
from the base) moves it.
"""

from __future__ import annotations

import json
import logging
import re
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from lerobot.utils.constants import HF_LEROBOT_CALIBRATION
from scipy.spatial.transform import Rotation

from lerobot_obsbench.errors import ConfigError, MissingFileError, ObsBenchError

logger = logging.getLogger(__name__)
# Where `obsbench calibrate-cameras` saves one JSON file per camera serial.
DEFAULT_EXTRINSICS_DIR = HF_LEROBOT_CALIBRATION / "obsbench_extrinsics"
# The turn between OpenCV's board axes (x along the columns, y down the printed board, z into it) and the board
# frame used here (z up, y towards the top edge): 180 degrees about x, its own inverse. The origins differ too:
# `BoardSpec.board_to_cv_board()` is the whole transform.
CV_BOARD_TO_BOARD = np.diag([1.0, -1.0, -1.0, 1.0])


def charuco_corner_offset_px(opencv_version: str = cv2.__version__) -> float:
    """How far (in x and y, pixels) OpenCV's CharucoDetector puts every ChArUco corner off its true position.

    OpenCV 4.7 to 4.13 shift the corners by -0.5 px before `cornerSubPix` and add the 0.5 px back after it, but
    `cornerSubPix` converges to the image's saddle point wherever it starts, so each returned corner is the true
    one + (0.5, 0.5) px (opencv/opencv issue 25539, fixed by pull request 28380 for 4.14.0). Measured on
    supersampled renders of the paper's board (tests/robots/test_extrinsics.py): mean (+0.49, +0.50) px in 4.7.0 and
    (+0.49, +0.48) px in 4.10.0, 4.12.0 and 4.13.0; (-0.01, -0.00) px in 4.14.0 and 5.0.0. Left in, the shift
    turns the camera ~0.03 degrees about its centre (the board moves 0.3-0.6 mm in the camera frame at 0.4-0.8 m,
    1280x720): every world point then projects ~0.5 px off in that camera."""
    found = re.match(r"(\d+)\.(\d+)", opencv_version)
    if found is None:
        raise ConfigError(f"cannot read an OpenCV version from {opencv_version!r}")
    return 0.5 if (4, 7) <= (int(found[1]), int(found[2])) < (4, 14) else 0.0


class CalibrationError(ObsBenchError, RuntimeError):
    """A board view or a calibration that cannot be trusted, with the reason and the fix."""


@dataclass
class BoardSpec:
    """The ChArUco board as printed (the paper's: 5 x 7 squares, 35 mm squares, 26 mm markers, DICT_4X4_50)."""

    squares_x: int = 5
    squares_y: int = 7
    square_length: float = 0.035  # metres, as measured on the print
    marker_length: float = 0.026  # metres
    dictionary: str = "DICT_4X4_50"

    def board(self) -> cv2.aruco.CharucoBoard:
        if not hasattr(cv2.aruco, self.dictionary):
            raise ConfigError(f"Unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_4X4_50).")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), self.square_length, self.marker_length, dictionary
        )

    def image(self, pixels_per_metre: float = 4000.0, margin_px: int = 40) -> np.ndarray:
        """The board to print (uint8 grey), at `pixels_per_metre` (4000 = ~100 dpi); print at 100 % scale."""
        size = (
            int(round(self.squares_x * self.square_length * pixels_per_metre)) + 2 * margin_px,
            int(round(self.squares_y * self.square_length * pixels_per_metre)) + 2 * margin_px,
        )
        return self.board().generateImage(size, marginSize=margin_px)

    def board_to_cv_board(self) -> np.ndarray:
        """The board frame (module docstring: origin at ChArUco corner 0, x along the 5-square side, z up) ->
        OpenCV's board frame (origin at the outer corner of the top-left square, y down the print, z into it),
        4x4: corner 0 is OpenCV's (square_length, square_length, 0)."""
        T = CV_BOARD_TO_BOARD.copy()
        T[:2, 3] = self.square_length
        return T


@dataclass
class BoardView:
    """The board's pose in one frame."""

    board_to_camera: np.ndarray  # (4, 4)
    corners: int  # ChArUco corners used
    reprojection_px: float  # RMS reprojection error of those corners


def _transform(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = np.asarray(tvec).reshape(3)
    return T


def detect_corners(grey: np.ndarray, spec: BoardSpec) -> tuple[np.ndarray, np.ndarray]:
    """ChArUco corners (N, 2) in OpenCV pixel coordinates (integers at pixel centres) and their ids (N,) in a
    grey uint8 image, with the offset of the installed OpenCV's detector removed (`charuco_corner_offset_px`)."""
    corners, ids, _, _ = cv2.aruco.CharucoDetector(spec.board()).detectBoard(grey)
    if ids is None:
        return np.zeros((0, 2), np.float32), np.zeros(0, np.int32)
    return corners.reshape(-1, 2) - np.float32(charuco_corner_offset_px()), ids.reshape(-1)


def detect_board(
    image: np.ndarray, K: np.ndarray, spec: BoardSpec, min_corners: int = 12, max_reprojection_px: float = 1.0
) -> BoardView:
    """The board's pose in an RGB (or grey) image taken with pinhole intrinsics K; CalibrationError if the view
    shows fewer than `min_corners` ChArUco corners or the pose reprojects them worse than `max_reprojection_px`."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    corners, ids = detect_corners(grey, spec)
    found = len(ids)
    if found < min_corners:
        raise CalibrationError(
            f"board not detected well enough: {found} ChArUco corners < {min_corners}. Show the whole board "
            f"({spec.squares_x}x{spec.squares_y}, {spec.dictionary}), flat, well lit and in focus, or check the "
            "board parameters (--square-length/--marker-length as printed)."
        )
    object_points, image_points = spec.board().matchImagePoints(corners.reshape(-1, 1, 2), ids.reshape(-1, 1))
    object_points, image_points = object_points.reshape(-1, 3), image_points.reshape(-1, 2)
    ok, rvec, tvec = cv2.solvePnP(object_points, image_points, K.astype(np.float64), None)
    if not ok:
        raise CalibrationError("board pose could not be estimated from the detected corners.")
    projected = cv2.projectPoints(object_points, rvec, tvec, K.astype(np.float64), None)[0].reshape(-1, 2)
    error = float(np.sqrt(np.mean(np.sum((projected - image_points) ** 2, axis=-1))))
    if error > max_reprojection_px:
        raise CalibrationError(
            f"board pose reprojection error {error:.2f} px > {max_reprojection_px} px: the board is bent, blurred "
            "or the intrinsics are wrong; flatten the board, hold the camera still, or check K."
        )
    return BoardView(_transform(rvec, tvec) @ spec.board_to_cv_board(), found, error)


def average_transforms(transforms: list[np.ndarray]) -> np.ndarray:
    """Mean rigid transform: chordal mean of the rotations, arithmetic mean of the translations."""
    stack = np.stack(transforms)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_matrix(stack[:, :3, :3]).mean().as_matrix()
    T[:3, 3] = stack[:, :3, 3].mean(axis=0)
    return T


@dataclass
class CameraExtrinsics:
    """One camera's calibration, as saved per serial."""

    serial_number: str
    cam2world: list[list[float]]  # (4, 4) OpenCV camera -> world
    board: dict
    board_to_world: list[list[float]]
    views_used: int
    views_refused: int
    reprojection_px: float  # mean over the views used
    spread_mm: float  # largest distance of a view's camera position from the mean
    created: str
    # Where the board frame's origin is (the module docstring); files without it put it at the board's outer
    # corner, 35 mm from corner 0 in x and y (`load_extrinsics` warns)
    world_origin: str = "charuco_corner_0"
    # `obsbench refine-cameras`: the reference camera's serial and the correction applied (robots/fusion.py)
    refinement: dict | None = None

    def matrix(self) -> np.ndarray:
        return np.asarray(self.cam2world, dtype=np.float64)


def calibrate(
    images: list[np.ndarray],
    K: np.ndarray,
    serial_number: str,
    spec: BoardSpec | None = None,
    board_to_world: np.ndarray | None = None,
    min_views: int = 5,
    min_corners: int = 12,
    max_reprojection_px: float = 1.0,
) -> CameraExtrinsics:
    """cam2world from several views of the board by a fixed camera; refused views are counted, too few accepted
    views is a CalibrationError naming the most common reason."""
    spec = spec or BoardSpec()
    board_to_world = np.eye(4) if board_to_world is None else np.asarray(board_to_world, dtype=np.float64)
    views, reasons = [], []
    for image in images:
        try:
            views.append(detect_board(image, K, spec, min_corners, max_reprojection_px))
        except CalibrationError as error:
            reasons.append(str(error))
    if len(views) < min_views:
        reason = max(set(reasons), key=reasons.count) if reasons else "no frames"
        raise CalibrationError(f"only {len(views)} of {len(images)} views usable (need {min_views}); {reason}")
    cam_to_board = [np.linalg.inv(v.board_to_camera) for v in views]
    mean = average_transforms(cam_to_board)
    spread = max(np.linalg.norm(T[:3, 3] - mean[:3, 3]) for T in cam_to_board)
    return CameraExtrinsics(
        serial_number=serial_number,
        cam2world=(board_to_world @ mean).tolist(),
        board=asdict(spec),
        board_to_world=board_to_world.tolist(),
        views_used=len(views),
        views_refused=len(reasons),
        reprojection_px=float(np.mean([v.reprojection_px for v in views])),
        spread_mm=float(spread * 1000),
        created=time.strftime("%Y-%m-%dT%H:%M:%S"),
    )


def extrinsics_path(serial_number: str, directory: Path | str | None = None) -> Path:
    return Path(directory or DEFAULT_EXTRINSICS_DIR) / f"{serial_number}.json"


def save_extrinsics(result: CameraExtrinsics, directory: Path | str | None = None) -> Path:
    path = extrinsics_path(result.serial_number, directory)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(asdict(result), indent=2) + "\n")
    tmp.replace(path)
    return path


def load_extrinsics(serial_number: str, directory: Path | str | None = None) -> CameraExtrinsics:
    """The saved calibration of a camera; FileNotFoundError naming the command that makes it."""
    path = extrinsics_path(serial_number, directory)
    if not path.is_file():
        raise MissingFileError(
            f"No extrinsics for camera {serial_number} ({path}). Put the ChArUco board on the table and run "
            f"`obsbench calibrate-cameras --serial {serial_number}`"
            + (f" --out {directory}" if directory else "")
            + " (print the board with `obsbench calibrate-cameras --print-board board.png`)."
        )
    data = json.loads(path.read_text())
    if "world_origin" not in data:
        logger.warning(
            f"{path} was calibrated with the world origin at the board's outer corner, 35 mm from ChArUco corner 0 in "
            "x and y, where the docs and the presets' crop boxes put it: run `obsbench calibrate-cameras` again "
            "(datasets recorded with this file keep its frame)."
        )
        data["world_origin"] = "board_outer_corner"
    result = CameraExtrinsics(**data)
    if np.asarray(result.cam2world).shape != (4, 4):
        raise ConfigError(f"{path}: cam2world must be a 4x4 matrix; recalibrate with `obsbench calibrate-cameras`.")
    return result
