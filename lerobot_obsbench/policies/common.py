"""What obs_act and obs_diffusion share: the observation fields of their configs, the observation encoder
module (adapter + registry encoder), and the paper's optimiser / OneCycle schedule."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from lerobot.optim.optimizers import AdamWConfig
from lerobot.optim.schedulers import LRSchedulerConfig
from torch import Tensor, nn
from torch.optim import Optimizer
from torch.optim.lr_scheduler import LRScheduler, OneCycleLR

from lerobot_obsbench import geometry
from lerobot_obsbench.datasets import schema
from lerobot_obsbench.encoders import available_encoders, check_encoder, encoder_info, make_encoder
from lerobot_obsbench.encoders.pointnet import SAMPLING
from lerobot_obsbench.spaces import (
    DEFAULT_WORKSPACE,
    ObservationAdapter,
    check_frame,
    check_geometry,
    check_point_features,
)

# The paper's encoder for each space when `encoder` is left empty.
DEFAULT_ENCODER = {"rgb": "resnet50", "depth": "resnet50", "rgbd": "resnet50", "pointmap": "resnet50",
                   "pointcloud": "pointnet"}


@dataclass
class ObservationConfig:
    """Observation fields shared by obs_act and obs_diffusion, mixed in before their LeRobot config
    (`class ObsACTConfig(ObservationConfig, ACTConfig)`), so its methods take precedence: config-time checks,
    dataset feature resolution, and the paper's AdamW + OneCycle training presets."""

    # Observation space the policy sees: rgb, depth, rgbd, pointmap or pointcloud. The one field to change
    # when comparing spaces; the dataset stays the same.
    obs_space: str = "pointcloud"
    # Registered encoder name (`obsbench encoders` lists them). Empty: the paper's choice for the space
    # (resnet50 for images, pointnet for point clouds).
    encoder: str | None = None
    # Pretrained weights for image encoders: "imagenet" (downloads torchvision's weights) or a local file.
    # None (default) never downloads anything.
    pretrained: str | None = None
    # Cameras to read (`observation.*.<cam>` keys). Empty: every camera of the dataset that has the keys the
    # space needs; filled in and saved with the checkpoint.
    cameras: list[str] = field(default_factory=list)
    # (height, width) of the camera frames the policy was trained on; filled in from the dataset and saved,
    # so evaluation can refuse an env rendering another size.
    camera_resolution: list[int] = field(default_factory=list)
    # Frame of point coordinates (pointcloud, pointmap): world, camera (first camera) or ee (end effector,
    # from the last 7 values of observation.state: xyz + quaternion wxyz).
    frame: str = "world"
    # Per-point features: "rgb+xyz" (paper default), "xyz" or "rgb".
    point_features: str = "rgb+xyz"
    # Point tokenizer placement: "post" (encode all points, then FPS + kNN; paper default) or "pre".
    sampling: str = "post"
    # Number of FPS seeds = point tokens (paper: 2048).
    num_tokens: int = 2048
    # Neighbours grouped per seed (paper: 16).
    knn: int = 16
    # Voxel edge for one-point-per-voxel sampling, metres (paper: 5 mm).
    voxel_size: float = 0.005
    # Workspace crop box in the world frame (xmin, xmax, ymin, ymax, zmin, zmax), metres; zmin > 0 drops the
    # ground / table plane.
    workspace: list[float] = field(default_factory=lambda: list(DEFAULT_WORKSPACE))
    # Depth range (near, far) in metres that depth images are clipped to and scaled from.
    depth_clip: list[float] = field(default_factory=lambda: [0.0, 2.0])
    # AdamW weight decay of the paper's training recipe (Appendix C).
    optimizer_weight_decay: float = 0.05
    # OneCycle schedule of the paper (stepped per batch).
    scheduler_pct_start: float = 0.15
    scheduler_div_factor: float = 100.0
    scheduler_final_div_factor: float = 1000.0

    def __post_init__(self):
        super().__post_init__()  # the LeRobot config this is mixed into (ACTConfig / DiffusionConfig)
        self.validate_observation_fields()

    def validate_features(self) -> None:
        self.resolve_observation_features()

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(lr=self.optimizer_lr, weight_decay=self.optimizer_weight_decay)

    def get_scheduler_preset(self) -> OneCycleSchedulerConfig:
        return OneCycleSchedulerConfig(pct_start=self.scheduler_pct_start, div_factor=self.scheduler_div_factor,
                                       final_div_factor=self.scheduler_final_div_factor)

    def validate_observation_fields(self) -> None:
        """Config-time checks: fail before any data is read."""
        schema.check_obs_space(self.obs_space)
        if not self.encoder:
            self.encoder = DEFAULT_ENCODER[self.obs_space]
        check_encoder(self.encoder, self.obs_space)
        check_frame(self.frame)
        check_point_features(self.point_features)
        if self.sampling not in SAMPLING:
            raise ValueError(f"sampling must be one of {SAMPLING}; got {self.sampling!r}")
        self.check_ablations()
        check_geometry(self.workspace, self.voxel_size, self.depth_clip)
        for name in ("num_tokens", "knn"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1; got {getattr(self, name)}")

    def check_ablations(self) -> None:
        """Design choices that only some spaces / encoders have: refuse the others instead of ignoring them."""
        if self.pretrained and not encoder_info(self.encoder).pretrained:
            with_weights = [n for n in available_encoders(self.obs_space) if encoder_info(n).pretrained]
            raise ValueError(f"encoder {self.encoder!r} has no pretrained weights (pretrained={self.pretrained!r}); "
                             f"encoders for {self.obs_space!r} that load weights: {', '.join(with_weights) or 'none'}")
        points = self.obs_space == "pointcloud"
        for name, default in (("sampling", "post"), ("point_features", "rgb+xyz")):
            if not points and getattr(self, name) != default:
                raise ValueError(f"{name}={getattr(self, name)!r} is a point-cloud design choice; obs_space="
                                 f"{self.obs_space!r} has none (use obs_space='pointcloud' or leave {name}={default!r})")
        if self.frame != "world" and self.obs_space not in ("pointcloud", "pointmap"):
            raise ValueError(f"frame={self.frame!r} changes point coordinates; obs_space={self.obs_space!r} has none "
                             "(use pointcloud or pointmap, or leave frame='world')")

    def resolve_observation_features(self) -> None:
        """Check the dataset features against the space, fix `cameras`, and take the sensor keys out of
        `input_features`: LeRobot's normaliser must not touch depth (mm), K or cam2world, and RGB is
        normalised by the adapter so that training and evaluation see identical inputs."""
        sensors = {k: ft for k, ft in self.input_features.items() if schema.is_sensor_key(k)}
        if sensors or not self.cameras:
            self.cameras = schema.validate_features(self.input_features, self.obs_space, self.cameras or None)
            self.camera_resolution = schema.camera_resolution(self.input_features, self.obs_space, self.cameras)
        self.input_features = {k: ft for k, ft in self.input_features.items() if not schema.is_sensor_key(k)}
        state = self.input_features.get(schema.STATE_KEY)
        if self.frame == "ee" and self.obs_space in ("pointcloud", "pointmap"):
            if state is None or state.shape[0] < schema.EE_POSE_SIZE:
                raise schema.SchemaError(
                    f"frame='ee' reads the end-effector pose from the last {schema.EE_POSE_SIZE} values of "
                    f"{schema.STATE_KEY}; the dataset has {state.shape if state else 'no state'}. Record the EE "
                    "pose (xyz + quaternion wxyz) at the end of the state or use --policy.frame=world."
                )

    def observation_keys(self) -> list[str]:
        return schema.sensor_keys(self.obs_space, self.cameras)


@LRSchedulerConfig.register_subclass("onecycle")
@dataclass
class OneCycleSchedulerConfig(LRSchedulerConfig):
    """torch's OneCycleLR over the whole run (the paper's schedule); peak = the optimiser's lr."""

    num_warmup_steps: int | None = None
    pct_start: float = 0.15
    anneal_strategy: str = "cos"
    div_factor: float = 100.0
    final_div_factor: float = 1000.0

    def build(self, optimizer: Optimizer, num_training_steps: int) -> LRScheduler:
        return OneCycleLR(optimizer, max_lr=[g["lr"] for g in optimizer.param_groups],
                          total_steps=max(num_training_steps, 2), pct_start=self.pct_start,
                          anneal_strategy=self.anneal_strategy, div_factor=self.div_factor,
                          final_div_factor=self.final_div_factor)


class StateDenormalizer(nn.Module):
    """Recovers the raw observation.state from the normalised one (LeRobot normalises before the model).

    Needed for the end-effector frame. Its buffers come from the dataset stats at construction and are saved
    with the checkpoint, so a loaded policy needs no stats.
    """

    def __init__(self, state: PolicyFeature | None, mode: NormalizationMode, stats: dict | None):
        super().__init__()
        dim = state.shape[0] if state is not None else 0
        loc, scale = torch.zeros(dim), torch.ones(dim)
        st = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in (stats or {}).items()}
        if st and mode is NormalizationMode.MEAN_STD:
            loc, scale = st["mean"], st["std"]
        elif st and mode is NormalizationMode.MIN_MAX:
            span = st["max"] - st["min"]
            span = torch.where(span == 0, torch.full_like(span, 1e-8), span)
            loc, scale = st["min"] + span / 2, span / 2
        elif st and mode is not NormalizationMode.IDENTITY:
            raise NotImplementedError(f"state normalisation {mode} is not supported for the ee frame")
        self.register_buffer("loc", loc.reshape(dim))
        self.register_buffer("scale", scale.reshape(dim))

    def forward(self, state: Tensor) -> Tensor:
        return state * self.scale + self.loc


class EnvObservationMixin:
    """Lets stock lerobot-eval drive the policy: unpacks the env's `observation.robot_state` passthrough
    (depth, intrinsics, cam2world; see `schema.unpack_passthrough`) onto the policy's device before LeRobot's
    own `select_action` / `predict_action_chunk` run."""

    def _unpack(self, batch: dict) -> dict:
        unpacked = schema.unpack_passthrough(batch)
        if unpacked is batch:
            return batch
        device = torch.device(self.config.device) if self.config.device else None
        return {k: v.to(device) if isinstance(v, Tensor) and device else v for k, v in unpacked.items()}

    def select_action(self, batch: dict, *args, **kwargs) -> Tensor:
        return super().select_action(self._unpack(batch), *args, **kwargs)

    def predict_action_chunk(self, batch: dict, *args, **kwargs) -> Tensor:
        return super().predict_action_chunk(self._unpack(batch), *args, **kwargs)


class ObservationEncoder(nn.Module):
    """ObservationAdapter + registry encoder: sensor batch -> tokens/pos (ACT) or a feature vector (DP)."""

    def __init__(self, config, output: str, dim: int, dataset_stats: dict | None = None):
        super().__init__()
        self.adapter = ObservationAdapter(
            config.obs_space, config.cameras, frame=config.frame, point_features=config.point_features,
            workspace=tuple(config.workspace), voxel_size=config.voxel_size, depth_clip=tuple(config.depth_clip),
        )
        self.encoder = make_encoder(
            config.encoder, config.obs_space, output=output, dim=dim, pretrained=config.pretrained,
            point_features=config.point_features, sampling=config.sampling, num_tokens=config.num_tokens,
            knn=config.knn, voxel_size=config.voxel_size,
            image_size=config.camera_resolution[0] if config.camera_resolution else None,
        )
        self.out_dim = self.encoder.out_dim
        mode = config.normalization_mapping.get(FeatureType.STATE.value, NormalizationMode.IDENTITY)
        stats = (dataset_stats or {}).get(schema.STATE_KEY)
        self.state = StateDenormalizer(config.input_features.get(schema.STATE_KEY), mode, stats)
        self.input_keys = config.observation_keys() + ([schema.STATE_KEY] if self.adapter.needs_ee_pose else [])

    def forward(self, batch: dict[str, Tensor]) -> Tensor | tuple[Tensor, Tensor]:
        ee_pose = None
        if self.adapter.needs_ee_pose:
            pose = self.state(batch[schema.STATE_KEY])[..., -schema.EE_POSE_SIZE:]
            ee_pose = geometry.pose_to_matrix(pose[..., :3], pose[..., 3:])
        return self.encoder(self.adapter(batch, ee_pose=ee_pose))
