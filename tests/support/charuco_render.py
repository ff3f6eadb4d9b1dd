"""A sub-pixel exact picture of the printed ChArUco board seen by a pinhole camera, for the extrinsics tests.

Every camera pixel is split into `supersample` x `supersample` sub-pixels; each sub-pixel centre is mapped back
through the board-plane homography onto the printed board and takes the grey of the print there (or of the
table around it), and the pixel is the mean of its sub-pixels: the area average of the board over the pixel, up
to the sub-pixel quantisation. Pixel conventions are OpenCV's: integer image coordinates are pixel centres, so
pixel (u, v) covers [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5] and a board point projects to K (R X + t) exactly.
The print is `BoardSpec.image()`, whose squares are whole pixels at 4000 px/m: the square edges, and so the
ChArUco corners, sit exactly where the board's object points say (OpenCV's board frame: origin at the print's
top-left outer corner of the squares, x along the columns, y down the rows, metres).
"""

from __future__ import annotations

import numpy as np

from lerobot_obsbench.robots.extrinsics import BoardSpec

PX_PER_M, MARGIN_PX = 4000.0, 40  # the print: 35 mm squares are 140 px, a 10 mm white margin


def render_board(
    cv_board_to_camera: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    spec: BoardSpec | None = None,
    supersample: int = 4,
    table: float = 150.0,
    brightness: float = 1.0,
) -> np.ndarray:
    """The board at pose `cv_board_to_camera` (OpenCV board frame -> camera, 4x4) seen through K by a
    `size` = (width, height) camera, on a grey table; grey float32 image in [0, 255 * brightness]."""
    spec = spec or BoardSpec()
    printed = spec.image(PX_PER_M, MARGIN_PX).astype(np.float32)
    R, t = cv_board_to_camera[:3, :3], cv_board_to_camera[:3, 3]
    homography = K @ np.column_stack([R[:, 0], R[:, 1], t])  # board plane (X, Y, 1) metres -> image
    to_board = np.linalg.inv(homography)
    width, height = size
    image = np.full((height, width), table, np.float32)

    # only the pixels the print can cover (its outline projected, one pixel of slack)
    rows, cols = printed.shape
    outline = np.array([[0, 0], [cols, 0], [cols, rows], [0, rows]], float) / PX_PER_M - MARGIN_PX / PX_PER_M
    projected = homography @ np.c_[outline, np.ones(4)].T
    if np.any(projected[2] <= 0):
        raise ValueError("the board is not entirely in front of the camera")
    u, v = projected[:2] / projected[2]
    u0, u1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 2, width)
    v0, v1 = max(int(np.floor(v.min())) - 1, 0), min(int(np.ceil(v.max())) + 2, height)
    if u0 >= u1 or v0 >= v1:
        return image * brightness

    s = supersample
    offsets = (np.arange(s) + 0.5) / s - 0.5  # sub-pixel centres within [-0.5, 0.5]
    xs = (np.arange(u0, u1)[:, None] + offsets).ravel()
    chunk = max(1, 2_000_000 // (len(xs) * s))  # pixel rows per step, to bound memory
    for top in range(v0, v1, chunk):
        bottom = min(top + chunk, v1)
        ys = (np.arange(top, bottom)[:, None] + offsets).ravel()[:, None]
        w = to_board[2, 0] * xs + to_board[2, 1] * ys + to_board[2, 2]
        X = (to_board[0, 0] * xs + to_board[0, 1] * ys + to_board[0, 2]) / w
        Y = (to_board[1, 0] * xs + to_board[1, 1] * ys + to_board[1, 2]) / w
        # print pixel (row, col) covers [col, col + 1) x [row, row + 1) in print units from its top-left edge
        col = np.floor(X * PX_PER_M + MARGIN_PX).astype(np.int64)
        row = np.floor(Y * PX_PER_M + MARGIN_PX).astype(np.int64)
        inside = (w > 0) & (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
        samples = np.where(inside, printed[row.clip(0, rows - 1), col.clip(0, cols - 1)], np.float32(table))
        image[top:bottom, u0:u1] = samples.reshape(bottom - top, s, u1 - u0, s).mean(axis=(1, 3))
    return image * brightness


def to_uint8_rgb(grey: np.ndarray, noise: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
    """A float grey render as the RGB uint8 frame a camera delivers, with optional Gaussian sensor noise."""
    if noise:
        grey = grey + (rng or np.random.default_rng()).normal(0.0, noise, grey.shape)
    grey = np.clip(np.round(grey), 0, 255).astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


def look_at_board(
    distance: float, tilt_deg: float, azimuth_deg: float, roll_deg: float = 0.0, spec: BoardSpec | None = None
) -> np.ndarray:
    """OpenCV board -> camera transform of a camera `distance` metres from the board's centre, looking at it,
    its optical axis `tilt_deg` off the board's normal towards azimuth `azimuth_deg` (in the board plane, from
    OpenCV's board x), turned `roll_deg` about its optical axis."""
    spec = spec or BoardSpec()
    centre = np.array([spec.squares_x * spec.square_length / 2, spec.squares_y * spec.square_length / 2, 0.0])
    tilt, azimuth, roll = np.radians([tilt_deg, azimuth_deg, roll_deg])
    # OpenCV's board z points into the print: the camera sits on the -z side, looking along +z when untilted
    direction = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])
    position = centre + distance * direction
    forward = -direction  # camera z
    down = np.array([0.0, 1.0, 0.0]) - forward * forward[1]  # camera y: towards the print's lower rows
    down /= np.linalg.norm(down)
    right = np.cross(down, forward)  # camera x
    camera_to_board = np.eye(4)
    c, s = np.cos(roll), np.sin(roll)
    x_axis, y_axis = c * right + s * down, -s * right + c * down
    camera_to_board[:3, :3] = np.column_stack([x_axis, y_axis, forward])
    camera_to_board[:3, 3] = position
    return np.linalg.inv(camera_to_board)
