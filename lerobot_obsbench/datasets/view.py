"""See what the policy sees (`obsbench view`): for a dataset frame (simulated or real) or a live RGB-D camera, the
colour and depth images, each camera's pose and frustum, the fused point cloud in the world frame before and
after the workspace crop and voxel sampling, the workspace box and the robot-base (world) axes, in rerun (what
LeRobot's dataset viewer uses). Setting a crop box on a real table is guesswork without it.

With a display the viewer opens; without one (or with --out) the recording is saved to an .rrd file to open with
`rerun FILE.rrd` elsewhere.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from lerobot_obsbench.camera_calibration import dataset_calibration
from lerobot_obsbench.errors import UsageError
from lerobot_obsbench.schema import (
    ATTACH_CALIBRATION_HINT,
    SchemaError,
    cam2world_key,
    cameras_in,
    depth_key,
    image_key,
    intrinsics_key,
    stock_depth_cameras,
    stock_depth_key,
)
from lerobot_obsbench.spaces import AdapterConfig, CalibratedDepth, ObservationAdapter

AXIS_COLOURS = [[230, 40, 40], [40, 200, 40], [40, 80, 230]]


def dataset_frame(root: str | Path, index: int, repo_id: str = "local/dataset") -> dict[str, np.ndarray]:
    """One frame of a LeRobotDataset as schema-keyed numpy arrays (colour HWC uint8). LeRobot's own depth maps
    come out as the schema's depth, intrinsics and cam2world of each camera whose calibration is attached, as the
    policies register them (`spaces.CalibratedDepth`); an uncalibrated camera's depth map is left out."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(repo_id, root=root)
    if not 0 <= index < len(dataset):
        raise UsageError(f"--frame {index} is outside the dataset's {len(dataset)} frames (0..{len(dataset) - 1})")
    item = {key: value for key, value in dataset[index].items() if isinstance(value, torch.Tensor)}
    stock = stock_depth_cameras(dataset.meta.features)
    if stock:
        registered = CalibratedDepth(dataset_calibration(dataset.meta))(
            {key: value[None] for key, value in item.items()}
        )
        stock_keys = {stock_depth_key(cam) for cam in stock}
        item = {key: value[0] for key, value in registered.items() if key not in stock_keys}
        if not any(key.startswith(depth_key("")) for key in item):
            raise SchemaError(
                f"{root}: LeRobot's own depth of camera {stock[0]!r} has no calibration, so it has no points to show; "
                + ATTACH_CALIBRATION_HINT.format(cam=stock[0])
            )
    frame = {}
    for key, value in item.items():
        value = value.numpy()
        if key.startswith(image_key("")) and value.ndim == 3 and value.shape[0] == 3:
            value = (np.clip(value.transpose(1, 2, 0), 0, 1) * 255).round().astype(np.uint8)
        frame[key] = value
    return frame


def to_batch(frame: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
    batch = {}
    for key, value in frame.items():
        tensor = torch.from_numpy(np.ascontiguousarray(value))
        if key.startswith(image_key("")):
            tensor = tensor.permute(2, 0, 1).float() / 255.0
        batch[key] = tensor.unsqueeze(0)
    return batch


def coloured_points(
    batch: Mapping[str, torch.Tensor], cameras: list[str], workspace, voxel_size: float
) -> tuple[np.ndarray, np.ndarray]:
    """The fused world points of `cameras` inside `workspace` after voxel sampling, as the policy's point-cloud
    adapter makes them: xyz (N, 3) and rgb uint8 (N, 3)."""
    config = AdapterConfig("pointcloud", cameras, workspace=workspace, voxel_size=voxel_size)
    cloud = ObservationAdapter(config).eval()(batch)
    mask = cloud.mask[0]
    rgb = ((cloud.features[0][mask][:, :3] + 1) * 127.5).round().clamp(0, 255).to(torch.uint8)
    return cloud.xyz[0][mask].numpy(), rgb.numpy()


def clouds(frame: Mapping[str, np.ndarray], cameras: list[str], workspace, voxel_size: float):
    """(uncropped world points (N, 3), after crop + voxel (xyz (M, 3), rgb uint8 (M, 3))) of the fused cameras."""
    batch = to_batch(frame)
    everything, _ = coloured_points(batch, cameras, (-1e3, 1e3, -1e3, 1e3, -1e3, 1e3), 1e-4)
    return (everything, *coloured_points(batch, cameras, workspace, voxel_size))


def camera_cloud(frame: Mapping[str, np.ndarray], camera: str, workspace) -> tuple[np.ndarray, np.ndarray]:
    """One camera's world points inside `workspace`, every pixel (no voxel sampling): xyz (N, 3), rgb uint8 (N, 3)."""
    return coloured_points(to_batch(frame), [camera], workspace, 1e-4)


def log_frame(
    frame: Mapping[str, np.ndarray],
    workspace,
    voxel_size: float = 0.005,
    cameras: list[str] | None = None,
    out: str | Path | None = None,
    spawn: bool | None = None,
    ply: str | Path | None = None,
) -> dict:
    """Log one schema frame to rerun; returns what was logged (point counts, cameras, the .rrd path). `ply`: also
    write the policy's fused cloud (cropped, voxel-sampled, coloured) there, for other tools."""
    import rerun as rr

    with_depth = [c for c in cameras_in(frame) if depth_key(c) in frame and cam2world_key(c) in frame]
    unknown = sorted(set(cameras or []) - set(with_depth))
    if unknown:
        raise UsageError(f"--cameras {' '.join(unknown)}: not a camera with depth here; the frame's are {with_depth}")
    cameras = cameras or with_depth
    if not cameras:
        raise SchemaError(
            "the frame has no camera with depth, intrinsics and cam2world (schema keys observation.depth.<cam>, "
            "observation.intrinsics.<cam>, observation.cam2world.<cam>): nothing to fuse."
        )
    rr.init("obsbench_view", spawn=False)
    display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if out is None and not (display if spawn is None else spawn):
        out = Path("obsbench_view.rrd")
    if out is not None:
        rr.save(str(out))
    else:
        rr.spawn()
    rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rr.log("world/robot_base", rr.Arrows3D(origins=np.zeros((3, 3)), vectors=np.eye(3) * 0.1, colors=AXIS_COLOURS))
    box = np.asarray(workspace, dtype=float).reshape(3, 2)
    rr.log("world/workspace", rr.Boxes3D(centers=[box.mean(axis=1)], half_sizes=[(box[:, 1] - box[:, 0]) / 2]))
    for cam in cameras:
        pose = np.asarray(frame[cam2world_key(cam)], dtype=float)
        K = np.asarray(frame[intrinsics_key(cam)], dtype=float)
        depth = np.asarray(frame[depth_key(cam)])[..., 0]
        rr.log(f"world/{cam}", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        rr.log(f"world/{cam}/image", rr.Pinhole(image_from_camera=K, resolution=[depth.shape[1], depth.shape[0]]))
        if image_key(cam) in frame:
            rr.log(f"world/{cam}/image/rgb", rr.Image(frame[image_key(cam)]))
        rr.log(f"world/{cam}/image/depth", rr.DepthImage(depth, meter=1000.0))
    everything, xyz, rgb = clouds(frame, cameras, workspace, voxel_size)
    rr.log("world/points_all", rr.Points3D(everything, colors=[[140, 140, 140]], radii=0.001))
    rr.log("world/points_policy", rr.Points3D(xyz, colors=rgb, radii=0.003))
    rr.disconnect()
    if ply is not None:
        from lerobot_obsbench.robots.fusion import write_ply

        write_ply(ply, xyz, rgb)
    return {
        "cameras": cameras,
        "points_all": len(everything),
        "points_policy": len(xyz),
        "rrd": str(out) if out else None,
        "ply": str(ply) if ply else None,
    }


def crop_box(workspace: tuple[float, ...] | None, preset: str | None) -> tuple[float, ...]:
    """The crop box `view` and `refine-cameras` use: the one given, else the preset's, else the default."""
    from lerobot_obsbench.presets import preset_overrides
    from lerobot_obsbench.schema import POLICY_TYPES
    from lerobot_obsbench.spaces import DEFAULT_WORKSPACE

    if workspace is not None:
        return tuple(workspace)
    if preset:
        from_preset = preset_overrides(preset, POLICY_TYPES[0], "pointcloud").get("workspace")
        if from_preset is not None:
            return tuple(from_preset)
    return DEFAULT_WORKSPACE


def live_camera_configs(
    serials: list[str], recordings: list[str], width: int, height: int, fps: int, downsample: int
) -> dict:
    """RealSense configs of live cameras (by serial) and recordings (.bag), named camera_0, camera_1, ... in that
    order; a recording needs no auto-exposure warm-up."""
    from lerobot_obsbench.errors import UsageError
    from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig

    if not serials and not recordings:
        raise UsageError("give --serial SERIAL ... or --playback FILE.bag ... for the cameras")
    sources = [("serial_number", s) for s in serials] + [("playback_file", f) for f in recordings]
    return {
        f"camera_{i}": RealSenseRGBDCameraConfig(
            **{field: value},
            width=width,
            height=height,
            fps=fps,
            downsample=downsample,
            warmup_s=0.0 if field == "playback_file" else 1.0,
        )
        for i, (field, value) in enumerate(sources)
    }


def live_frame(
    camera_configs: dict, extrinsics_dir: str | Path | None = None
) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """One frameset of live (or played-back) RGB-D cameras with their saved extrinsics, as schema keys; and each
    camera's serial number (what its extrinsics are saved under)."""
    from lerobot_obsbench.robots.frames import schema_key
    from lerobot_obsbench.robots.scene_cameras import SceneCameras

    scene = SceneCameras(camera_configs, extrinsics_dir)
    scene.connect()
    try:
        observation = scene.read()
        serials = {name: camera.serial_number for name, camera in scene.cameras.items()}
    finally:
        scene.disconnect()
    return {schema_key(key): value for key, value in observation.items()}, serials
