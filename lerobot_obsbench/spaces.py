"""ObservationAdapter: stored sensor tensors -> the inputs of one observation space.

    rgb        -> images (B, n_cam, 3, H, W)   ImageNet-normalised colour
    depth      -> images (B, n_cam, 1, H, W)   metric depth clipped to `depth_clip` and scaled to [-1, 1]
                                               (`depth_normalization="official"`: (metres - 0.5) / 0.5)
    rgbd       -> images (B, n_cam, 4, H, W)   rgb ‖ depth, channel-stacked
    pointmap   -> images (B, n_cam, 6, H, W)   rgb ‖ xyz (metres, chosen frame; 0 where depth is invalid;
                                               official normalization: (xyz - 0.5) / 0.5)
    pointcloud -> PointCloud(xyz (B, N, 3), features (B, N, C), mask (B, N)): all cameras fused, cropped to the
                  workspace box (world frame, which also drops the ground; in training optionally jittered by
                  `workspace_jitter` per bound, as the official real-robot code), moved to the chosen frame, one point
                  per voxel (random in training; with `point_pipeline="official"` also in evaluation, and
                  points shuffled in training); features are rgb in [-1, 1] and/or xyz in metres (or, with
                  `point_normalization="box"`, in [-1, 1] over the workspace box, as DP3 scales its clouds).
                  A frame with no valid point inside the box (a depth dropout, a hand over the camera) becomes
                  the empty-cloud point: one point at the box centre with colour 0, so training and rollouts
                  go on; such frames are counted and logged, and training stops when more than half of its
                  first 64+ frames are empty (bad units or extrinsics, not dropouts).
    rgb+pointcloud -> (rgb's images, pointcloud's PointCloud): a fused space gives each part's input.
    none       -> (B, 0): the blind control sees nothing (the batch size comes from observation.state).
    state      -> (B, 7 * O): the oracle control reads the simulator's object poses (observation.privileged_state).

The same module runs on dataset batches in training and on env observations in evaluation, so an observation
space is never baked into stored data. In training it also runs the policy's augmentation recipe
(`augmentations.py`): colour transforms on each camera's colour before normalisation, image transforms on the
space's images, point transforms on the world-frame cloud before the crop box. `CalibratedDepth` runs before it
on datasets recorded by LeRobot itself.
"""

from __future__ import annotations

import logging

import torch
from torch import Tensor, nn

from lerobot_obsbench import geometry
from lerobot_obsbench.augmentations import Augmenter, parse_augment
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.schema import (
    BLIND_SPACES,
    CONTROL_SPACES,
    DEPTH_NORMALIZATIONS,
    FRAMES,
    FUSED_SPACES,
    ORACLE_SPACES,
    POINT_FEATURES,
    POINT_NORMALIZATIONS,
    POINT_PIPELINES,
    PRIVILEGED_STATE_KEY,
    STATE_KEY,
    PointCloud,
    SchemaError,
    cam2world_key,
    check_choice,
    check_obs_space,
    depth_key,
    has_positions,
    image_key,
    intrinsics_key,
    stock_depth_key,
)

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
DEFAULT_WORKSPACE = (-1.0, 1.0, -1.0, 1.0, 0.005, 1.0)
# cam2world must be rigid: |R R^T - I|, |det R - 1| and the last row's deviation from 0 0 0 1 below this.
RIGID_TOLERANCE = 1e-3
# Training stops when more than this fraction of its frames had an empty cloud, once it has seen this many.
MAX_EMPTY_FRACTION = 0.5
EMPTY_CHECK_FRAMES = 64

logger = logging.getLogger(__name__)


def check_geometry(workspace, voxel_size: float, depth_clip) -> None:
    """Workspace box, voxel edge and depth range, checked where they are configured and where they are used."""
    if len(workspace) != 6 or any(workspace[2 * i] >= workspace[2 * i + 1] for i in range(3)):
        raise ConfigError(f"workspace must be (xmin, xmax, ymin, ymax, zmin, zmax) with min < max; got {workspace}")
    if voxel_size <= 0:
        raise ConfigError(f"voxel_size must be > 0 metres; got {voxel_size}")
    if len(depth_clip) != 2 or not depth_clip[0] < depth_clip[1]:
        raise ConfigError(f"depth_clip must be (near, far) in metres with near < far; got {depth_clip}")


class ObservationAdapter(nn.Module):
    def __init__(
        self,
        obs_space: str,
        cameras: list[str],
        frame: str = "world",
        point_features: str = "rgb+xyz",
        workspace: tuple[float, ...] = DEFAULT_WORKSPACE,
        voxel_size: float = 0.005,
        depth_clip: tuple[float, float] = (0.0, 2.0),
        depth_normalization: str = "clip",
        point_pipeline: str = "plugin",
        workspace_jitter: float = 0.0,
        point_normalization: str = "metres",
        augment: str = "",
    ):
        super().__init__()
        if not cameras and obs_space not in CONTROL_SPACES:
            raise SchemaError(f"ObservationAdapter for obs_space={obs_space!r} needs at least one camera name.")
        check_geometry(workspace, voxel_size, depth_clip)
        self.obs_space = check_obs_space(obs_space)
        self.cameras = list(cameras)
        self.frame = check_choice("frame", frame, FRAMES)
        self.point_features = check_choice("point_features", point_features, POINT_FEATURES)
        self.workspace = tuple(float(w) for w in workspace)
        self.voxel_size = float(voxel_size)
        self.depth_clip = (float(depth_clip[0]), float(depth_clip[1]))
        self.depth_normalization = check_choice("depth_normalization", depth_normalization, DEPTH_NORMALIZATIONS)
        self.official_points = check_choice("point_pipeline", point_pipeline, POINT_PIPELINES) == "official"
        self.box_scaled = check_choice("point_normalization", point_normalization, POINT_NORMALIZATIONS) == "box"
        if self.box_scaled and self.frame != "world":
            raise ConfigError(f"point_normalization='box' scales world coordinates by the crop box; frame={frame!r}")
        if workspace_jitter < 0:
            raise ConfigError(f"workspace_jitter must be >= 0 metres; got {workspace_jitter}")
        self.workspace_jitter = float(workspace_jitter)
        self.augment = Augmenter(parse_augment(augment, self.obs_space))
        self.frames_seen, self.frames_empty, self._next_warning = 0, 0, 1  # empty-cloud bookkeeping
        self.register_buffer("rgb_mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    @property
    def needs_ee_pose(self) -> bool:
        return self.frame == "ee" and has_positions(self.obs_space)

    # ---- checked accessors: a clear error names the key and the fix ------------------------------------

    def _rgb(self, batch: dict, cam: str) -> Tensor:
        key = image_key(cam)
        x = _require(batch, key)
        if x.dim() != 4 or x.shape[1] != 3 or not x.is_floating_point():
            raise SchemaError(f"{key}: expected a float (B, 3, H, W) image in [0, 1], got {x.dtype} {tuple(x.shape)}.")
        return x

    def _depth_m(self, batch: dict, cam: str) -> Tensor:
        key = depth_key(cam)
        d = _require(batch, key)
        if d.is_floating_point() or d.dtype == torch.bool:
            raise SchemaError(
                f"{key}: depth must be integer millimetres (uint16, 0 = invalid), got {d.dtype}. "
                "Store it as (depth_m * 1000).round().astype(uint16)."
            )
        if d.dim() != 4 or d.shape[-1] != 1:
            raise SchemaError(f"{key}: expected shape (B, H, W, 1) (channel-last, one channel), got {tuple(d.shape)}.")
        return d[..., 0].float() / 1000.0

    def _camera(self, batch: dict, cam: str) -> tuple[Tensor, Tensor]:
        k_key, t_key = intrinsics_key(cam), cam2world_key(cam)
        K, cam2world = _require(batch, k_key).float(), _require(batch, t_key).float()
        if K.shape[-2:] != (3, 3):
            raise SchemaError(f"{k_key}: expected (B, 3, 3) OpenCV intrinsics, got {tuple(K.shape)}.")
        if cam2world.shape[-2:] != (4, 4):
            raise SchemaError(f"{t_key}: expected (B, 4, 4) camera->world transforms, got {tuple(cam2world.shape)}.")
        if not bool(torch.isfinite(K).all()) or not bool((K[:, 0, 0] > 0).all() and (K[:, 1, 1] > 0).all()):
            raise SchemaError(f"{k_key}: intrinsics must be finite with fx, fy > 0; fix the recorded camera K.")
        if not bool(torch.isfinite(cam2world).all()):
            raise SchemaError(f"{t_key}: camera pose contains non-finite values; fix the recorded extrinsics.")
        error = geometry.rigidity_error(cam2world)
        if float(error.max()) > RIGID_TOLERANCE:
            raise SchemaError(
                f"{t_key}: not a rigid transform (rotation not orthonormal with det +1, or last row not 0 0 0 1; "
                f"largest deviation {float(error.max()):.3g}), so points would be scaled or sheared. Fix the "
                "recorded extrinsics (`obsbench validate` finds the episodes)."
            )
        return K, cam2world

    # ---- spaces ------------------------------------------------------------------------------------------

    def _scaled_depth(self, depth_m: Tensor) -> Tensor:
        if self.depth_normalization == "official":
            return (depth_m - 0.5) / 0.5
        near, far = self.depth_clip
        return (depth_m.clamp(near, far) - near) / (far - near) * 2 - 1

    def _frame_transform(self, first_cam: str, batch: dict, ee_pose: Tensor | None) -> Tensor | None:
        """world -> chosen frame transform (B, 4, 4), or None for the world frame."""
        if self.frame == "world":
            return None
        if self.frame == "camera":
            return geometry.invert_transform(self._camera(batch, first_cam)[1])
        if ee_pose is None:
            raise SchemaError("frame='ee' needs the end-effector pose (the last 7 values of observation.state).")
        return geometry.invert_transform(ee_pose)

    def _world_points(self, batch: dict, cam: str) -> tuple[Tensor, Tensor]:
        depth_m = self._depth_m(batch, cam)
        K, cam2world = self._camera(batch, cam)
        points = geometry.transform_points(geometry.unproject_depth(depth_m, K), cam2world)
        return points, depth_m > 0

    def forward(self, batch: dict, ee_pose: Tensor | None = None) -> Tensor | PointCloud | tuple:
        if self.obs_space in BLIND_SPACES:
            state = _require(batch, STATE_KEY)
            return state.new_zeros(state.shape[0], 0)
        if self.obs_space in ORACLE_SPACES:
            return _require(batch, PRIVILEGED_STATE_KEY).float()
        if self.obs_space in FUSED_SPACES:
            return tuple(self._space_input(part, batch, ee_pose) for part in FUSED_SPACES[self.obs_space])
        return self._space_input(self.obs_space, batch, ee_pose)

    def _space_input(self, space: str, batch: dict, ee_pose: Tensor | None) -> Tensor | PointCloud:
        if space == "pointcloud":
            return self._pointcloud(batch, ee_pose)
        to_frame = self._frame_transform(self.cameras[0], batch, ee_pose) if space == "pointmap" else None
        per_camera = []
        for cam in self.cameras:
            channels = []
            if space in ("rgb", "rgbd", "pointmap"):
                channels.append((self.augment.colour(self._rgb(batch, cam)) - self.rgb_mean) / self.rgb_std)
            if space in ("depth", "rgbd"):
                channels.append(self._scaled_depth(self._depth_m(batch, cam))[:, None])
            if space == "pointmap":
                points, valid = self._world_points(batch, cam)
                if to_frame is not None:
                    points = geometry.transform_points(points, to_frame)
                points = points * valid[..., None]
                if self.depth_normalization == "official":
                    points = (points - 0.5) / 0.5
                channels.append(points.permute(0, 3, 1, 2))
            per_camera.append(torch.cat(channels, dim=1))
        return self.augment.image(torch.stack(per_camera, dim=1))

    def _pointcloud(self, batch: dict, ee_pose: Tensor | None) -> PointCloud:
        jitter = self.workspace_jitter if self.training else 0.0
        # only the pixels that can land in the box (widened by the jitter and by how far the point augmentations
        # can move a point into it) are unprojected: the same points
        margin = jitter + self.augment.point_reach(self.workspace)
        widest = [bound + (margin if i % 2 else -margin) for i, bound in enumerate(self.workspace)]
        xyz, rgb, valid = [], [], []
        for cam in self.cameras:
            depth_m = self._depth_m(batch, cam)
            colour = self._rgb(batch, cam)
            if colour.shape[-2:] != depth_m.shape[1:]:
                raise SchemaError(
                    f"{image_key(cam)} is {tuple(colour.shape[-2:])} but {depth_key(cam)} is "
                    f"{tuple(depth_m.shape[1:])}: point clouds need depth aligned to colour at the same resolution."
                )
            K, cam2world = self._camera(batch, cam)
            window = geometry.box_pixel_window(K, cam2world, widest, *depth_m.shape[1:])
            if window is not None:
                v0, v1, u0, u1 = window
                depth_m, colour = depth_m[:, v0:v1, u0:u1], colour[..., v0:v1, u0:u1]
                K = geometry.shift_intrinsics(K, v0, u0)
            points = geometry.transform_points(geometry.unproject_depth(depth_m, K), cam2world)
            xyz.append(points.flatten(1, 2))
            rgb.append(colour.permute(0, 2, 3, 1).flatten(1, 2) * 2 - 1)
            valid.append((depth_m > 0).flatten(1))
        xyz, rgb, valid = torch.cat(xyz, 1), torch.cat(rgb, 1), torch.cat(valid, 1)
        box = torch.tensor(self.workspace, dtype=xyz.dtype, device=xyz.device)
        if jitter > 0:  # each bound moves by up to ±jitter, per sample
            box = box + (torch.rand(len(xyz), 6, device=xyz.device, dtype=xyz.dtype) * 2 - 1) * jitter
        xyz, valid = self.augment.points(xyz, valid, box)
        valid = geometry.crop_mask(xyz, valid, box)
        empty = ~valid.any(dim=1)
        self._count_empty(int(empty.sum()), len(empty))
        if bool(empty.any()):  # the empty-cloud point: one point at the box centre, colour 0 (module docstring)
            centre = (box.reshape(-1, 3, 2).mean(-1)).expand(len(xyz), 3)
            xyz[empty, 0], rgb[empty, 0], valid[empty, 0] = centre[empty], 0.0, True
        xyz, rgb, valid = geometry.pack(valid, xyz, rgb)
        to_frame = self._frame_transform(self.cameras[0], batch, ee_pose)
        if to_frame is not None:
            xyz = geometry.transform_points(xyz, to_frame)
        keep = geometry.voxel_sample(xyz, valid, self.voxel_size, random=self.training or self.official_points)
        xyz, rgb, mask = geometry.pack(keep, xyz, rgb)
        if self.training and self.official_points:  # FPS then starts from a random point, as in the official code
            xyz, rgb, mask = geometry.shuffle(mask, xyz, rgb)
        scaled = xyz
        if self.box_scaled:  # the nominal box, also when jittered: the same point gets the same features
            bounds = torch.tensor(self.workspace, dtype=xyz.dtype, device=xyz.device).reshape(3, 2)
            scaled = (xyz - bounds.mean(-1)) / ((bounds[:, 1] - bounds[:, 0]) / 2)
        if self.point_features == "rgb+xyz":
            feats = torch.cat([rgb, scaled], -1)
        else:
            feats = scaled if self.point_features == "xyz" else rgb
        return PointCloud(xyz=xyz * mask[..., None], features=feats * mask[..., None], mask=mask)

    def _count_empty(self, empty: int, frames: int) -> None:
        """Count frames with no point in the workspace: warn as they come, and stop a training whose data is
        mostly such frames (a unit or extrinsics error, not a few dropouts) after its first batches."""
        self.frames_seen += frames
        self.frames_empty += empty
        if not empty:
            return
        if self.frames_empty >= self._next_warning:
            self._next_warning = 2 * self.frames_empty
            logger.warning(
                f"{self.frames_empty} of {self.frames_seen} frames so far had no valid point inside the workspace "
                f"{self.workspace} (depth dropout, occlusion): each was given the empty-cloud point"
            )
        fraction = self.frames_empty / self.frames_seen
        if self.training and self.frames_seen >= EMPTY_CHECK_FRAMES and fraction > MAX_EMPTY_FRACTION:
            raise SchemaError(
                f"{self.frames_empty} of the first {self.frames_seen} training frames have no valid point inside "
                f"the workspace {self.workspace} in {', '.join(depth_key(c) for c in self.cameras)}: the data, not a "
                "dropout. Check that depth is in millimetres, that cam2world maps camera -> world, and "
                "--policy.workspace (`obsbench validate --root DATASET` scans every frame)."
            )


def _require(batch: dict, key: str) -> Tensor:
    if key not in batch:
        raise SchemaError(
            f"Missing {key!r} in the observation batch (it has "
            f"{sorted(k for k in batch if k.startswith('observation'))}). "
            "The chosen obs_space/cameras need it: record it in the dataset / env observation, or change "
            "--policy.obs_space / --policy.cameras."
        )
    return batch[key]


class CalibratedDepth(nn.Module):
    """LeRobot 0.6's own depth recordings -> the schema's sensor keys, with the cameras' attached calibration
    (`camera_calibration.CameraCalibration` fields per camera, from the policy config).

    `observation.images.<cam>_depth` (float stored units, (..., 1, Hd, Wd), in the depth camera's pixels) becomes
    `observation.depth.<cam>`: holes (stored values at or below `depth_min_mm`, where LeRobot's video codec puts
    them) set to 0, units to millimetres, registered into the colour camera with z in the colour frame
    (`geometry.register_depth`), rounded to integer mm (..., H, W, 1); `observation.intrinsics.<cam>` and
    `observation.cam2world.<cam>` are the colour camera's K and pose, repeated over the leading dimensions.
    Batches without the stock keys (the plugin's own datasets, simulators) pass through unchanged."""

    def __init__(self, calibration: dict[str, dict]):
        super().__init__()
        self.cameras = sorted(calibration)
        self.color_sizes, self.units, self.holes = {}, {}, {}
        for cam in self.cameras:
            entry = calibration[cam]
            self.color_sizes[cam] = tuple(entry["color_size"])
            self.units[cam] = float(entry.get("depth_unit_mm", 1.0))
            self.holes[cam] = float(entry.get("depth_min_mm", 0.0))
            for name in ("depth_intrinsics", "depth_to_color", "color_intrinsics", "cam2world"):
                self.register_buffer(f"{cam}__{name}", torch.tensor(entry[name], dtype=torch.float32), persistent=False)

    def forward(self, batch: dict) -> dict:
        if not any(stock_depth_key(cam) in batch for cam in self.cameras):
            return batch
        out = dict(batch)
        for cam in self.cameras:
            raw = batch.get(stock_depth_key(cam))
            if raw is None:
                continue
            if raw.dim() < 3 or raw.shape[-3] != 1:
                raise SchemaError(
                    f"{stock_depth_key(cam)}: expected depth maps (..., 1, H, W), got {tuple(raw.shape)}."
                )
            lead, (hd, wd) = raw.shape[:-3], raw.shape[-2:]
            stored = raw.reshape(-1, hd, wd).float()
            # half a unit above the codec's hole value, which comes back as depth_min up to float rounding
            limit = self.holes[cam] + 0.5 if self.holes[cam] > 0 else 0.0
            metres = torch.where(stored > limit, stored * (self.units[cam] / 1000.0), torch.zeros_like(stored))
            n = metres.shape[0]

            def repeat(name: str, cam: str = cam, n: int = n) -> Tensor:
                value = getattr(self, f"{cam}__{name}")
                return value.expand(n, *value.shape)

            registered = geometry.register_depth(
                metres,
                repeat("depth_intrinsics"),
                repeat("depth_to_color"),
                repeat("color_intrinsics"),
                self.color_sizes[cam],
            )
            height, width = self.color_sizes[cam]
            out[depth_key(cam)] = (registered * 1000.0).round().to(torch.int32).reshape(*lead, height, width, 1)
            out[intrinsics_key(cam)] = repeat("color_intrinsics").reshape(*lead, 3, 3)
            out[cam2world_key(cam)] = repeat("cam2world").reshape(*lead, 4, 4)
        return out
