"""Camera extrinsics from a ChArUco board: OpenCV renders the board, a homography with a known K and pose puts it
into a camera image, and the calibration must recover that pose."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lerobot_obsbench.robots.extrinsics import (
    CV_BOARD_TO_BOARD,
    BoardSpec,
    CalibrationError,
    calibrate,
    detect_board,
    load_extrinsics,
    save_extrinsics,
)

K = np.array([[610.0, 0.0, 321.3], [0.0, 605.0, 238.7], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
PX_PER_M, MARGIN = 4000.0, 40


def board_pose(tilt=(-28.0, 6.0, 15.0), centre=(0.02, -0.01, 0.55)) -> np.ndarray:
    """OpenCV board -> camera transform with the board's centre at `centre` (camera frame)."""
    spec = BoardSpec()
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", tilt, degrees=True).as_matrix()
    middle = np.array([spec.squares_x * spec.square_length / 2, spec.squares_y * spec.square_length / 2, 0.0])
    T[:3, 3] = np.asarray(centre) - T[:3, :3] @ middle
    return T


def render_view(cv_board_to_camera: np.ndarray, spec: BoardSpec | None = None, brightness: float = 1.0) -> np.ndarray:
    """The printed board seen by a pinhole camera K at the given pose, on a grey table (RGB uint8)."""
    spec = spec or BoardSpec()
    board = spec.image(PX_PER_M, MARGIN)
    # board-image pixel (index convention) -> board plane metres -> camera pixels
    to_metres = np.array([[1 / PX_PER_M, 0, (0.5 - MARGIN) / PX_PER_M], [0, 1 / PX_PER_M, (0.5 - MARGIN) / PX_PER_M]])
    to_metres = np.vstack([to_metres, [0, 0, 1]])
    R, t = cv_board_to_camera[:3, :3], cv_board_to_camera[:3, 3]
    homography = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ to_metres
    view = cv2.warpPerspective(board, homography, SIZE, flags=cv2.INTER_AREA, borderValue=150)
    view = np.clip(view.astype(float) * brightness, 0, 255).astype(np.uint8)
    return cv2.cvtColor(view, cv2.COLOR_GRAY2RGB)


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(mm, degrees) between two rigid transforms."""
    mm = float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]) * 1000)
    degrees = float(np.degrees(Rotation.from_matrix(estimate[:3, :3] @ truth[:3, :3].T).magnitude()))
    return mm, degrees


@pytest.mark.parametrize("tilt", [(-28.0, 6.0, 15.0), (-45.0, -10.0, 80.0), (-5.0, 3.0, -30.0)])
def test_one_view_recovers_the_board_pose(tilt):
    truth = board_pose(tilt)
    view = detect_board(render_view(truth), K, BoardSpec())
    assert view.corners == 24 and view.reprojection_px < 0.5
    mm, degrees = pose_error(view.board_to_camera, truth @ CV_BOARD_TO_BOARD)
    assert mm < 1.0 and degrees < 0.3, (mm, degrees)


def test_calibration_averages_views_and_applies_the_board_pose_in_the_robot_frame():
    truth = board_pose()
    rng = np.random.default_rng(0)
    views = []
    for _ in range(6):  # sensor noise and exposure changes between frames of a fixed camera
        image = render_view(truth, brightness=rng.uniform(0.8, 1.1)).astype(float)
        views.append(np.clip(image + rng.normal(0, 3, image.shape), 0, 255).astype(np.uint8))
    board_to_world = np.eye(4)
    board_to_world[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    board_to_world[:3, 3] = [0.30, -0.05, 0.0]
    result = calibrate(views, K, "123", board_to_world=board_to_world)
    expected = board_to_world @ np.linalg.inv(truth @ CV_BOARD_TO_BOARD)
    mm, degrees = pose_error(result.matrix(), expected)
    assert mm < 1.0 and degrees < 0.3, (mm, degrees)
    assert result.views_used == 6 and result.views_refused == 0 and result.spread_mm < 1.0
    # the world frame has z up: the camera above the table has a positive height
    assert result.matrix()[2, 3] > 0.3


def test_views_without_the_board_or_with_a_bad_fit_are_refused():
    truth = board_pose()
    empty = np.full((SIZE[1], SIZE[0], 3), 150, np.uint8)
    with pytest.raises(CalibrationError, match="0 ChArUco corners < 12"):
        detect_board(empty, K, BoardSpec())
    # a camera whose real lens differs from the K given: the board fits badly
    wrong_K = K.copy()
    wrong_K[0, 0] *= 1.25
    with pytest.raises(CalibrationError, match="reprojection error"):
        detect_board(render_view(truth), wrong_K, BoardSpec())
    # a board printed at another scale than declared fits but lands elsewhere: the declared size matters
    small = BoardSpec(square_length=0.030, marker_length=0.022)
    view = detect_board(render_view(truth), K, small)
    assert pose_error(view.board_to_camera, truth @ CV_BOARD_TO_BOARD)[0] > 20
    with pytest.raises(CalibrationError, match=r"only 1 of 4 views usable \(need 3\); board not detected"):
        calibrate([render_view(truth), empty, empty, empty], K, "123", min_views=3)


def test_extrinsics_file_round_trip_and_missing_file_names_the_command(tmp_path):
    result = calibrate([render_view(board_pose())] * 5, K, "843112073228")
    path = save_extrinsics(result, tmp_path)
    assert path.name == "843112073228.json" and json.loads(path.read_text())["views_used"] == 5
    np.testing.assert_allclose(load_extrinsics("843112073228", tmp_path).matrix(), result.matrix())
    with pytest.raises(FileNotFoundError, match="obsbench calibrate-cameras --serial 000000000000"):
        load_extrinsics("000000000000", tmp_path)


def test_calibrate_cameras_command_on_a_recorded_camera(tmp_path, capsys):
    """`obsbench calibrate-cameras` end to end: frames of the board played back through librealsense."""
    pytest.importorskip("pyrealsense2")
    from lerobot_obsbench.cli import main as obsbench
    from lerobot_obsbench.robots.realsense.synthetic import StreamSpec, SyntheticRGBD, write_bag

    truth = board_pose((-35.0, 4.0, -20.0))
    spec = StreamSpec(SIZE[0], SIZE[1], K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    camera = SyntheticRGBD(spec, spec, serial_number="843112073228")
    view = render_view(truth)
    write_bag(tmp_path / "board.bag", camera, ((view, np.full(SIZE[::-1], 600, np.uint16)) for _ in range(30)))
    command = ["calibrate-cameras", "--playback", str(tmp_path / "board.bag"), "--width", "640", "--height", "480"]
    assert obsbench([*command, "--views", "6", "--interval", "0.02", "--out", str(tmp_path / "extrinsics")]) == 0
    saved = load_extrinsics("843112073228", tmp_path / "extrinsics")
    mm, degrees = pose_error(saved.matrix(), np.linalg.inv(truth @ CV_BOARD_TO_BOARD))
    assert mm < 1.0 and degrees < 0.3, (mm, degrees)
    assert "6/6 views" in capsys.readouterr().out

    assert obsbench(["calibrate-cameras", "--print-board", str(tmp_path / "board.png")]) == 0
    printed = cv2.imread(str(tmp_path / "board.png"), cv2.IMREAD_GRAYSCALE)
    assert printed.shape == (7 * 140 + 80, 5 * 140 + 80)  # 35 mm squares at 4000 px/m, 40 px margins
