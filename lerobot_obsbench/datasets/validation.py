"""`obsbench validate`: does a dataset serve each observation space — its metadata, and every sensor value.

The metadata check (`schema.validate_features`) says which keys exist with which shapes. The scan reads every
frame's depth, intrinsics and camera pose from the dataset's parquet files (colour stays in its videos: its
resolution comes from the metadata) and finds what would train silently wrong or crash hours in:

- depth: an integer dtype, values that look like millimetres (median valid depth between 2 cm and 20 m), not one
  value over the whole view in every frame (a conversion gone wrong; some such frames are reported), and per
  episode the frames with no valid pixel at all; an episode where most frames are empty fails, a few empty
  frames are reported (training gives them the empty-cloud point, see `lerobot_obsbench.spaces`);
- intrinsics: finite, with fx, fy > 0;
- cam2world: finite and rigid (orthonormal rotation with det +1, last row 0 0 0 1);
- colour and depth of one camera at the same resolution (rgbd, pointmap and pointcloud pair them pixel by pixel).

Each space's verdict lists the problems of the sensors it reads.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from lerobot_obsbench.camera_calibration import calibration_path, read_calibration
from lerobot_obsbench.geometry import rigidity_error
from lerobot_obsbench.schema import (
    ATTACH_CALIBRATION_HINT,
    CAM2WORLD_PREFIX,
    DEPTH_PREFIX,
    IMAGE_PREFIX,
    INTRINSICS_PREFIX,
    OBS_SPACES,
    ORACLE_SPACES,
    PRIVILEGED_STATE_KEY,
    SPACE_SENSORS,
    SchemaError,
    cam2world_key,
    depth_key,
    frame_size,
    image_key,
    intrinsics_key,
    stock_depth_cameras,
    stock_depth_key,
    validate_features,
)
from lerobot_obsbench.spaces import MAX_EMPTY_FRACTION, RIGID_TOLERANCE

# Median valid depth outside this range (millimetres) means the unit is wrong (metres, or 0.1 mm ticks).
DEPTH_MEDIAN_RANGE_MM = (20, 20_000)
# horizontal and vertical fields of view a camera's K may give at its frame size (degrees)
FIELD_OF_VIEW_DEG = (5, 170)
# where in the frame (fractions of its width / height) a principal point may lie: near the centre for any lens,
# off it for a crop, never at the border
PRINCIPAL_POINT_BAND = (0.05, 0.95)
INTEGER_DTYPES = ("uint16", "uint32", "int32", "int64")


@dataclass
class CameraScan:
    """What the scan found for one camera: problems per sensor prefix, and notes that do not fail a space."""

    problems: dict[str, list[str]] = field(default_factory=lambda: defaultdict(list))
    notes: list[str] = field(default_factory=list)
    empty_frames: int = 0


def _column(table, key: str, shape: tuple[int, ...]) -> np.ndarray:
    """A fixed-shape nested-list parquet column as one (n, *shape) array."""
    column = table.column(key).combine_chunks()
    column = getattr(column, "storage", column)  # HF datasets' ArrayND extension type, when registered
    for _ in shape:
        column = column.flatten()
    return column.to_numpy(zero_copy_only=False).reshape(-1, *shape)


def _episodes(flags: np.ndarray, episodes: np.ndarray, limit: int = 8) -> str:
    """The episodes where `flags` holds, as 'episodes 3, 7 (2 of 50)'."""
    bad = sorted({int(e) for e in episodes[flags]})
    shown = ", ".join(str(e) for e in bad[:limit]) + (", ..." if len(bad) > limit else "")
    return f"episode{'s' if len(bad) > 1 else ''} {shown} ({len(bad)} of {len(np.unique(episodes))})"


def scan_dataset(root: Path, features: dict, cameras: list[str], progress: bool = True) -> dict[str, CameraScan]:
    """Read every frame's depth, K and cam2world of `cameras` from the parquet files under `root`/data."""
    import pyarrow.parquet as pq
    from tqdm import tqdm

    scans = {cam: CameraScan() for cam in cameras}
    columns = {
        cam: [k for k in (depth_key(cam), intrinsics_key(cam), cam2world_key(cam)) if k in features] for cam in cameras
    }
    files = sorted((Path(root) / "data").rglob("*.parquet"))
    if not files:
        raise SchemaError(f"{root}/data has no parquet files: not a LeRobot v3 dataset, or an unfinished recording")
    gathered: dict[str, list] = defaultdict(list)
    for path in tqdm(files, desc="scanning frames", unit="file", disable=not progress):
        wanted = ["episode_index", *{k for keys in columns.values() for k in keys}]
        table = pq.read_table(path, columns=wanted)
        gathered["episode_index"].append(table.column("episode_index").to_numpy())
        for key in wanted[1:]:
            shape = tuple(int(s) for s in features[key]["shape"])
            gathered[key].append(_column(table, key, shape))
    episodes = np.concatenate(gathered.pop("episode_index"))
    data = {key: np.concatenate(parts) for key, parts in gathered.items()}
    for cam, scan in scans.items():
        _check_depth(cam, features, data, episodes, scan)
        _check_intrinsics(cam, features, data, episodes, scan)
        _check_cam2world(cam, data, episodes, scan)
        _check_sizes(cam, features, scan)
    return scans


def _check_depth(cam: str, features: dict, data: dict, episodes: np.ndarray, scan: CameraScan) -> None:
    key = depth_key(cam)
    if key not in data:
        return
    problems = scan.problems[DEPTH_PREFIX]
    dtype = features[key].get("dtype")
    if dtype not in INTEGER_DTYPES:
        problems.append(f"{key} has dtype {dtype}; depth is stored as uint16 millimetres (0 = invalid)")
        return
    depth = data[key].reshape(len(episodes), -1)
    valid = depth > 0
    empty = ~valid.any(axis=1)
    scan.empty_frames = int(empty.sum())
    if valid.any():
        median = float(np.median(depth[valid][:: max(1, int(valid.sum()) // 1_000_000)]))
        low, high = DEPTH_MEDIAN_RANGE_MM
        if not low <= median <= high:
            problems.append(
                f"{key}: median valid depth is {median:g}, expected millimetres ({low}..{high}); store "
                "(depth_m * 1000).round().astype(uint16)"
            )
    else:
        problems.append(f"{key}: every frame's depth is 0 (invalid): no depth was recorded")
        return
    # A frame whose valid pixels all hold one value: a camera square above a bare table can see that, a whole
    # dataset of them is a conversion gone wrong (a 1-channel image decoded as RLBench's packed depth, say)
    flat = valid.any(axis=1) & (np.where(valid, depth, depth.max()).min(axis=1) == depth.max(axis=1))
    if flat.any():
        summary = f"{key}: {int(flat.sum())} of {len(episodes)} frames hold one depth value over the whole view"
        if flat[valid.any(axis=1)].all():
            problems.append(f"{summary}: this is not depth; check how it was converted")
        else:
            scan.notes.append(f"{summary} (in {_episodes(flat, episodes)})")
    if empty.any():
        fractions = {int(e): float(empty[episodes == e].mean()) for e in np.unique(episodes[empty])}
        mostly = [e for e, f in fractions.items() if f > MAX_EMPTY_FRACTION]
        worst = max(fractions, key=fractions.get)
        summary = (
            f"{key}: {scan.empty_frames} of {len(episodes)} frames have no valid depth pixel, in "
            f"{_episodes(empty, episodes)}; worst: episode {worst}, {fractions[worst]:.0%} of its frames"
        )
        if mostly:
            problems.append(
                f"{summary}; more than {MAX_EMPTY_FRACTION:.0%} of the frames of episodes {mostly[:8]} are empty: "
                "re-record or drop them (lerobot-edit-dataset --operation.type=delete_episodes)"
            )
        else:
            scan.notes.append(f"{summary} (training gives such frames the empty-cloud point)")


def intrinsics_off(K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Per K of (N, 3, 3): whether it cannot be a camera of `size` = (height, width) pixels: non-finite, fx or
    fy <= 0, the principal point outside PRINCIPAL_POINT_BAND of the image (a K of another resolution, or scaled),
    or a field of view outside FIELD_OF_VIEW_DEG."""
    height, width = size
    K = np.asarray(K, dtype=np.float64).reshape(-1, 3, 3)
    finite = np.isfinite(K).all(axis=(1, 2))
    fx, fy, cx, cy = (np.where(finite, K[:, i, j], np.nan) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    with np.errstate(invalid="ignore", divide="ignore"):
        fov = np.degrees(2 * np.arctan(np.array([width / (2 * fx), height / (2 * fy)])))
        low, high = FIELD_OF_VIEW_DEG
        low_pp, high_pp = PRINCIPAL_POINT_BAND
        ok = (fx > 0) & (fy > 0)
        ok &= (cx >= low_pp * width) & (cx <= high_pp * width) & (cy >= low_pp * height) & (cy <= high_pp * height)
        ok &= ((fov >= low) & (fov <= high)).all(axis=0)
    return ~(finite & ok)


def _k_text(K: np.ndarray) -> str:
    return f"fx {K[0, 0]:.4g}, fy {K[1, 1]:.4g}, principal point ({K[0, 2]:.4g}, {K[1, 2]:.4g})"


def _check_intrinsics(cam: str, features: dict, data: dict, episodes: np.ndarray, scan: CameraScan) -> None:
    key = intrinsics_key(cam)
    if key not in data:
        return
    sized = depth_key(cam) if depth_key(cam) in features else image_key(cam)  # a scanned camera has one of them
    size = frame_size(sized, features[sized])
    bad = intrinsics_off(data[key], size)
    if bad.any():
        first = data[key][np.flatnonzero(bad)[0]]
        scan.problems[INTRINSICS_PREFIX].append(
            f"{key}: {int(bad.sum())} frames have intrinsics that cannot belong to the {size[1]}x{size[0]} frames "
            f"(e.g. {_k_text(first)}: a principal point at or outside the image's border, fx/fy <= 0, a field of "
            f"view outside {FIELD_OF_VIEW_DEG[0]}-{FIELD_OF_VIEW_DEG[1]} deg, or not finite), in "
            f"{_episodes(bad, episodes)}; "
            "record the K of the stream at the size it was stored (scale fx, fy, cx, cy with the image)"
        )


def calibration_problems(cam: str, features: dict, calibration: dict) -> list[str]:
    """What in a stock-depth camera's attached calibration cannot fit the dataset's recorded frames."""
    problems = []
    streams = (
        ("color", image_key(cam)),
        ("depth", stock_depth_key(cam)),
    )
    for stream, key in streams:
        if key not in features:
            continue
        recorded = tuple(frame_size(key, features[key]))
        given = tuple(int(v) for v in calibration[f"{stream}_size"])
        K = np.asarray(calibration[f"{stream}_intrinsics"], dtype=np.float64)
        if given != recorded:
            problems.append(
                f"camera {cam}'s attached calibration: {stream}_size {list(given)} is not the dataset's {key} "
                f"({recorded[0]}x{recorded[1]} as height x width); attach the calibration of the streams at the "
                f"size they were recorded: {ATTACH_CALIBRATION_HINT.format(cam=cam)}"
            )
        elif intrinsics_off(K, recorded).any():
            problems.append(
                f"camera {cam}'s attached calibration: {stream}_intrinsics ({_k_text(K)}) cannot belong to the "
                f"{recorded[1]}x{recorded[0]} {stream} frames (principal point outside, or field of view outside "
                f"{FIELD_OF_VIEW_DEG[0]}-{FIELD_OF_VIEW_DEG[1]} deg); attach the K of that stream at that size"
            )
    return problems


def _check_cam2world(cam: str, data: dict, episodes: np.ndarray, scan: CameraScan) -> None:
    key = cam2world_key(cam)
    if key not in data:
        return
    pose = data[key].astype(np.float64)
    finite = np.isfinite(pose).all(axis=(1, 2))
    error = np.full(len(pose), np.inf)
    error[finite] = rigidity_error(torch.from_numpy(pose[finite])).numpy()
    bad = error > RIGID_TOLERANCE
    if bad.any():
        scan.problems[CAM2WORLD_PREFIX].append(
            f"{key}: {int(bad.sum())} frames are not rigid camera -> world transforms (largest deviation "
            f"{float(error[bad].max()):.3g}; rotation orthonormal with det +1, last row 0 0 0 1), in "
            f"{_episodes(bad, episodes)}; fix the recorded extrinsics"
        )


def _check_sizes(cam: str, features: dict, scan: CameraScan) -> None:
    colour, depth = image_key(cam), depth_key(cam)
    if colour in features and depth in features:
        colour_hw, depth_hw = frame_size(colour, features[colour]), frame_size(depth, features[depth])
        if colour_hw != depth_hw:
            scan.problems["size"].append(
                f"{colour} is {colour_hw[0]}x{colour_hw[1]} but {depth} is {depth_hw[0]}x{depth_hw[1]}: colour "
                "and depth are paired pixel by pixel; record depth aligned to colour at the same resolution"
            )


def space_verdicts(
    features: dict,
    spaces: tuple[str, ...],
    cameras: list[str] | None,
    scans: dict[str, CameraScan] | None,
    calibration: dict | None = None,
) -> dict[str, tuple[list[str], list[str]]]:
    """space -> (cameras used, problems): metadata problems, then the scanned sensors' (when `scans`)."""
    verdicts = {}
    for space in spaces:
        try:
            used = validate_features(features, space, cameras, calibration)
        except SchemaError as err:
            verdicts[space] = ([], [str(err)])
            continue
        problems = []
        needed = SPACE_SENSORS[space]
        for cam in used:
            scan = (scans or {}).get(cam)
            if scan is None:
                continue
            for prefix in needed:
                problems += scan.problems.get(prefix, [])
            if IMAGE_PREFIX in needed and DEPTH_PREFIX in needed:
                problems += scan.problems.get("size", [])
        verdicts[space] = (used, problems)
    return verdicts


def validate_dataset(
    root: Path,
    repo_id: str,
    obs_space: str = "all",
    cameras: list[str] | None = None,
    quick: bool = False,
    progress: bool = True,
    echo=print,
) -> int:
    """Print one verdict per space (and the scan's notes); 0 when every asked space passes, else 1."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(repo_id, root=root)
    features = meta.features
    calibration = {cam: c.to_dict() for cam, c in read_calibration(root).items()}
    stock = [cam for cam in stock_depth_cameras(features) if cam in calibration]
    spaces = OBS_SPACES if obs_space == "all" else (obs_space,)
    if obs_space == "all" and PRIVILEGED_STATE_KEY not in features:
        # the oracle control exists only in simulation: not a defect of a real recording
        spaces = tuple(s for s in spaces if s not in ORACLE_SPACES)
        echo(f"n/a     {ORACLE_SPACES[0]:10s} the oracle control needs simulated object poses ({PRIVILEGED_STATE_KEY})")
    scans = None
    if not quick:
        used = {c for space in spaces for c in _used(features, space, cameras, calibration)}
        scanned = sorted(used - set(stock))
        scans = scan_dataset(Path(root), features, scanned, progress=progress) if scanned else {}
        for cam in stock:  # their K and sizes come from the attached calibration, not the frames
            scans.setdefault(cam, CameraScan()).problems[DEPTH_PREFIX] += calibration_problems(
                cam, features, calibration[cam]
            )
    failures = 0
    for cam in stock:
        echo(f"note    {cam}: LeRobot's own depth recording, registered to colour with {calibration_path(root)}")
    for space, (used, problems) in space_verdicts(features, spaces, cameras, scans, calibration).items():
        if problems:
            failures += 1
            echo(f"FAILED  {space:10s} " + "\n                   ".join(problems))
        else:
            control = "oracle control: object poses" if space in ORACLE_SPACES else "blind control"
            echo(f"ok      {space:10s} cameras: {', '.join(used) or f'(none: {control})'}")
    for scan in (scans or {}).values():
        for note in scan.notes:
            echo(f"note    {note}")
    scope = "metadata only (--quick)" if quick else "metadata and every frame's depth, intrinsics and pose"
    echo(f"{meta.total_episodes} episodes, {meta.total_frames} frames at {meta.fps} fps in {root}; checked {scope}")
    return 1 if failures else 0


def _used(features: dict, space: str, cameras: list[str] | None, calibration: dict) -> list[str]:
    try:
        return validate_features(features, space, cameras, calibration)
    except SchemaError:
        return []
