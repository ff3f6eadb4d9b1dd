"""Several RGB-D cameras as one cloud: each extra camera's cam2world refined against the first's with Open3D's
coloured ICP, and fused clouds written as .ply for other tools.

ChArUco calibrates each camera on its own (`extrinsics.py`: ~0.3 mm / 0.03 degrees on renders); on a real table the
board's print, its flatness and each camera's depth bias leave the cameras' clouds a few millimetres apart where
they overlap, which doubles edges in the fused cloud. The refinement aligns the overlapping table and objects:
coloured ICP (Park, Zhou and Koltun 2017, as Open3D implements it) coarse to fine on voxel-sampled clouds brings
them together from the calibration's start, and a last point-to-plane ICP on the full-resolution clouds removes
what voxel averaging leaves (on renders, a 5 mm / 0.5 degree error came back to 0.07 mm / 0.003 degrees from each
of six random directions in an exploratory run; tests/robots/test_fusion.py holds it under 1 mm / 0.1 degrees). A
correction larger than a calibration can be off by, or too little overlap, is refused rather than applied: ICP
then converged somewhere wrong.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lerobot_obsbench.errors import MissingDependencyError, ObsBenchError
from lerobot_obsbench.robots.extrinsics import CalibrationError

INSTALL_HINT = "open3d is needed to refine and fuse cameras: pip install 'lerobot_policy_obsbench[realsense]'"
# Coloured ICP's coarse-to-fine voxel sizes (metres) and iterations, then point-to-plane on the full clouds
COARSE_TO_FINE = ((0.01, 50), (0.005, 50))
FINE_DISTANCE = 0.003  # metres: the last stage's largest point-to-point distance of a correspondence
NORMAL_RADIUS = 0.006  # metres, at least: the neighbourhood each normal is fitted to


class PointCloudWriteError(ObsBenchError, OSError):
    """Open3D could not write the fused point cloud (its writer picks the format from the file's suffix)."""


def import_open3d():
    try:
        import open3d
    except ImportError as error:
        raise MissingDependencyError(f"{INSTALL_HINT} ({error})") from error
    return open3d


@dataclass
class Alignment:
    """A world-frame correction (4, 4) to left-multiply a camera's cam2world by, and how well it fits."""

    correction: list[list[float]]
    translation_mm: float  # of the camera's position
    rotation_deg: float
    overlap: float  # share of the moving cloud's points with a partner in the reference (Open3D's fitness)
    rmse_mm: float  # of those partners' distances

    def as_dict(self) -> dict:
        return asdict(self)


def _cloud(o3d, xyz: np.ndarray, rgb: np.ndarray):
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(np.asarray(xyz, dtype=np.float64))
    cloud.colors = o3d.utility.Vector3dVector(np.asarray(rgb, dtype=np.float64) / 255.0)
    return cloud


def align_clouds(
    reference: tuple[np.ndarray, np.ndarray],
    moving: tuple[np.ndarray, np.ndarray],
    moving_cam2world: np.ndarray,
    max_translation_mm: float = 20.0,
    max_rotation_deg: float = 2.0,
    min_overlap: float = 0.3,
) -> Alignment:
    """The correction that brings `moving` (world xyz (N, 3), colours uint8 (N, 3)), seen by a camera at
    `moving_cam2world`, onto `reference`. CalibrationError when it moves the camera by more than
    `max_translation_mm` / `max_rotation_deg` or fewer than `min_overlap` of its points meet the reference."""
    o3d = import_open3d()
    source, target = _cloud(o3d, *moving), _cloud(o3d, *reference)
    if len(source.points) < 100 or len(target.points) < 100:
        raise CalibrationError(
            f"too few points to align ({len(source.points)} and {len(target.points)} in the workspace): widen the "
            "workspace or point both cameras at the table"
        )
    try:
        result = _icp(o3d, source, target)
    except RuntimeError as error:  # Open3D raises when no point has a partner within the distance
        raise CalibrationError(
            f"none of the camera's points meet the reference camera's ({str(error).strip()}): the cameras see too "
            "little of the same table and objects, or their calibrations are far apart; check both with "
            "`obsbench view`"
        ) from error
    correction = np.asarray(result.transformation)
    moved = correction @ np.asarray(moving_cam2world, dtype=np.float64)
    alignment = Alignment(
        correction=correction.tolist(),
        translation_mm=float(np.linalg.norm(moved[:3, 3] - moving_cam2world[:3, 3]) * 1000),
        rotation_deg=float(np.rad2deg(Rotation.from_matrix(correction[:3, :3]).magnitude())),
        overlap=float(result.fitness),
        rmse_mm=float(result.inlier_rmse * 1000),
    )
    if alignment.overlap < min_overlap:
        raise CalibrationError(
            f"only {alignment.overlap:.0%} of the camera's points meet the reference camera's (at least "
            f"{min_overlap:.0%} needed): the cameras see too little of the same table and objects, or their "
            "calibrations are far apart; check both with `obsbench view`"
        )
    if alignment.translation_mm > max_translation_mm or alignment.rotation_deg > max_rotation_deg:
        raise CalibrationError(
            f"the refinement would move the camera by {alignment.translation_mm:.1f} mm and "
            f"{alignment.rotation_deg:.2f} degrees (at most {max_translation_mm:g} mm and {max_rotation_deg:g} "
            "degrees): more than a ChArUco calibration is off by, so ICP likely matched the wrong surfaces; "
            "calibrate the camera again (obsbench calibrate-cameras)"
        )
    return alignment


def _icp(o3d, source, target):
    """Coloured ICP coarse to fine on voxel-sampled copies, then point-to-plane on the full clouds (the module
    docstring says why); Open3D's registration result."""
    registration = o3d.pipelines.registration
    transform = np.eye(4)
    for voxel, iterations in COARSE_TO_FINE:
        small_source, small_target = source.voxel_down_sample(voxel), target.voxel_down_sample(voxel)
        for cloud in (small_source, small_target):
            cloud.estimate_normals(
                o3d.geometry.KDTreeSearchParamHybrid(radius=max(2 * voxel, NORMAL_RADIUS), max_nn=30)
            )
        transform = registration.registration_colored_icp(
            small_source,
            small_target,
            1.5 * voxel,
            transform,
            registration.TransformationEstimationForColoredICP(),
            registration.ICPConvergenceCriteria(relative_fitness=1e-9, relative_rmse=1e-9, max_iteration=iterations),
        ).transformation
    for cloud in (source, target):
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS, max_nn=30))
    return registration.registration_icp(
        source,
        target,
        FINE_DISTANCE,
        transform,
        registration.TransformationEstimationPointToPlane(),
        registration.ICPConvergenceCriteria(relative_fitness=1e-9, relative_rmse=1e-9, max_iteration=100),
    )


def write_ply(path: str | Path, xyz: np.ndarray, rgb: np.ndarray) -> Path:
    """A coloured cloud (xyz (N, 3) metres, rgb (N, 3) uint8) as a binary .ply through Open3D."""
    o3d = import_open3d()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not o3d.io.write_point_cloud(str(path), _cloud(o3d, xyz, rgb)):
        raise PointCloudWriteError(f"Open3D could not write {path}; give a path ending in .ply")
    return path
