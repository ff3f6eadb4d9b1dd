"""The observation fields obs_act and obs_diffusion share, their config-time checks, and the paper's optimiser
and schedule presets (`class ObsACTConfig(ObservationConfig, ACTConfig)`: mixed in first, so its fields and
methods take precedence over the LeRobot config's)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import ClassVar

from lerobot.optim.optimizers import AdamWConfig

from lerobot_obsbench.encoders import (
    EncoderContext,
    available_encoders,
    check_encoder,
    default_encoder,
    encoder_info,
)
from lerobot_obsbench.policies.onecycle import OneCycleSchedulerConfig
from lerobot_obsbench.schema import (
    EE_POSE_SIZE,
    FRAMES,
    POINT_FEATURES,
    POINT_SPACES,
    SAMPLING,
    STATE_KEY,
    SchemaError,
    camera_resolution,
    check_choice,
    check_obs_space,
    is_sensor_key,
    sensor_keys,
    validate_features,
)
from lerobot_obsbench.spaces import DEFAULT_WORKSPACE, check_geometry

# Config fields that are options of some encoders: a value other than the default is refused where the chosen
# encoder does not take it (it would be silently ignored).
ENCODER_FIELDS = ("pretrained", "point_features", "sampling", "num_tokens", "knn")


def _plain(value):
    """Tuples and lists compare equal (draccus gives lists where defaults are tuples)."""
    return list(value) if isinstance(value, (tuple, list)) else value


@dataclass
class ObservationConfig:
    # Observation space the policy sees: rgb, depth, rgbd, pointmap or pointcloud. The one field to change
    # when comparing spaces; the dataset stays the same.
    obs_space: str = "pointcloud"
    # Registered encoder name (`obsbench encoders` lists them). Empty: the registry's default for the space
    # (the paper's: resnet50 for images, pointnet for point clouds).
    encoder: str | None = None
    # Pretrained weights of the encoder: "imagenet" (ResNets; downloads torchvision's weights), a local file,
    # or a Hub file ORG/REPO:FILENAME. None (default) never downloads anything.
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
    # AdamW of the paper's training recipe (Appendix C): weight decay, betas, eps.
    optimizer_weight_decay: float = 0.05
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    optimizer_eps: float = 1e-8
    # OneCycle schedule of the paper (stepped per batch).
    scheduler_pct_start: float = 0.15
    scheduler_div_factor: float = 100.0
    scheduler_final_div_factor: float = 1000.0

    # Fields inherited from the LeRobot config that the plugin replaces: field -> what to use instead. A value
    # other than the default is refused instead of being silently ignored.
    REPLACED_FIELDS: ClassVar[dict[str, str]] = {}

    def __post_init__(self):
        super().__post_init__()  # the LeRobot config this is mixed into (ACTConfig / DiffusionConfig)
        self.validate_observation_fields()

    def validate_features(self) -> None:
        self.resolve_observation_features()

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(
            lr=self.optimizer_lr,
            betas=tuple(self.optimizer_betas),
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
        )

    def get_scheduler_preset(self) -> OneCycleSchedulerConfig:
        return OneCycleSchedulerConfig(
            pct_start=self.scheduler_pct_start,
            div_factor=self.scheduler_div_factor,
            final_div_factor=self.scheduler_final_div_factor,
        )

    @classmethod
    def field_default(cls, name: str):
        spec = cls.__dataclass_fields__[name]
        return spec.default_factory() if spec.default is dataclasses.MISSING else spec.default

    def _non_default(self, name: str) -> bool:
        return _plain(getattr(self, name)) != _plain(self.field_default(name))

    def validate_observation_fields(self) -> None:
        """Config-time checks: fail before any data is read."""
        check_obs_space(self.obs_space)
        if not self.encoder:
            self.encoder = default_encoder(self.obs_space)
        check_encoder(self.encoder, self.obs_space)
        check_choice("frame", self.frame, FRAMES)
        check_choice("point_features", self.point_features, POINT_FEATURES)
        check_choice("sampling", self.sampling, SAMPLING)
        check_geometry(self.workspace, self.voxel_size, self.depth_clip)
        for name in ("num_tokens", "knn"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1; got {getattr(self, name)}")
        self.check_ablations()
        self.check_replaced_fields()

    def check_ablations(self) -> None:
        """Design choices that only some spaces / encoders have: refuse the others instead of ignoring them."""
        info = encoder_info(self.encoder)
        if self.pretrained and not info.pretrained:
            with_weights = [n for n in available_encoders(self.obs_space) if encoder_info(n).pretrained]
            raise ValueError(
                f"encoder {self.encoder!r} has no pretrained weights (pretrained={self.pretrained!r}); "
                f"encoders for {self.obs_space!r} that load weights: {', '.join(with_weights) or 'none'}"
            )
        for name in ENCODER_FIELDS:
            if name in info.options or not self._non_default(name):
                continue
            value, default = getattr(self, name), self.field_default(name)
            if self.obs_space not in POINT_SPACES:
                raise ValueError(
                    f"{name}={value!r} is a point-cloud design choice; obs_space={self.obs_space!r} has "
                    f"none (use obs_space='pointcloud' or leave {name}={default!r})"
                )
            raise ValueError(
                f"{name}={value!r} is not an option of encoder {self.encoder!r} (it takes "
                f"{', '.join(info.options)}); leave {name}={default!r}"
            )
        if self.frame != "world" and self.obs_space not in ("pointcloud", "pointmap"):
            raise ValueError(
                f"frame={self.frame!r} changes point coordinates; obs_space={self.obs_space!r} has none "
                "(use pointcloud or pointmap, or leave frame='world')"
            )

    def check_replaced_fields(self) -> None:
        """LeRobot fields this policy does not use: refuse a value the user set, naming what to use instead."""
        for name, instead in self.REPLACED_FIELDS.items():
            if self._non_default(name):
                raise ValueError(
                    f"{self.type}: {name}={getattr(self, name)!r} has no effect in this plugin's policies; {instead}"
                )

    def resolve_observation_features(self) -> None:
        """Check the dataset features against the space, fix `cameras`, and take the sensor keys out of
        `input_features`: LeRobot's normaliser must not touch depth (mm), K or cam2world, and RGB is
        normalised by the adapter so that training and evaluation see identical inputs."""
        sensors = {k: ft for k, ft in self.input_features.items() if is_sensor_key(k)}
        if sensors or not self.cameras:
            self.cameras = validate_features(self.input_features, self.obs_space, self.cameras or None)
            self.camera_resolution = camera_resolution(self.input_features, self.obs_space, self.cameras)
        self.input_features = {k: ft for k, ft in self.input_features.items() if not is_sensor_key(k)}
        state = self.input_features.get(STATE_KEY)
        if self.frame == "ee" and self.obs_space in ("pointcloud", "pointmap"):
            if state is None or state.shape[0] < EE_POSE_SIZE:
                raise SchemaError(
                    f"frame='ee' reads the end-effector pose from the last {EE_POSE_SIZE} values of "
                    f"{STATE_KEY}; the dataset has {state.shape if state else 'no state'}. Record the EE "
                    "pose (xyz + quaternion wxyz) at the end of the state or use --policy.frame=world."
                )

    def observation_keys(self) -> list[str]:
        return sensor_keys(self.obs_space, self.cameras)

    def encoder_options(self) -> dict:
        """The chosen encoder's options, taken from this config (`image_size` from the camera resolution)."""
        values = {name: getattr(self, name) for name in (*ENCODER_FIELDS, "voxel_size")}
        if self.camera_resolution:
            values["image_size"] = tuple(self.camera_resolution)
        return {k: v for k, v in values.items() if k in encoder_info(self.encoder).options}

    def encoder_context(self) -> EncoderContext:
        size = tuple(self.camera_resolution) if self.obs_space not in POINT_SPACES and self.camera_resolution else None
        return EncoderContext(cameras=len(self.cameras), image_size=size)
