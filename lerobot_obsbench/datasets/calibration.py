"""`obsbench attach-calibration`: make a dataset recorded by stock `lerobot-record` (a RealSense with
`use_depth: true`) usable by every observation space, by writing its cameras' calibration into the dataset's
`meta/obsbench_cameras.json` (see `camera_calibration`).

The depth and colour intrinsics and the depth->colour extrinsic come from the camera itself (`--serial`, the
streams at the dataset's resolutions), from a RealSense recording of it (`--from-recording`, a .bag of the same
streams), or from a JSON file of `CameraCalibration` fields (`--from-json`); cam2world from `obsbench
calibrate-cameras` (`--cam2world`, its saved file or a plain 4x4 JSON matrix). Sizes are checked against the
dataset's features, and the depth codec's hole value is read from them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lerobot_obsbench.camera_calibration import (
    CalibrationFileError,
    CameraCalibration,
    stored_calibration,
    write_calibration,
)
from lerobot_obsbench.errors import MissingFileError
from lerobot_obsbench.schema import (
    SchemaError,
    image_key,
    is_stock_depth,
    stock_depth_cameras,
    stock_depth_key,
)


def _read_json(path: Path, what: str):
    """A JSON file's content, or one SchemaError line naming `what` it is and why it cannot be read."""
    try:
        return json.loads(Path(path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise SchemaError(f"{what} {path}: not valid JSON ({err})") from None


def _features(root: Path) -> dict:
    info = root / "meta" / "info.json"
    if not info.is_file():
        raise MissingFileError(f"{root} is not a LeRobot dataset (no meta/info.json)")
    data = _read_json(info, "the dataset's metadata")
    if not isinstance(data, dict) or not isinstance(data.get("features"), dict):
        raise SchemaError(f"{info}: no 'features' mapping; is the dataset's metadata complete?")
    return data["features"]


def _size(feature: dict) -> list[int]:
    shape = list(feature["shape"])
    return shape[:2] if shape[-1] in (1, 3) else shape[1:]  # (H, W, C) as LeRobot records, else (C, H, W)


def _stream_profiles(rs, device, sizes, what: str) -> tuple:
    """The colour and depth video stream profiles of `device` (named `what` in errors): the ones a recording holds
    (`sizes` None), else the camera's rgb8 colour and z16 depth profiles at `sizes` = (colour (H, W), depth (H, W))."""
    wanted = {rs.stream.color: rs.format.rgb8, rs.stream.depth: rs.format.z16}
    offered = {kind: [] for kind in wanted}
    for sensor in device.query_sensors():
        for profile in sensor.get_stream_profiles():
            if profile.stream_type() in wanted and profile.is_video_stream_profile():
                offered[profile.stream_type()].append(profile.as_video_stream_profile())
    chosen = []
    for (kind, fmt), size in zip(wanted.items(), sizes or (None, None), strict=True):
        name = "colour" if kind == rs.stream.color else "depth"
        usable = [p for p in offered[kind] if size is None or p.format() == fmt]
        found = [p for p in usable if size is None or [p.height(), p.width()] == size]
        if not found:
            have = ", ".join(f"{h}x{w}" for h, w in sorted({(p.height(), p.width()) for p in usable})) or "none"
            want = "" if size is None else f"{size[0]}x{size[1]} (HxW) {str(fmt).split('.')[-1]} "
            raise SchemaError(f"the {what} has no {want}{name} stream (it has: {have})")
        chosen.append(found[0])
    return tuple(chosen)


def realsense_streams(recording: str | Path | None = None, serial: str | None = None, sizes=None) -> dict:
    """Intrinsics, depth->colour extrinsic and depth unit of a RealSense (by serial) or of a .bag recording, as
    `CameraCalibration` fields (without cam2world). `sizes` = (colour (H, W), depth (H, W)) picks a live camera's
    stream resolutions; a recording gives the ones it holds. Read from the stream profiles, without streaming:
    stopping a pipeline that plays a short recording crashed librealsense now and then."""
    from lerobot_obsbench.robots.realsense.realsense_rgbd import import_realsense, pinhole_K

    rs = import_realsense()
    context = rs.context()
    if recording is not None:
        if not Path(recording).is_file():
            raise MissingFileError(f"--from-recording {recording}: no such file")
        try:
            device = context.load_device(str(recording))
        except RuntimeError as err:
            raise SchemaError(f"cannot open the recording {recording}: {err}") from None
        sizes, what = None, f"recording {recording}"
    else:
        found = [d for d in context.query_devices() if d.get_info(rs.camera_info.serial_number) == serial]
        if not found:
            raise SchemaError(f"no RealSense with serial {serial} is connected (`obsbench find-cameras` lists them)")
        device, what = found[0], f"RealSense {serial}"
    try:
        color, depth = _stream_profiles(rs, device, sizes, what)
        extrinsics = depth.get_extrinsics_to(color)
        depth_to_color = np.eye(4)
        depth_to_color[:3, :3] = np.asarray(extrinsics.rotation, dtype=np.float64).reshape(3, 3).T  # column-major
        depth_to_color[:3, 3] = extrinsics.translation
        scale = device.first_depth_sensor().get_depth_scale()
        ci, di = color.get_intrinsics(), depth.get_intrinsics()
        return {
            "color_size": [ci.height, ci.width],
            "color_intrinsics": pinhole_K(ci).tolist(),
            "depth_size": [di.height, di.width],
            "depth_intrinsics": pinhole_K(di).tolist(),
            "depth_to_color": depth_to_color.tolist(),
            "depth_unit_mm": float(scale) * 1000.0,
        }
    except RuntimeError as err:  # librealsense's own: a camera busy or not permitted, a damaged recording
        raise SchemaError(f"cannot read the {what}'s streams: {err}") from None
    finally:
        if recording is not None:
            context.unload_device(str(recording))


def read_cam2world(path: str | Path) -> list[list[float]]:
    """A camera pose from `obsbench calibrate-cameras`' saved file (its `cam2world`) or a plain 4x4 JSON matrix."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"--cam2world {path}: no such file (`obsbench calibrate-cameras` writes it)")
    data = _read_json(path, "--cam2world")
    matrix = data.get("cam2world") if isinstance(data, dict) else data
    expected = f"--cam2world {path}: expected a 4x4 matrix of numbers or an object with 'cam2world' (4x4)"
    if np.asarray(matrix, dtype=object).shape != (4, 4):
        raise SchemaError(expected)
    try:
        return [[float(v) for v in row] for row in matrix]
    except (TypeError, ValueError):
        raise SchemaError(expected) from None


def attach_calibration(
    root: str | Path,
    camera: str,
    from_json: str | Path | None = None,
    from_recording: str | Path | None = None,
    serial: str | None = None,
    cam2world: str | Path | None = None,
    overwrite: bool = False,
) -> tuple[Path, CameraCalibration]:
    """Write camera `camera`'s calibration into the dataset at `root`; returns the file and what was written. The
    file's other cameras are kept; a file that cannot be read is replaced only with `overwrite`."""
    root = Path(root)
    features = _features(root)
    depth_feature = features.get(stock_depth_key(camera))
    if depth_feature is None or not is_stock_depth(stock_depth_key(camera), depth_feature):
        recorded = stock_depth_cameras(features)
        raise SchemaError(
            f"--camera {camera}: the dataset has no LeRobot depth feature {stock_depth_key(camera)} "
            f"(cameras recorded with depth: {', '.join(recorded) or 'none'}); record with the RealSense's "
            "use_depth: true."
        )
    try:
        stored_calibration(root)  # before a camera or recording is opened
    except CalibrationFileError as err:
        if not overwrite:
            raise SchemaError(
                f"{err.path}: {err.problem}; add --overwrite to replace the file (what it holds is lost), or delete it"
            ) from None
    if sum(source is not None for source in (from_json, from_recording, serial)) != 1:
        raise SchemaError("give exactly one of --from-json FILE, --from-recording FILE.bag, --serial SERIAL")
    sizes = [_size(features[image_key(camera)]) if image_key(camera) in features else _size(depth_feature)]
    sizes.append(_size(depth_feature))
    if from_json is not None:
        if not Path(from_json).is_file():
            raise MissingFileError(f"--from-json {from_json}: no such file")
        values = _read_json(Path(from_json), "--from-json")
        if not isinstance(values, dict):
            raise SchemaError(f"--from-json {from_json}: expected an object of CameraCalibration fields")
        source = f"file {from_json}"
    else:
        values = realsense_streams(from_recording, serial, sizes)
        source = f"recording {from_recording}" if from_recording is not None else f"RealSense {serial}"
    values = {"color_size": sizes[0], "depth_size": sizes[1], **values}
    if cam2world is not None:
        values["cam2world"] = read_cam2world(cam2world)
    if "cam2world" not in values:
        raise SchemaError("the camera pose is missing: --cam2world FILE (from `obsbench calibrate-cameras`)")
    info = depth_feature.get("info") or {}
    if depth_feature["dtype"] == "video":
        values.setdefault("depth_min_mm", float(info.get("video.depth_min", 0.0)) * 1000.0)
    values.setdefault("source", source)
    calibration = CameraCalibration.from_dict(values, where=f"calibration of camera {camera!r}")
    for name, recorded in (("color_size", sizes[0]), ("depth_size", sizes[1])):
        if list(getattr(calibration, name)) != list(recorded):
            raise SchemaError(
                f"calibration of camera {camera!r}: {name} {getattr(calibration, name)} but the dataset records "
                f"{recorded}; calibrate the camera at the resolution it recorded at."
            )
    return write_calibration(root, {camera: calibration}, replace_unreadable=overwrite), calibration
