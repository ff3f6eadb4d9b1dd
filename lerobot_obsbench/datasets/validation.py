"""`obsbench validate`: does a dataset serve each observation space — its metadata, and every frame it trains from.

The metadata check (`schema.validate_features`) says which keys exist with which shapes. The frame scan then reads
every frame of the keys the asked spaces read and finds what would train silently wrong or crash hours in:

- the schema's own arrays, read from the parquet files: depth (an integer dtype, values that look like
  millimetres: median valid depth between 2 cm and 20 m; not one value over the whole view in every frame, a
  conversion gone wrong; per episode the frames with no valid pixel: an episode where most frames are empty
  fails, a few empty frames are reported, as training gives them the empty-cloud point, see
  `lerobot_obsbench.spaces`), intrinsics (finite, fx, fy > 0, a field of view and principal point that fit the
  frame) and cam2world (finite and rigid: orthonormal rotation with det +1, last row 0 0 0 1);
- colour (`observation.images.<cam>`, video or images) and LeRobot's own depth maps (`observation.images.<cam>_depth`
  of calibrated cameras, video or 16-bit images), decoded with LeRobot's reader as training decodes them: a file
  that cannot be decoded, and LeRobot depth in which no frame holds valid depth or whose median is not millimetres
  (after the calibration's `depth_unit_mm`), are refused in one line naming the camera, the file and the fix;
  the per-episode checks above apply to LeRobot depth too;
- colour and depth of one camera at the same resolution (rgbd, pointmap and pointcloud pair them pixel by pixel).

Each space's verdict lists the problems of the sensors it reads, and the output says which keys were read, how many
frames and from what storage.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterator
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
    PRIVILEGED_STATE_KEY,
    SchemaError,
    available_spaces,
    cam2world_key,
    depth_key,
    frame_size,
    image_key,
    intrinsics_key,
    space_info,
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
# Valid depth values kept per DepthFrames (a regular subsample): enough for the median that tells the unit.
DEPTH_SAMPLES = 16_384
# Frames decoded per call: bounds the memory a long episode's frames take while they are checked.
DECODE_BLOCK_FRAMES = 64
# LeRobotDataset's default: how far a video frame's timestamp may be from the one the data asks for (seconds).
TOLERANCE_S = 1e-4
# What PIL raises for an image in the parquet files that cannot be decoded (truncated or damaged bytes).
IMAGE_DECODE_ERRORS = (OSError, ValueError)


@dataclass
class CameraScan:
    """What the scan found for one camera: problems per sensor prefix, and notes that do not fail a space."""

    problems: dict[str, list[str]] = field(default_factory=lambda: defaultdict(list))
    notes: list[str] = field(default_factory=list)


@dataclass
class FrameScan:
    """What the frame scan found per camera, and one line per group of keys it read (which, how many of the
    dataset's `total_frames`, from what storage)."""

    total_frames: int
    cameras: dict[str, CameraScan] = field(default_factory=dict)
    read: list[str] = field(default_factory=list)


@dataclass
class DepthFrames:
    """One depth source frame by frame: each frame's episode, whether it has a valid pixel and whether its valid
    pixels all hold one value; and a subsample of the valid values in millimetres."""

    episodes: np.ndarray
    nonempty: np.ndarray
    flat: np.ndarray
    samples: np.ndarray

    @classmethod
    def of(cls, depth: np.ndarray, valid: np.ndarray, episodes: np.ndarray, mm_per_value: float = 1) -> DepthFrames:
        """From frames (n, pixels) of stored values, their valid pixels and their episodes (n,)."""
        nonempty = valid.any(axis=1)
        # invalid pixels filled with the extreme that cannot win, in the frames' own dtype (no float copy)
        lowest = np.where(valid, depth, depth.max()).min(axis=1)
        flat = nonempty & (lowest == np.where(valid, depth, depth.min()).max(axis=1))
        values = depth[valid]
        return cls(episodes, nonempty, flat, values[:: max(1, values.size // DEPTH_SAMPLES)] * mm_per_value)

    @classmethod
    def joined(cls, parts: list[DepthFrames]) -> DepthFrames:
        return cls(*(np.concatenate([getattr(p, name) for p in parts]) for name in cls.__dataclass_fields__))

    @property
    def median_mm(self) -> float:
        return float(np.median(self.samples))


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


def scan_arrays(root: Path, features: dict, cameras: list[str], scan: FrameScan, progress: bool = True) -> None:
    """Read every frame's depth, K and cam2world of `cameras` from the parquet files under `root`/data."""
    import pyarrow.parquet as pq
    from tqdm import tqdm

    scans = {cam: scan.cameras.setdefault(cam, CameraScan()) for cam in cameras}
    columns = {
        cam: [k for k in (depth_key(cam), intrinsics_key(cam), cam2world_key(cam)) if k in features] for cam in cameras
    }
    files = _parquet_files(root)
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
    for cam, camera_scan in scans.items():
        _check_depth(cam, features, data, episodes, camera_scan)
        _check_intrinsics(cam, features, data, episodes, camera_scan)
        _check_cam2world(cam, data, episodes, camera_scan)
        _check_sizes(cam, features, camera_scan)
    keys = [key for keys in columns.values() for key in keys]
    if keys:
        scan.read.append(
            f"{', '.join(keys)}: {len(episodes)} of {scan.total_frames} frames, every value (arrays in parquet)"
        )


def _parquet_files(root: Path) -> list[Path]:
    files = sorted((Path(root) / "data").rglob("*.parquet"))
    if not files:
        raise SchemaError(f"{root}/data has no parquet files: not a LeRobot v3 dataset, or an unfinished recording")
    return files


def _check_depth(cam: str, features: dict, data: dict, episodes: np.ndarray, scan: CameraScan) -> None:
    key = depth_key(cam)
    if key not in data:
        return
    dtype = features[key].get("dtype")
    if dtype not in INTEGER_DTYPES:
        scan.problems[DEPTH_PREFIX].append(
            f"{key} has dtype {dtype}; depth is stored as uint16 millimetres (0 = invalid)"
        )
        return
    depth = data[key].reshape(len(episodes), -1)
    _judge_depth(key, DepthFrames.of(depth, depth > 0, episodes), scan)


def _judge_depth(key: str, frames: DepthFrames, scan: CameraScan) -> None:
    """The problems and notes of one depth source's frames: its unit, frames of one value, empty frames."""
    problems, episodes = scan.problems[DEPTH_PREFIX], frames.episodes
    empty = ~frames.nonempty
    if frames.nonempty.any():
        median = frames.median_mm
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
    flat = frames.flat
    if flat.any():
        summary = f"{key}: {int(flat.sum())} of {len(episodes)} frames hold one depth value over the whole view"
        if flat[frames.nonempty].all():
            problems.append(f"{summary}: this is not depth; check how it was converted")
        else:
            scan.notes.append(f"{summary} (in {_episodes(flat, episodes)})")
    if empty.any():
        fractions = {int(e): float(empty[episodes == e].mean()) for e in np.unique(episodes[empty])}
        mostly = [e for e, f in fractions.items() if f > MAX_EMPTY_FRACTION]
        worst = max(fractions, key=fractions.get)
        summary = (
            f"{key}: {int(empty.sum())} of {len(episodes)} frames have no valid depth pixel, in "
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


def decode_frames(
    root: Path,
    meta,
    colour_keys: list[str],
    depth_cameras: list[str],
    calibration: dict,
    scan: FrameScan,
    progress: bool = True,
) -> None:
    """Decode every frame of `colour_keys` and of the LeRobot depth maps of `depth_cameras` as training's reader
    decodes them; refuse a file that cannot be decoded and LeRobot depth that holds no millimetres."""
    import pyarrow.parquet as pq
    from lerobot.configs import DEPTH_METER_UNIT
    from lerobot.datasets.dataset_reader import DatasetReader
    from lerobot.datasets.depth_utils import MM_PER_METRE
    from lerobot.utils.import_utils import get_safe_default_video_backend
    from tqdm import tqdm

    # the reader's video decoding needs only the metadata: the parquet files are read here, column by column
    reader = DatasetReader(
        meta, Path(root), None, TOLERANCE_S, get_safe_default_video_backend(), None, None, return_uint8=True
    )
    files = _parquet_files(root)
    index = [pq.read_table(path, columns=["episode_index", "timestamp"]) for path in files]
    episodes = np.concatenate([table.column("episode_index").to_numpy() for table in index])
    timestamps = np.concatenate([table.column("timestamp").to_numpy() for table in index])
    blocks = {
        key: _video_blocks(reader, key, episodes, timestamps) if key in meta.video_keys else _image_blocks(files, key)
        for key in colour_keys + [stock_depth_key(cam) for cam in depth_cameras]
    }
    with tqdm(total=len(blocks) * meta.total_frames, desc="decoding frames", unit="frame", disable=not progress) as bar:
        for key in colour_keys:
            read, frames = set(), 0
            for path, _, decoded in blocks[key]:
                read.add(path)
                frames += len(decoded)
                bar.update(len(decoded))
            scan.read.append(f"{key}: {frames} of {scan.total_frames} frames decoded ({_storage(meta, key, read)})")
        for cam in depth_cameras:
            key, entry = stock_depth_key(cam), calibration[cam]
            unit, holes = float(entry["depth_unit_mm"]), float(entry["depth_min_mm"])
            limit = holes + 0.5 if holes > 0 else 0.0  # the hole value as spaces.CalibratedDepth masks it
            # LeRobot's reader serves depth images stored in metres in millimetres
            served = MM_PER_METRE if (meta.features[key].get("info") or {}).get("depth_unit") == DEPTH_METER_UNIT else 1
            read, parts = set(), []
            for path, block_episodes, decoded in blocks[key]:
                read.add(path)
                stored = decoded.reshape(len(decoded), -1) * served
                parts.append(DepthFrames.of(stored, stored > limit, block_episodes, mm_per_value=unit))
                bar.update(len(decoded))
            frames = DepthFrames.joined(parts)
            _refuse_depth_without_millimetres(cam, key, frames, sorted(read), unit, holes)
            _judge_depth(key, frames, scan.cameras.setdefault(cam, CameraScan()))
            scan.read.append(
                f"{key} (camera {cam}, LeRobot's depth): {len(frames.episodes)} of {scan.total_frames} frames "
                f"decoded ({_storage(meta, key, read)}); {int(frames.nonempty.sum())} with valid depth, median "
                f"valid depth {frames.median_mm:.0f} mm"
            )


def _video_blocks(
    reader, key: str, episodes: np.ndarray, timestamps: np.ndarray
) -> Iterator[tuple[Path, np.ndarray, np.ndarray]]:
    """(file, episodes (k,), frames (k, C, H, W)) over every frame of video `key`, DECODE_BLOCK_FRAMES at a time,
    decoded by LeRobot's reader as training decodes them (its depth video dequantised to millimetres)."""
    from lerobot_obsbench.dataset_reads import query_videos

    for ep_idx in np.unique(episodes).tolist():
        rels = np.flatnonzero(episodes == ep_idx)
        path = reader.root / reader._meta.get_video_file_path(ep_idx, key)
        for start in range(0, len(rels), DECODE_BLOCK_FRAMES):
            block = rels[start : start + DECODE_BLOCK_FRAMES]
            decoded = query_videos(reader, {key: timestamps[block].tolist()}, ep_idx)[key]
            yield path, episodes[block], decoded.reshape(len(block), *decoded.shape[-3:]).numpy()


def _image_blocks(files: list[Path], key: str) -> Iterator[tuple[Path, np.ndarray, np.ndarray]]:
    """(file, episodes (k,), frames (k, H, W[, C])) over every image of `key` in the parquet `files`, as stored,
    decoded by the `datasets` Image feature LeRobot's reader decodes them with."""
    import pyarrow.parquet as pq
    from datasets.features import Image

    from lerobot_obsbench.dataset_reads import error_reason

    image = Image()
    for path in files:
        table = pq.read_table(path, columns=["episode_index", key])
        episodes = table.column("episode_index").to_numpy()
        for start in range(0, len(table), DECODE_BLOCK_FRAMES):
            stored = table.column(key).slice(start, DECODE_BLOCK_FRAMES).to_pylist()
            block = episodes[start : start + DECODE_BLOCK_FRAMES]
            decoded = []
            for row, value in enumerate(stored):
                try:
                    decoded.append(np.asarray(image.decode_example(value)))
                except IMAGE_DECODE_ERRORS as err:
                    raise SchemaError(
                        f"{path}: the {key} image of episode {block[row]} cannot be decoded ({error_reason(err)}); "
                        "copy the file again, or drop the episode (lerobot-edit-dataset "
                        "--operation.type=delete_episodes)"
                    ) from None
            yield path, block, np.stack(decoded)


def _storage(meta, key: str, files: set[Path]) -> str:
    kind = "video" if key in meta.video_keys else "images in parquet"
    return f"{kind}, {len(files)} file{'s' if len(files) != 1 else ''}"


def _files_text(files: list[Path]) -> str:
    return str(files[0]) + (f" and {len(files) - 1} more files" if len(files) > 1 else "")


def _refuse_depth_without_millimetres(
    cam: str, key: str, frames: DepthFrames, files: list[Path], unit: float, holes: float
) -> None:
    """Refuse LeRobot depth no depth space can train from: no frame with a valid value, or a median that is not
    millimetres (what the empty-cloud stop in training finds only after its first batches)."""
    where = f"camera {cam}: {key} in {_files_text(files)}"
    if not frames.nonempty.any():
        hole = f"0 or the depth codec's hole value ({holes:g} mm)" if holes > 0 else "0"
        raise SchemaError(
            f"{where}: no frame holds valid depth (all {len(frames.episodes)} frames hold only {hole}): the "
            "camera recorded no depth, or depth in metres was stored as integers (LeRobot takes integer depth as "
            "millimetres); record again with the depth stream on (use_depth: true) in millimetres"
        )
    low, high = DEPTH_MEDIAN_RANGE_MM
    if not low <= frames.median_mm <= high:
        raise SchemaError(
            f"{where}: median valid depth is {frames.median_mm:g} mm (stored value x depth_unit_mm {unit:g}), not in "
            f"millimetres ({low}..{high} mm): depth in metres or centimetres stored as integers (LeRobot takes "
            "integer depth as millimetres: record again) or a wrong depth_unit_mm in the attached calibration "
            "(attach it again with the camera's millimetres per stored value)"
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
        needed = space_info(space).sensors
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
    """Print one verdict per space, the scan's notes and what it read; 0 when every asked space passes, else 1. A
    file that cannot be decoded, or LeRobot depth without millimetres, is refused (SchemaError) before any verdict."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(repo_id, root=root)
    features = meta.features
    calibration = {cam: c.to_dict() for cam, c in read_calibration(root).items()}
    stock = [cam for cam in stock_depth_cameras(features) if cam in calibration]
    spaces = available_spaces() if obs_space == "all" else (obs_space,)
    if obs_space == "all" and PRIVILEGED_STATE_KEY not in features:
        # the oracle control exists only in simulation: not a defect of a real recording
        oracles = available_spaces(lambda s: s.control == "oracle")
        spaces = tuple(s for s in spaces if s not in oracles)
        for oracle in oracles:
            echo(f"n/a     {oracle:10s} the oracle control needs simulated object poses ({PRIVILEGED_STATE_KEY})")
    scan = None
    if not quick:
        scan = FrameScan(meta.total_frames)
        used = {c for space in spaces for c in _used(features, space, cameras, calibration)}
        scanned = sorted(used - set(stock))
        if scanned:
            scan_arrays(Path(root), features, scanned, scan, progress=progress)
        for cam in stock:  # their K and sizes come from the attached calibration, not the frames
            scan.cameras.setdefault(cam, CameraScan()).problems[DEPTH_PREFIX] += calibration_problems(
                cam, features, calibration[cam]
            )
        colour_keys, depth_cameras = _decoded_sources(features, spaces, cameras, calibration, stock)
        if colour_keys or depth_cameras:
            decode_frames(Path(root), meta, colour_keys, depth_cameras, calibration, scan, progress=progress)
    failures = 0
    for cam in stock:
        echo(f"note    {cam}: LeRobot's own depth recording, registered to colour with {calibration_path(root)}")
    scans = scan.cameras if scan else None
    for space, (used, problems) in space_verdicts(features, spaces, cameras, scans, calibration).items():
        if problems:
            failures += 1
            echo(f"FAILED  {space:10s} " + "\n                   ".join(problems))
        else:
            control = "oracle control: object poses" if space_info(space).control == "oracle" else "blind control"
            echo(f"ok      {space:10s} cameras: {', '.join(used) or f'(none: {control})'}")
    for camera_scan in (scans or {}).values():
        for note in camera_scan.notes:
            echo(f"note    {note}")
    for line in scan.read if scan else []:
        echo(f"read    {line}")
    if quick:
        scope = "the metadata only (--quick): no frame was read"
    elif scan.read:
        scope = "the metadata and every frame of the keys read above"
    else:
        scope = "the metadata (the asked spaces read no camera)"
    echo(f"{meta.total_episodes} episodes, {meta.total_frames} frames at {meta.fps} fps in {root}; checked {scope}")
    return 1 if failures else 0


def _decoded_sources(
    features: dict, spaces: tuple[str, ...], cameras: list[str] | None, calibration: dict, stock: list[str]
) -> tuple[list[str], list[str]]:
    """(colour keys, cameras with LeRobot depth) that the asked spaces train from: decoded frame by frame."""
    colour_keys, depth_cameras = set(), set()
    for space in spaces:
        sensors = space_info(space).sensors
        for cam in _used(features, space, cameras, calibration):
            if IMAGE_PREFIX in sensors:
                colour_keys.add(image_key(cam))
            if DEPTH_PREFIX in sensors and cam in stock:
                depth_cameras.add(cam)
    return sorted(colour_keys), sorted(depth_cameras)


def _used(features: dict, space: str, cameras: list[str] | None, calibration: dict) -> list[str]:
    try:
        return validate_features(features, space, cameras, calibration)
    except SchemaError:
        return []
