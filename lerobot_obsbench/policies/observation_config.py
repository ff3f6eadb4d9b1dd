"""The observation fields obs_act and obs_diffusion share, their config-time checks, and the paper's optimiser
and schedule presets (`class ObsACTConfig(ObservationConfig, ACTConfig)`: mixed in first, so its fields and
methods take precedence over the LeRobot config's)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import ClassVar

from lerobot.optim.optimizers import AdamWConfig

from lerobot_obsbench.camera_calibration import dataset_calibration
from lerobot_obsbench.dataset_reads import memory_budget_bytes, reader_choice
from lerobot_obsbench.encoders import (
    EncoderContext,
    available_encoders,
    check_encoder,
    default_encoder,
    encoder_info,
)
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.numeric import check_number, check_numbers
from lerobot_obsbench.policies.onecycle import OneCycleSchedulerConfig
from lerobot_obsbench.schema import (
    DEFAULT_POINT_FEATURES,
    DEPTH_PREFIX,
    EE_POSE_SIZE,
    PRIVILEGED_STATE_KEY,
    SAMPLING,
    STATE_KEY,
    SchemaError,
    camera_resolution,
    check_choice,
    has_positions,
    is_sensor_key,
    reads_images,
    reads_points,
    sensor_keys,
    space_info,
    stock_depth_key,
    validate_features,
)
from lerobot_obsbench.spaces import DEFAULT_WORKSPACE, AdapterConfig

# Config field -> the encoder option it sets. A value other than the field's default is refused where the chosen
# encoder does not take that option (it would be silently ignored). Policy configs add their own.
ENCODER_FIELDS = {
    "pretrained": "pretrained",
    "point_features": "point_features",
    "sampling": "sampling",
    "num_tokens": "num_tokens",
    "knn": "knn",
    "image_input_size": "input_size",
    "zero_init_extra_channels": "zero_extra_channels",
    "point_pipeline": "pipeline",
    "encoder_norm": "norm",
}
POINT_CHOICES = ("point_features", "sampling", "num_tokens", "knn", "point_pipeline")


def _plain(value):
    """Tuples and lists compare equal (draccus gives lists where defaults are tuples)."""
    return list(value) if isinstance(value, (tuple, list)) else value


@dataclass
class ObservationConfig:
    """The observation fields of obs_act and obs_diffusion, in groups:

    Args:
        What the policy sees: `obs_space` (the one field to change when comparing spaces), its `encoder`, the
            encoder's normalisation and pretrained weights, and the cameras read.
        Filled in from the dataset: the camera resolution, the oracle's privileged-state size and names, and the
            calibration of LeRobot-native depth; saved with the checkpoint so that evaluation can check the env.
        Point clouds: the coordinate frame, per-point features, tokenizer (sampling, tokens, neighbours), voxel
            size, the workspace crop box and its training jitter, and the official pipeline's details.
        Images and depth: depth clipping and scaling, the encoder's input size, zero-initialised extra channels.
        Training: the augmentation recipe and whether the encoder is compiled.
        Optimiser and schedule: the paper's AdamW and OneCycle (Appendix C).
    """

    # --- What the policy sees ---
    # Observation space the policy sees: rgb, depth, rgbd, pointmap, pointcloud, the fused rgb+pointcloud, or a
    # control (none: blind; state: the oracle's object poses). The one field to change when comparing spaces; the
    # dataset stays the same.
    obs_space: str = "pointcloud"
    # Registered encoder name (`obsbench encoders` lists them). Empty: the registry's default for the space
    # (the paper's: resnet50 for images, pointnet for point clouds).
    encoder: str | None = None
    # Normalisation layers of the encoder, where it offers a choice (`obsbench encoders` lists them): "batch",
    # "layer" (dp3, pointnet) or "group", "batch" (spatial_softmax). None: the encoder's own (DP3's LayerNorm,
    # the paper's BatchNorm for PointNet, GroupNorm for the keypoint encoder).
    encoder_norm: str | None = None
    # Pretrained weights of the encoder: "imagenet" (ResNets; downloads torchvision's weights), a local file,
    # or a Hub file ORG/REPO:FILENAME. None (default) never downloads anything.
    pretrained: str | None = None
    # Cameras to read (`observation.*.<cam>` keys). Empty: every camera of the dataset that has the keys the
    # space needs; filled in and saved with the checkpoint.
    cameras: list[str] = field(default_factory=list)

    # --- Filled in from the dataset when training starts and saved with the checkpoint ---
    # (height, width) of the camera frames the policy was trained on; filled in from the dataset and saved,
    # so evaluation can refuse an env rendering another size.
    camera_resolution: list[int] = field(default_factory=list)
    # Size of observation.privileged_state (7 per object) the oracle space `state` reads; filled in from the
    # dataset and saved (the key is kept from LeRobot's normaliser, as the sensors are). 0 for every other space.
    privileged_state_dim: int = 0
    # Names of those values (`<object>.<component>`, schema.privileged_state_names) where the dataset has them;
    # filled in and saved, so evaluation refuses a task whose objects are others. Empty for every other space.
    privileged_state_names: list[str] = field(default_factory=list)
    # Calibration of cameras recorded with LeRobot's own depth feature (`observation.images.<cam>_depth`): camera ->
    # the fields of `camera_calibration.CameraCalibration`. Filled in from the dataset's meta/obsbench_cameras.json
    # (`obsbench attach-calibration`) when training starts, and saved with the checkpoint.
    depth_calibration: dict[str, dict] = field(default_factory=dict)

    # --- Point clouds (and pointmap's frame) ---
    # Frame of point coordinates (pointcloud, pointmap): world, camera (first camera) or ee (end effector,
    # from the last 7 values of observation.state: xyz + quaternion wxyz).
    frame: str = "world"
    # Per-point features: "rgb+xyz" (paper default), "xyz" or "rgb".
    point_features: str = DEFAULT_POINT_FEATURES
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
    # Training-time jitter of each workspace bound, metres (uniform in ±jitter per sample; the official
    # real-robot code uses 0.01). Point clouds only.
    workspace_jitter: float = 0.0
    # Point-cloud sampling details: "plugin" (deterministic voxel point at evaluation, FPS from the first point)
    # or "official" (a random point per voxel also at evaluation, points shuffled in training, the tokenizer's
    # BatchNorm with PyTorch's defaults and statistics over repeated seed slots, as the official code).
    point_pipeline: str = "plugin"
    # Scale of the xyz point features: "metres" (the paper's) or "box" ([-1, 1] over `workspace`, as DP3's code
    # scales its clouds; world frame only). Point positions stay in metres.
    point_normalization: str = "metres"

    # --- Images and depth ---
    # Depth range (near, far) in metres that depth images are clipped to and scaled from.
    depth_clip: list[float] = field(default_factory=lambda: [0.0, 2.0])
    # Scaling of depth images and pointmap xyz: "clip" (to depth_clip, then [-1, 1]) or "official" (the official
    # code's (metres - 0.5) / 0.5; MultiViT standardises depth by its batch's 10th-90th percentile statistics).
    depth_normalization: str = "clip"
    # Image encoders resize frames to this size first (the official pipeline: 224, i.e. 49 ResNet tokens per
    # camera; ViT / MultiViT resize to 256 and centre-crop 224). None: frames at their recorded size.
    image_input_size: int | None = None
    # Start the stem's extra input channels (depth, xyz) at zero also when training from scratch, as the official
    # code does (a depth-only stem starts all zero). Pretrained stems always start them at zero.
    zero_init_extra_channels: bool = False

    # --- Training ---
    # Training-time augmentation recipe: registered names joined by '+' (`random_shift`, `point_jitter+point_dropout`;
    # `obsbench encoders` lists them with their spaces), run inside the policy's forward in training only (the
    # centre crop of `random_crop` also at test). Empty: none.
    augment: str = ""
    # Train with the observation encoder compiled by torch.compile (inductor): the same model and weights, fused
    # kernels (on a CPU no faster: docs/performance.md); evaluation runs it eagerly, so a checkpoint loads and acts
    # without compiling.
    compile_encoder: bool = False

    # --- Optimiser and schedule (the paper's recipe) ---
    # AdamW of the paper's training recipe (Appendix C): weight decay, betas, eps.
    optimizer_weight_decay: float = 0.05
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    optimizer_eps: float = 1e-8
    # Exempt biases and 1-D parameters (norms) from weight decay (the official Diffusion Policy recipe).
    optimizer_decay_exempt_1d: bool = False
    # Gradient-norm clipping in LeRobot's trainer (LeRobot's default 10; the official code's 0.5).
    optimizer_grad_clip_norm: float = 10.0
    # OneCycle schedule of the paper (stepped per batch).
    scheduler_pct_start: float = 0.15
    scheduler_div_factor: float = 100.0
    scheduler_final_div_factor: float = 1000.0

    # Fields inherited from the LeRobot config that the plugin replaces: field -> what to use instead. A value
    # other than the default is refused instead of being silently ignored.
    REPLACED_FIELDS: ClassVar[dict[str, str]] = {}
    ENCODER_FIELDS: ClassVar[dict[str, str]] = ENCODER_FIELDS

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
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def param_groups(self, named_parameters, backbone_prefix: str = "", backbone_lr: float | None = None) -> list[dict]:
        """AdamW parameter groups: the observation encoder (names starting with `backbone_prefix`) at
        `backbone_lr` when given, and, with `optimizer_decay_exempt_1d`, biases and 1-D parameters without weight
        decay."""
        groups: dict[tuple[bool, bool], list] = {}
        for name, param in named_parameters:
            if param.requires_grad:
                backbone = backbone_lr is not None and name.startswith(backbone_prefix)
                exempt = self.optimizer_decay_exempt_1d and param.ndim <= 1
                groups.setdefault((backbone, exempt), []).append(param)
        out = []
        for (backbone, exempt), params in sorted(groups.items()):
            out.append(
                {
                    "params": params,
                    **({"lr": backbone_lr} if backbone else {}),
                    **({"weight_decay": 0.0} if exempt else {}),
                }
            )
        return out

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
        self.adapter_config()  # the space and the adapter's fields, checked against it
        if not self.encoder:
            self.encoder = default_encoder(self.obs_space)
        check_encoder(self.encoder, self.obs_space)
        check_choice("sampling", self.sampling, SAMPLING)
        self.check_numbers()
        self.check_ablations()
        self.check_replaced_fields()

    # Numeric fields -> their bounds (`numeric.check_number`); the adapter checks its own (workspace, voxel_size,
    # depth_clip, workspace_jitter), the policy configs add theirs.
    NUMBER_FIELDS: ClassVar[dict[str, dict]] = {
        "num_tokens": {"whole": True, "minimum": 1},
        "knn": {"whole": True, "minimum": 1},
        "optimizer_lr": {"above": 0},
        "optimizer_weight_decay": {"minimum": 0},
        "optimizer_eps": {"above": 0},
        "optimizer_grad_clip_norm": {"minimum": 0},
        "scheduler_pct_start": {"above": 0, "below": 1},
        "scheduler_div_factor": {"above": 0},
        "scheduler_final_div_factor": {"above": 0},
    }

    def check_numbers(self) -> None:
        """Every numeric field finite and within its bounds, named when it is not (a NaN passes `<` checks), and
        the settings lerobot-train's data loading reads from the environment (checked here, where LeRobot's parser
        shows the reason, rather than as a traceback once the dataset loads)."""
        for name, bounds in self.NUMBER_FIELDS.items():
            check_number(name, getattr(self, name), **bounds)
        if self.image_input_size is not None:
            check_number("image_input_size (pixels; or None)", self.image_input_size, whole=True, minimum=16)
        check_numbers("optimizer_betas", self.optimizer_betas, length=2, minimum=0, below=1)
        reader_choice()
        memory_budget_bytes()

    def check_ablations(self) -> None:
        """Design choices that only some encoders have: refuse the others instead of ignoring them (the adapter's
        fields are checked against the space by `adapter_config()`)."""
        info = encoder_info(self.encoder)
        if self.pretrained and not info.pretrained:
            with_weights = [n for n in available_encoders(self.obs_space) if encoder_info(n).pretrained]
            raise ConfigError(
                f"encoder {self.encoder!r} has no pretrained weights (pretrained={self.pretrained!r}); "
                f"encoders for {self.obs_space!r} that load weights: {', '.join(with_weights) or 'none'}"
            )
        for name, option in self.ENCODER_FIELDS.items():
            if option in info.options or not self._non_default(name):
                continue
            value, default = getattr(self, name), self.field_default(name)
            if not reads_points(self.obs_space) and name in POINT_CHOICES:
                raise ConfigError(
                    f"{name}={value!r} is a point-cloud design choice; obs_space={self.obs_space!r} has "
                    f"none (use obs_space='pointcloud' or leave {name}={default!r})"
                )
            raise ConfigError(
                f"{name}={value!r} is not an option of encoder {self.encoder!r} (it takes "
                f"{', '.join(info.options) or 'no options'}); leave {name}={default!r}"
            )
        for name, option in self.ENCODER_FIELDS.items():
            allowed, value = info.choices.get(option), getattr(self, name)
            if allowed and value is not None and value not in allowed:
                raise ConfigError(
                    f"{name}={value!r}: encoder {self.encoder!r} takes {', '.join(allowed)} (or None, its own)"
                )

    def adapter_config(self) -> AdapterConfig:
        """The observation adapter's settings: this config's fields of the same names, checked against the space."""
        return AdapterConfig(**{spec.name: getattr(self, spec.name) for spec in dataclasses.fields(AdapterConfig)})

    def check_replaced_fields(self) -> None:
        """LeRobot fields this policy does not use: refuse a value the user set, naming what to use instead."""
        for name, instead in self.REPLACED_FIELDS.items():
            if self._non_default(name):
                raise ConfigError(
                    f"{self.type}: {name}={getattr(self, name)!r} has no effect in this plugin's policies; {instead}"
                )

    def resolve_observation_features(self) -> None:
        """Check the dataset features against the space, fix `cameras`, and take the sensor keys out of
        `input_features`: LeRobot's normaliser must not touch depth (mm), K or cam2world, and RGB is
        normalised by the adapter so that training and evaluation see identical inputs."""
        sensors = {k: ft for k, ft in self.input_features.items() if is_sensor_key(k)}
        if space_info(self.obs_space).control == "oracle":
            if sensors or not self.privileged_state_dim:  # a dataset's features; a loaded checkpoint has the size
                validate_features(self.input_features, self.obs_space)
                self.privileged_state_dim = int(self.input_features[PRIVILEGED_STATE_KEY].shape[0])
        elif sensors or not self.cameras:
            calibration = self.depth_calibration
            self.cameras = validate_features(self.input_features, self.obs_space, self.cameras or None, calibration)
            self.camera_resolution = camera_resolution(self.input_features, self.obs_space, self.cameras, calibration)
        self.depth_calibration = {cam: v for cam, v in self.depth_calibration.items() if cam in self.cameras}
        self.input_features = {k: ft for k, ft in self.input_features.items() if not is_sensor_key(k)}
        state = self.input_features.get(STATE_KEY)
        if self.frame == "ee" and has_positions(self.obs_space):
            if state is None or state.shape[0] < EE_POSE_SIZE:
                raise SchemaError(
                    f"frame='ee' reads the end-effector pose from the last {EE_POSE_SIZE} values of "
                    f"{STATE_KEY}; the dataset has {state.shape if state else 'no state'}. Record the EE "
                    "pose (xyz + quaternion wxyz) at the end of the state or use --policy.frame=world."
                )

    def read_dataset_meta(self, dataset_meta) -> None:
        """Take from the dataset's metadata what its features do not say (once: a loaded checkpoint keeps what it
        was trained with): the calibration of its LeRobot-recorded depth cameras (meta/ folder) and, for the
        oracle, the names of the object-pose values."""
        if dataset_meta is None:
            return
        if not self.depth_calibration:
            self.depth_calibration = dataset_calibration(dataset_meta)
        names = dataset_meta.features.get(PRIVILEGED_STATE_KEY, {}).get("names")
        if (
            space_info(self.obs_space).control == "oracle"
            and not self.privileged_state_names
            and isinstance(names, list)
        ):
            self.privileged_state_names = [str(name) for name in names]

    def dataset_reads(self, dataset_meta) -> set[str]:
        """The dataset features this policy reads in training: every feature that is not a sensor (state, action,
        ...) and the sensors of its space on its cameras (a calibrated LeRobot depth map where it stands in for
        the schema's depth). lerobot-train then loads nothing else (`lerobot_obsbench.dataset_reads`)."""
        features = dataset_meta.features
        reads = {key for key in features if not is_sensor_key(key)}
        if space_info(self.obs_space).control == "oracle":
            return reads | {PRIVILEGED_STATE_KEY}
        calibration = self.depth_calibration or dataset_calibration(dataset_meta)
        # the dataset's own features: validate_features registers calibrated depth itself, and names a LeRobot
        # depth map that lacks its calibration
        cameras = validate_features(features, self.obs_space, self.cameras or None, calibration)
        for key in sensor_keys(self.obs_space, cameras, self.point_features):
            if key in features:
                reads.add(key)
            elif key.startswith(DEPTH_PREFIX):  # registered from the camera's LeRobot depth map
                reads.add(stock_depth_key(key.removeprefix(DEPTH_PREFIX)))
        return reads

    def observation_keys(self) -> list[str]:
        oracle = [PRIVILEGED_STATE_KEY] if space_info(self.obs_space).control == "oracle" else []
        return sensor_keys(self.obs_space, self.cameras, self.point_features) + oracle

    def encoder_options(self) -> dict:
        """The chosen encoder's options, taken from this config (`image_size` from the camera resolution, MultiViT's
        depth standardisation from `depth_normalization`)."""
        values = {option: getattr(self, name) for name, option in self.ENCODER_FIELDS.items()}
        values["voxel_size"] = self.voxel_size
        values["state_dim"] = self.privileged_state_dim
        values["depth_standardize"] = self.depth_normalization == "official"
        if self.camera_resolution:
            values["image_size"] = tuple(self.camera_resolution)
        return {k: v for k, v in values.items() if k in encoder_info(self.encoder).options}

    def encoder_context(self) -> EncoderContext:
        size = tuple(self.camera_resolution) if reads_images(self.obs_space) and self.camera_resolution else None
        return EncoderContext(cameras=len(self.cameras), image_size=size)
