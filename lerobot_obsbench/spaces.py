"""ObservationAdapter: stored sensor tensors -> the inputs of one observation space.

    rgb        -> images (B, n_cam, 3, H, W)   ImageNet-normalised colour
    depth      -> images (B, n_cam, 1, H, W)   metric depth clipped to `depth_clip` and scaled to [-1, 1]
                                               (`depth_normalization="official"`: (metres - 0.5) / 0.5)
    rgbd       -> images (B, n_cam, 4, H, W)   rgb ‖ depth, channel-stacked
    pointmap   -> images (B, n_cam, 6, H, W)   rgb ‖ xyz (metres, chosen frame; 0 where depth is invalid;
                                               official normalization: (xyz - 0.5) / 0.5)
    pointcloud -> PointCloud(xyz (B, N, 3), features (B, N, C), mask (B, N)), in stages: all cameras fused
                  (`fuse_cameras`), cropped to the workspace box (`crop_to_workspace`; world frame, which also
                  drops the ground; in training optionally jittered by `workspace_jitter` per bound, as the
                  official real-robot code), moved to the chosen frame, one point per voxel (`sample_points`;
                  random in training; with `point_pipeline="official"` also in evaluation, and points shuffled
                  in training); features (`point_features`) are rgb in [-1, 1] and/or xyz in metres (or, with
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
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from lerobot_obsbench import geometry
from lerobot_obsbench.augmentations import Augmenter, parse_augment
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.numeric import check_number, check_numbers
from lerobot_obsbench.schema import (
    DEFAULT_POINT_FEATURES,
    DEPTH_NORMALIZATIONS,
    FRAMES,
    POINT_FEATURES,
    POINT_NORMALIZATIONS,
    POINT_PIPELINES,
    PRIVILEGED_STATE_KEY,
    STATE_KEY,
    PointCloud,
    SchemaError,
    Space,
    available_spaces,
    cam2world_key,
    check_choice,
    check_obs_space,
    depth_key,
    has_positions,
    image_key,
    intrinsics_key,
    is_control,
    points_carry_colour,
    reads_points,
    space_info,
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
    """Workspace box, voxel edge and depth range (metres)."""
    box = check_numbers("workspace", workspace, length=6)
    if any(box[2 * i] >= box[2 * i + 1] for i in range(3)):
        raise ConfigError(f"workspace must be (xmin, xmax, ymin, ymax, zmin, zmax) with min < max; got {workspace}")
    check_number("voxel_size", voxel_size, above=0)
    near, far = check_numbers("depth_clip", depth_clip, length=2, minimum=0)
    if not near < far:
        raise ConfigError(f"depth_clip must be (near, far) in metres with near < far; got {depth_clip}")


@dataclass(frozen=True)
class AdapterConfig:
    """The adapter's settings: the policy config's fields of the same names (`ObservationConfig.adapter_config()`
    builds a policy's). Every value is checked here, once, against the space, so a policy config fails on them
    when it is validated; lists become tuples and numbers floats."""

    obs_space: str
    cameras: tuple[str, ...] = ()
    frame: str = "world"
    point_features: str = DEFAULT_POINT_FEATURES
    workspace: tuple[float, ...] = DEFAULT_WORKSPACE
    voxel_size: float = 0.005
    depth_clip: tuple[float, float] = (0.0, 2.0)
    depth_normalization: str = "clip"
    point_pipeline: str = "plugin"
    workspace_jitter: float = 0.0
    point_normalization: str = "metres"
    augment: str = ""

    def __post_init__(self):
        check_obs_space(self.obs_space)
        check_geometry(self.workspace, self.voxel_size, self.depth_clip)
        check_choice("frame", self.frame, FRAMES)
        check_choice("point_features", self.point_features, POINT_FEATURES)
        check_choice("depth_normalization", self.depth_normalization, DEPTH_NORMALIZATIONS)
        check_choice("point_pipeline", self.point_pipeline, POINT_PIPELINES)
        check_choice("point_normalization", self.point_normalization, POINT_NORMALIZATIONS)
        check_number("workspace_jitter", self.workspace_jitter, minimum=0)
        self.augmentations()  # each name exists and applies to the space
        self._check_space()
        normalised = {
            "cameras": tuple(self.cameras),
            "workspace": tuple(float(w) for w in self.workspace),
            "voxel_size": float(self.voxel_size),
            "depth_clip": (float(self.depth_clip[0]), float(self.depth_clip[1])),
            "workspace_jitter": float(self.workspace_jitter),
        }
        for name, value in normalised.items():
            object.__setattr__(self, name, value)  # frozen: set once, here

    def _check_space(self) -> None:
        """Settings only some spaces have: refuse them elsewhere instead of ignoring them."""
        if self.depth_normalization == "official" and not space_info(self.obs_space).depth:
            raise ConfigError(
                f"depth_normalization={self.depth_normalization!r} scales depth / xyz images; obs_space="
                f"{self.obs_space!r} has none (spaces that do: {', '.join(available_spaces(lambda s: s.depth))})"
            )
        if self.workspace_jitter and not reads_points(self.obs_space):
            raise ConfigError(
                f"workspace_jitter={self.workspace_jitter} jitters the point-cloud crop; obs_space={self.obs_space!r} "
                "crops nothing (use obs_space='pointcloud' or leave workspace_jitter=0)"
            )
        if self.point_normalization == "box" and (not reads_points(self.obs_space) or self.frame != "world"):
            raise ConfigError(
                f"point_normalization={self.point_normalization!r} scales world-frame point clouds by the crop box; "
                f"obs_space={self.obs_space!r} with frame={self.frame!r} has none (use obs_space='pointcloud' with "
                "frame='world', or leave point_normalization='metres')"
            )
        if self.frame != "world" and not has_positions(self.obs_space):
            raise ConfigError(
                f"frame={self.frame!r} changes point coordinates; obs_space={self.obs_space!r} has none "
                "(use pointcloud or pointmap, or leave frame='world')"
            )

    def augmentations(self) -> tuple[str, ...]:
        """The names of the `augment` recipe, each checked to apply to the space."""
        return parse_augment(self.augment, self.obs_space)


class ObservationAdapter(nn.Module):
    """Sensor batch -> the inputs of `config.obs_space` (module docstring); a point cloud's stages are methods that
    each run alone (`fuse_cameras`, `crop_to_workspace`, `sample_points`, `point_features`)."""

    def __init__(self, config: AdapterConfig):
        super().__init__()
        if not config.cameras and not is_control(config.obs_space):
            raise SchemaError(f"ObservationAdapter for obs_space={config.obs_space!r} needs at least one camera name.")
        self.config = config
        self.augment = Augmenter(config.augmentations())
        self.frames_seen, self.frames_empty, self._next_warning = 0, 0, 1  # empty-cloud bookkeeping
        self.register_buffer("rgb_mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    @property
    def needs_ee_pose(self) -> bool:
        return self.config.frame == "ee" and has_positions(self.config.obs_space)

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
        d = d[..., 0]
        if self.augment.training and self.augment.by_kind["depth"]:
            d = self.augment.depth(d, _require(batch, intrinsics_key(cam))[..., 0, 0].float())
        return d.float() / 1000.0

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

    def _world_points(
        self, batch: dict, cam: str, box: Sequence[float] | None = None
    ) -> tuple[Tensor, Tensor, tuple[slice, slice]]:
        """One camera's world points (B, h, w, 3) and where its depth is valid (B, h, w): every pixel, or with
        `box` (xmin, xmax, ..., world frame) only the window of pixels that can land in it; and that window's
        rows and columns."""
        depth_m = self._depth_m(batch, cam)
        K, cam2world = self._camera(batch, cam)
        rows = columns = slice(None)
        window = None if box is None else geometry.box_pixel_window(K, cam2world, box, *depth_m.shape[1:])
        if window is not None:
            v0, v1, u0, u1 = window
            rows, columns = slice(v0, v1), slice(u0, u1)
            depth_m, K = depth_m[:, rows, columns], geometry.shift_intrinsics(K, v0, u0)
        points = geometry.transform_points(geometry.unproject_depth(depth_m, K), cam2world)
        return points, depth_m > 0, (rows, columns)

    def _frame_transform(self, batch: dict, ee_pose: Tensor | None) -> Tensor | None:
        """world -> chosen frame transform (B, 4, 4), or None for the world frame."""
        if self.config.frame == "world":
            return None
        if self.config.frame == "camera":
            return geometry.invert_transform(self._camera(batch, self.config.cameras[0])[1])
        if ee_pose is None:
            raise SchemaError("frame='ee' needs the end-effector pose (the last 7 values of observation.state).")
        return geometry.invert_transform(ee_pose)

    # ---- spaces ------------------------------------------------------------------------------------------

    def forward(self, batch: dict, ee_pose: Tensor | None = None) -> Tensor | PointCloud | tuple:
        space = space_info(self.config.obs_space)
        if space.control == "blind":
            state = _require(batch, STATE_KEY)
            return state.new_zeros(state.shape[0], 0)
        if space.control == "oracle":
            return _require(batch, PRIVILEGED_STATE_KEY).float()
        if space.fused:
            return tuple(self._space_input(space_info(part), batch, ee_pose) for part in space.parts)
        return self._space_input(space, batch, ee_pose)

    def _space_input(self, space: Space, batch: dict, ee_pose: Tensor | None) -> Tensor | PointCloud:
        if space.points:
            return self._pointcloud(batch, ee_pose)
        to_frame = self._frame_transform(batch, ee_pose) if space.positions else None
        per_camera = [
            torch.cat(self._image_channels(space, batch, cam, to_frame), dim=1) for cam in self.config.cameras
        ]
        return self.augment.image(torch.stack(per_camera, dim=1))

    def _image_channels(self, space: Space, batch: dict, cam: str, to_frame: Tensor | None) -> list[Tensor]:
        """One camera's channels of an image space's record (B, C, H, W) each: colour, scaled depth, xyz."""
        channels = []
        if space.colour:
            channels.append((self.augment.colour(self._rgb(batch, cam)) - self.rgb_mean) / self.rgb_std)
        if space.depth and not space.positions:  # a pointmap's depth is its xyz
            channels.append(self._scaled_depth(self._depth_m(batch, cam))[:, None])
        if space.positions:
            points, valid, _ = self._world_points(batch, cam)
            points = _in_frame(points, to_frame) * valid[..., None]
            if self.config.depth_normalization == "official":
                points = (points - 0.5) / 0.5
            channels.append(points.permute(0, 3, 1, 2))
        return channels

    def _scaled_depth(self, depth_m: Tensor) -> Tensor:
        if self.config.depth_normalization == "official":
            return (depth_m - 0.5) / 0.5
        near, far = self.config.depth_clip
        return (depth_m.clamp(near, far) - near) / (far - near) * 2 - 1

    def _pointcloud(self, batch: dict, ee_pose: Tensor | None) -> PointCloud:
        # only the pixels that can land in the crop box (widened by the jitter and by how far the point
        # augmentations can move a point into it) are unprojected: the same points, fewer of them
        reach = self._jitter + self.augment.point_reach(self.config.workspace)
        xyz, rgb, valid = self.fuse_cameras(batch, _widened(self.config.workspace, reach))
        workspace = torch.tensor(self.config.workspace, dtype=xyz.dtype, device=xyz.device)
        box = self._crop_box(workspace, len(xyz))
        xyz, valid = self.augment.points(xyz, valid, box)
        xyz, rgb, valid = self.crop_to_workspace(xyz, rgb, valid, box)
        xyz = _in_frame(xyz, self._frame_transform(batch, ee_pose))
        return self.point_features(*self.sample_points(xyz, rgb, valid), workspace)

    @property
    def _jitter(self) -> float:
        """The workspace jitter in force: none in evaluation."""
        return self.config.workspace_jitter if self.training else 0.0

    def _crop_box(self, workspace: Tensor, batch_size: int) -> Tensor:
        """The workspace box (6,), or in training with `workspace_jitter` one per cloud (B, 6) whose bounds each
        move by up to ±jitter (as the official real-robot code's)."""
        if self._jitter == 0:
            return workspace
        offsets = torch.rand(batch_size, 6, device=workspace.device, dtype=workspace.dtype) * 2 - 1
        return workspace + offsets * self._jitter

    def fuse_cameras(self, batch: dict, box: Sequence[float]) -> tuple[Tensor, Tensor, Tensor]:
        """Every camera's pixels that can land in `box` (xmin, xmax, ..., world frame), side by side: world points
        (B, N, 3), colours in [-1, 1] (B, N, 3; (B, N, 0) where the points carry none) and where depth is valid
        (B, N)."""
        xyz, rgb, valid = [], [], []
        # points without colour read no colour frame (`read_sensors`): an empty channel keeps the stages' shapes
        carry_colour = points_carry_colour(self.config.point_features)
        for cam in self.config.cameras:
            points, cam_valid, (rows, columns) = self._world_points(batch, cam, box)
            xyz.append(points.flatten(1, 2))
            valid.append(cam_valid.flatten(1))
            if not carry_colour:
                rgb.append(xyz[-1][..., :0])
                continue
            colour, size = self._rgb(batch, cam), batch[depth_key(cam)].shape[1:3]
            if colour.shape[-2:] != size:
                raise SchemaError(
                    f"{image_key(cam)} is {tuple(colour.shape[-2:])} but {depth_key(cam)} is {tuple(size)}: "
                    "point clouds need depth aligned to colour at the same resolution."
                )
            rgb.append(colour[..., rows, columns].permute(0, 2, 3, 1).flatten(1, 2) * 2 - 1)
        return torch.cat(xyz, 1), torch.cat(rgb, 1), torch.cat(valid, 1)

    def crop_to_workspace(self, xyz: Tensor, rgb: Tensor, valid: Tensor, box: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The valid points inside `box` ((6,) or one per cloud (B, 6)), packed to the front (xyz, rgb, mask); a
        cloud with none gets the empty-cloud point (the box's centre, colour 0), and is counted."""
        valid = geometry.crop_mask(xyz, valid, box)
        empty = ~valid.any(dim=1)
        self._count_empty(int(empty.sum()), len(empty))
        xyz, rgb, mask = geometry.pack(valid, xyz, rgb)
        if bool(empty.any()):  # into the first slot of the packed copies, which pack always keeps
            centre = box.reshape(-1, 3, 2).mean(-1).expand(len(xyz), 3)
            xyz[empty, 0], rgb[empty, 0], mask[empty, 0] = centre[empty], 0.0, True
        return xyz, rgb, mask

    def sample_points(self, xyz: Tensor, rgb: Tensor, mask: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """One point per `voxel_size` voxel (a random one in training, and with point_pipeline='official' also in
        evaluation), packed to the front (xyz, rgb, mask)."""
        official = self.config.point_pipeline == "official"
        keep = geometry.voxel_sample(xyz, mask, self.config.voxel_size, random=self.training or official)
        xyz, rgb, mask = geometry.pack(keep, xyz, rgb)
        if self.training and official:  # FPS then starts from a random point, as in the official code
            xyz, rgb, mask = geometry.shuffle(mask, xyz, rgb)
        return xyz, rgb, mask

    def point_features(self, xyz: Tensor, rgb: Tensor, mask: Tensor, workspace: Tensor) -> PointCloud:
        """The cloud with its `point_features` (rgb, xyz in metres or, with point_normalization='box', in [-1, 1]
        over the `workspace` box (6,)), zero outside `mask`."""
        scaled = xyz
        if self.config.point_normalization == "box":  # the nominal box also when jittered: same point, same features
            bounds = workspace.reshape(3, 2)
            scaled = (xyz - bounds.mean(-1)) / ((bounds[:, 1] - bounds[:, 0]) / 2)
        parts = {"rgb": rgb, "xyz": scaled}
        features = torch.cat([parts[name] for name in self.config.point_features.split("+")], -1)
        return PointCloud(xyz=xyz * mask[..., None], features=features * mask[..., None], mask=mask)

    def _count_empty(self, empty: int, frames: int) -> None:
        """Count frames with no point in the workspace: warn as they come, and stop a training whose data is
        mostly such frames (a unit or extrinsics error, not a few dropouts) after its first batches."""
        self.frames_seen += frames
        self.frames_empty += empty
        if not empty:
            return
        workspace = self.config.workspace
        if self.frames_empty >= self._next_warning:
            self._next_warning = 2 * self.frames_empty
            logger.warning(
                f"{self.frames_empty} of {self.frames_seen} frames so far had no valid point inside the workspace "
                f"{workspace} (depth dropout, occlusion): each was given the empty-cloud point"
            )
        fraction = self.frames_empty / self.frames_seen
        if self.training and self.frames_seen >= EMPTY_CHECK_FRAMES and fraction > MAX_EMPTY_FRACTION:
            raise SchemaError(
                f"{self.frames_empty} of the first {self.frames_seen} training frames have no valid point inside "
                f"the workspace {workspace} in {', '.join(depth_key(c) for c in self.config.cameras)} (or the "
                "observation.images.<cam>_depth LeRobot recorded, registered into them): the data, not a dropout. "
                "Check that depth is in millimetres, that cam2world maps camera -> world, and --policy.workspace: "
                "`obsbench validate --root DATASET` decodes every frame's depth and refuses depth in which no frame "
                "holds valid depth or whose median is not in millimetres."
            )


def _widened(box: Sequence[float], margin: float) -> list[float]:
    """The box (xmin, xmax, ymin, ymax, zmin, zmax) grown by `margin` on every side."""
    return [bound + (margin if i % 2 else -margin) for i, bound in enumerate(box)]


def _in_frame(points: Tensor, to_frame: Tensor | None) -> Tensor:
    """Points (B, ..., 3) moved by the world -> frame transform, or as they are in the world frame (None)."""
    return points if to_frame is None else geometry.transform_points(points, to_frame)


def _require(batch: dict, key: str) -> Tensor:
    if key not in batch:
        raise SchemaError(
            f"Missing {key!r} in the observation batch (it has "
            f"{sorted(k for k in batch if k.startswith('observation'))}). "
            "The chosen obs_space/cameras need it: record it in the dataset / env observation (an env told what "
            "to render, e.g. --env.obs_space, renders it for that space), or change --policy.obs_space / "
            "--policy.cameras."
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
