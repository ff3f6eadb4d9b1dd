"""The plugin's shared vocabulary: observation spaces and their inputs, the dataset schema, its
validator, the point-cloud container, and the env <-> policy passthrough codec.

Every other module takes these names from here; this module imports nothing of the plugin.

One LeRobotDataset stores raw sensor frames; every observation space is derived from them:

| key                              | dtype, shape           | meaning                                        |
|----------------------------------|------------------------|------------------------------------------------|
| observation.images.<cam>         | video/image (H, W, 3)  | colour                                         |
| observation.depth.<cam>          | uint16 (H, W, 1)       | depth along the optical axis, mm, 0 = invalid  |
| observation.intrinsics.<cam>     | float32 (3, 3)         | OpenCV K                                       |
| observation.cam2world.<cam>      | float32 (4, 4)         | OpenCV camera -> world                         |
| observation.state                | float32 (D,)           | joints + gripper; last 7 = EE xyz + quat wxyz  |
| observation.environment_state    | float32 (G,)           | task goal (optional)                           |
| observation.privileged_state     | float32 (7 * O,)       | simulation only: the task's object poses, xyz + |
|                                  |                        | quat wxyz each (the `state` oracle's input)    |
| action                           | float32 (A,)           | e.g. pd_ee_delta_pose                          |
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_PREFIX, OBS_STATE
from torch import Tensor

from lerobot_obsbench.errors import ConfigError, ObsBenchError

# The plugin's LeRobot policy types (`--policy.type`).
POLICY_TYPES = ("obs_act", "obs_diffusion")

# ---- observation spaces and their design choices ---------------------------------------------------------

# Per-point features of a point cloud, with their channel counts.
POINT_FEATURES = {"rgb+xyz": 6, "xyz": 3, "rgb": 3}
DEFAULT_POINT_FEATURES = "rgb+xyz"  # the paper's
# Frames point coordinates can be expressed in: world (robot base), the first camera, the end effector.
FRAMES = ("world", "camera", "ee")
# Where the point tokenizer's FPS + kNN grouping sits: after the backbone (paper default) or before it.
SAMPLING = ("post", "pre")
# How depth images and pointmap coordinates are scaled: clipped to a range and mapped to [-1, 1] ("clip"), or as
# the official code does ("official": (metres - 0.5) / 0.5, unclipped).
DEPTH_NORMALIZATIONS = ("clip", "official")
# Point-cloud sampling details: the plugin's (deterministic voxel point and FPS start at evaluation) or the
# official code's ("official": a random point per voxel also at evaluation, points shuffled in training so FPS
# starts anywhere, tokenizer BatchNorm as the official code's).
POINT_PIPELINES = ("plugin", "official")
# How the xyz channels of point features are scaled: raw metres (the paper's code), or to [-1, 1] over the
# workspace box ("box": DP3's code scales its clouds to [-1, 1] with the data's limits; the crop box is that limit).
# Point positions (FPS, kNN, position embeddings) stay in metres either way.
POINT_NORMALIZATIONS = ("metres", "box")
# How an RLBench [qx, qy, qz, qw] becomes a rotation: as the paper's code reads it (as w, x, y, z), or truly.
QUATERNION_MODES = ("pcm_compat", "xyzw")

# The repo id a local dataset is opened under: LeRobot's loaders ask for one even when they read a dataset from
# its folder, and the grids open their recorded demonstrations under this one.
LOCAL_REPO_ID = "local/obsbench"

STATE_KEY = OBS_STATE
ENV_STATE_KEY = OBS_ENV_STATE
ACTION_KEY = ACTION
IMAGE_PREFIX = OBS_IMAGES + "."
DEPTH_PREFIX = OBS_PREFIX + "depth."
INTRINSICS_PREFIX = OBS_PREFIX + "intrinsics."
CAM2WORLD_PREFIX = OBS_PREFIX + "cam2world."
SENSOR_PREFIXES = (IMAGE_PREFIX, DEPTH_PREFIX, INTRINSICS_PREFIX, CAM2WORLD_PREFIX)
EE_POSE_SIZE = 7  # xyz + quaternion (w, x, y, z)
# The simulator's object poses (7 values per object); taken out of every policy's input features like the
# sensors, so only the oracle reads it.
PRIVILEGED_STATE_KEY = OBS_PREFIX + "privileged_state"
POSE_SIZE = 7
# The names of one object's POSE_SIZE values in observation.privileged_state (LeRobot feature names
# `<object>.<component>`), so a checkpoint knows which objects its oracle input describes.
POSE_COMPONENTS = ("x", "y", "z", "qw", "qx", "qy", "qz")
# The smallest camera frame (pixels, square) every stage handles: LeRobot's AV1 video encoder (SVT-AV1) fails on
# smaller frames, after the simulation has run; so demos, grids and envs refuse it up front.
MIN_IMAGE_SIZE = 32


@dataclass(frozen=True)
class Space:
    """An observation space: what a policy sees, read per camera, and what applies to it. Registered once
    (`register_space`); every consumer asks the record (`space_info(name)`), never a list of names. A fused space
    is its parts (`fused_space`), its properties theirs."""

    name: str
    # per-camera sensors it reads (dataset key prefixes); the controls read none
    sensors: tuple[str, ...] = ()
    # channels of the image an image encoder gets (0: no image of its own)
    image_channels: int = 0
    # whether its input includes an image (so it has a frame size and image augmentations apply)
    image: bool = False
    # whether that image carries colour (colour augmentations apply)
    colour: bool = False
    # whether that image carries a depth or xyz channel (`depth_normalization` applies)
    depth: bool = False
    # whether its input holds 3-D positions unprojected from depth (`frame` expresses them)
    positions: bool = False
    # whether its input is a point cloud (a crop box, the point-cloud choices, point augmentations)
    points: bool = False
    # "blind" or "oracle" for the encoder-free controls (beyond the paper); "" for a sensor space
    control: str = ""
    # a fused space's parts, in the order their encoders are named ("a+b"); () for a single space
    parts: tuple[str, ...] = ()

    @property
    def fused(self) -> bool:
        return bool(self.parts)


_SPACES: dict[str, Space] = {}


def register_space(space: Space) -> Space:
    """Add `space` to the vocabulary (a name registered twice is refused)."""
    if space.name in _SPACES:
        raise ConfigError(f"an observation space named {space.name!r} is already registered")
    if space.control and (space.sensors or space.image or space.points):
        raise ConfigError(f"obs_space {space.name!r}: a control reads no sensor")
    _SPACES[space.name] = space
    return space


def fused_space(*parts: str) -> Space:
    """The fused space of registered single sensor spaces (beyond the paper): each part's input through its own
    encoder, their tokens (ACT) or features (Diffusion Policy) side by side in one condition; named "a+b"."""
    records = [space_info(p) for p in parts]
    if len(records) < 2 or any(r.fused or r.control for r in records):
        raise ConfigError(f"a fused space joins two or more single sensor spaces; got {'+'.join(parts)!r}")
    return Space(
        name="+".join(parts),
        sensors=tuple(dict.fromkeys(prefix for r in records for prefix in r.sensors)),
        image=any(r.image for r in records),
        colour=any(r.colour for r in records),
        depth=any(r.depth for r in records),
        positions=any(r.positions for r in records),
        points=any(r.points for r in records),
        parts=tuple(parts),
    )


def space_info(name: str) -> Space:
    """The registered space named `name`; a SchemaError naming the choices otherwise."""
    if name not in _SPACES:
        raise SchemaError(f"Unknown obs_space {name!r}; choose one of {', '.join(_SPACES)}.")
    return _SPACES[name]


def available_spaces(where=None) -> tuple[str, ...]:
    """Names of the registered spaces, in registration order; `where(space)`: only those it accepts."""
    return tuple(name for name, space in _SPACES.items() if where is None or where(space))


# The paper's spaces: rgb, metric depth, rgb ‖ depth, rgb ‖ xyz (a pointmap), a point cloud.
register_space(Space("rgb", (IMAGE_PREFIX,), image_channels=3, image=True, colour=True))
register_space(Space("depth", (DEPTH_PREFIX,), image_channels=1, image=True, depth=True))
register_space(Space("rgbd", (IMAGE_PREFIX, DEPTH_PREFIX), image_channels=4, image=True, colour=True, depth=True))
register_space(
    Space("pointmap", SENSOR_PREFIXES, image_channels=6, image=True, colour=True, depth=True, positions=True)
)
register_space(Space("pointcloud", SENSOR_PREFIXES, positions=True, points=True))
register_space(fused_space("rgb", "pointcloud"))
# The blind control: the same proprioception and goal, no visual observation at all.
register_space(Space("none", control="blind"))
# The oracle control: the same policy given the simulator's object poses instead of a sensor, an upper bound on
# what any observation can give. Only simulated demos record it.
register_space(Space("state", control="oracle"))


class SchemaError(ObsBenchError, ValueError):
    """A dataset or batch does not provide what the chosen observation space needs."""


def check_choice(name: str, value: str, choices) -> str:
    """`value` if it is one of `choices`, else a ValueError naming the field and the valid values."""
    if value not in choices:
        raise ConfigError(f"Unknown {name} {value!r}; choose one of {', '.join(choices)}.")
    return value


def single_spaces(where) -> tuple[str, ...]:
    """Names of the registered single (unfused) spaces `where(space)` accepts: what an encoder of one input
    declares it encodes (a fused space pairs encoders of its parts)."""
    return available_spaces(lambda space: not space.fused and where(space))


def check_obs_space(name: str) -> str:
    return space_info(name).name


def space_parts(name: str) -> tuple[str, ...]:
    """The spaces whose inputs `name` gives: its parts for a fused space, itself otherwise."""
    return space_info(name).parts or (name,)


def is_control(name: str) -> bool:
    """Whether `name` is an encoder-free control (blind or oracle), which reads no camera."""
    return bool(space_info(name).control)


def reads_points(name: str) -> bool:
    """Whether the space's input includes a point cloud (so it has a crop box and the point-cloud choices)."""
    return space_info(name).points


def reads_images(name: str) -> bool:
    """Whether the space's input includes images (so it has a frame size)."""
    return space_info(name).image


def has_positions(name: str) -> bool:
    """Whether the space's input holds 3-D positions, which `frame` expresses (point clouds, pointmaps)."""
    return space_info(name).positions


def input_channels(name: str, point_features: str = DEFAULT_POINT_FEATURES) -> int:
    """Channels the encoder receives: image channels, per-point feature size for point clouds, 0 when blind."""
    space = space_info(name)
    if space.points and not space.fused:
        return POINT_FEATURES[check_choice("point_features", point_features, POINT_FEATURES)]
    return space.image_channels


@dataclass
class PointCloud:
    """A batch of padded point clouds: what the adapter gives point encoders."""

    xyz: Tensor  # (B, N, 3) metres in the chosen frame
    features: Tensor  # (B, N, C)
    mask: Tensor  # (B, N) True for real points


# ---- dataset keys ----------------------------------------------------------------------------------------


def image_key(cam: str) -> str:
    return IMAGE_PREFIX + cam


def depth_key(cam: str) -> str:
    return DEPTH_PREFIX + cam


def intrinsics_key(cam: str) -> str:
    return INTRINSICS_PREFIX + cam


def cam2world_key(cam: str) -> str:
    return CAM2WORLD_PREFIX + cam


def points_carry_colour(point_features: str) -> bool:
    """Whether points with `point_features` ("rgb+xyz", "xyz", "rgb") carry their pixel's colour."""
    return "rgb" in check_choice("point_features", point_features, POINT_FEATURES).split("+")


def read_sensors(obs_space: str, point_features: str = DEFAULT_POINT_FEATURES) -> tuple[str, ...]:
    """The per-camera sensors a policy on `obs_space` reads: its space's, but no colour where only a point cloud
    would take it and its points carry none (`point_features` without rgb), so no colour is rendered or decoded
    that no input uses."""
    space = space_info(obs_space)
    point_colour = points_carry_colour(point_features)
    parts = [space_info(part) for part in space.parts] or [space]
    colour = any(IMAGE_PREFIX in part.sensors and (point_colour or not part.points) for part in parts)
    return tuple(prefix for prefix in space.sensors if prefix != IMAGE_PREFIX or colour)


def sensor_keys(
    obs_space: str, cameras: list[str] | tuple[str, ...], point_features: str = DEFAULT_POINT_FEATURES
) -> list[str]:
    """Dataset keys a policy on an observation space reads (`read_sensors`), camera by camera."""
    return [prefix + cam for cam in cameras for prefix in read_sensors(obs_space, point_features)]


def is_sensor_key(key: str) -> bool:
    """Whether a key is read by the observation adapter rather than LeRobot's normaliser: the per-camera sensors and
    the oracle's privileged state."""
    return key.startswith(SENSOR_PREFIXES) or key == PRIVILEGED_STATE_KEY


def prefix_of(key: str) -> str:
    return next(p for p in SENSOR_PREFIXES if key.startswith(p))


def cameras_in(features: Mapping[str, object]) -> list[str]:
    """Camera names found in a feature dictionary (any sensor prefix), in first-seen order."""
    cams: list[str] = []
    for key in features:
        for prefix in SENSOR_PREFIXES:
            if key.startswith(prefix) and key[len(prefix) :] not in cams:
                cams.append(key[len(prefix) :])
    return cams


# ---- LeRobot's own depth recordings -----------------------------------------------------------------------
# LeRobot 0.6 records a RealSense's depth as `observation.images.<cam>_depth` (`info.is_depth_map`; a 1-channel
# video or 16-bit image, read back as float millimetres (1, H, W)), in the depth camera's own pixels and with no
# intrinsics or pose. With the camera's calibration attached (camera_calibration.py) it serves every space:
# `with_calibrated_depth` stands in the schema keys the policy derives from it (depth registered into the colour
# camera, K, cam2world).
STOCK_DEPTH_SUFFIX = "_depth"
ATTACH_CALIBRATION_HINT = (
    "attach the camera's calibration to the dataset first: obsbench attach-calibration --root DATASET --camera {cam} "
    "(--from-recording FILE.bag | --serial SERIAL | --from-json FILE) --cam2world FILE "
    "(docs/real-robot.md: datasets recorded by stock lerobot-record)"
)


def stock_depth_key(cam: str) -> str:
    return IMAGE_PREFIX + cam + STOCK_DEPTH_SUFFIX


def is_stock_depth(key: str, feature: object) -> bool:
    """Whether a feature is LeRobot's own depth map: `observation.images.<cam>_depth` flagged `is_depth_map`
    (dataset features), or of one channel (policy features, which carry no flags)."""
    if not (key.startswith(IMAGE_PREFIX) and key.endswith(STOCK_DEPTH_SUFFIX)):
        return False
    if isinstance(feature, Mapping) and isinstance(feature.get("info"), Mapping):
        return bool(feature["info"].get("is_depth_map") or feature["info"].get("video.is_depth_map"))
    shape = _shape(feature)
    return len(shape) == 3 and 1 in (shape[0], shape[-1]) and 3 not in (shape[0], shape[-1])


def stock_depth_cameras(features: Mapping[str, object]) -> list[str]:
    """Cameras recorded with LeRobot's own depth feature."""
    return [
        key.removeprefix(IMAGE_PREFIX).removesuffix(STOCK_DEPTH_SUFFIX)
        for key, ft in features.items()
        if is_stock_depth(key, ft)
    ]


def with_calibrated_depth(features: Mapping[str, object], calibration: Mapping[str, Mapping]) -> dict:
    """`features` as the policy sees them once LeRobot's depth maps are registered: each calibrated camera's
    stock depth key is replaced by the schema's depth (at the colour resolution), intrinsics and cam2world keys;
    an uncalibrated one is dropped (it is not a colour camera)."""
    out = {}
    for key, ft in features.items():
        if not is_stock_depth(key, ft):
            out[key] = ft
            continue
        cam = key.removeprefix(IMAGE_PREFIX).removesuffix(STOCK_DEPTH_SUFFIX)
        if cam in calibration:
            height, width = calibration[cam]["color_size"]
            out[depth_key(cam)] = {"dtype": "int32", "shape": (height, width, 1)}
            out[intrinsics_key(cam)] = {"dtype": "float32", "shape": (3, 3)}
            out[cam2world_key(cam)] = {"dtype": "float32", "shape": (4, 4)}
    return out


# ---- validation of LeRobot feature dictionaries ----------------------------------------------------------


def _shape(ft: object) -> tuple[int, ...]:
    shape = ft["shape"] if isinstance(ft, Mapping) else ft.shape
    return tuple(int(s) for s in shape)


def _dtype(ft: object) -> str | None:
    return ft.get("dtype") if isinstance(ft, Mapping) else None


def _expected(prefix: str, shape: tuple[int, ...]) -> tuple[bool, str]:
    if prefix == IMAGE_PREFIX:
        ok = len(shape) == 3 and 3 in (shape[0], shape[-1])
        return ok, "(H, W, 3) colour image or video"
    if prefix == DEPTH_PREFIX:
        ok = len(shape) == 3 and shape[-1] == 1
        return ok, "(H, W, 1) uint16 depth in millimetres (channel-last, 0 = invalid)"
    if prefix == INTRINSICS_PREFIX:
        return shape == (3, 3), "(3, 3) float32 OpenCV intrinsics K"
    return shape == (4, 4), "(4, 4) float32 OpenCV camera -> world transform"


def validate_features(
    features: Mapping[str, object],
    obs_space: str,
    cameras: list[str] | tuple[str, ...] | None = None,
    calibration: Mapping[str, Mapping] | None = None,
) -> list[str]:
    """Check that `features` (a LeRobot dataset `features` dict or policy features) serve `obs_space`;
    `calibration` (camera -> CameraCalibration fields) makes LeRobot's own depth maps count as depth.

    Returns the cameras used (all cameras that have the needed keys when `cameras` is None; none for the blind
    space). Raises `SchemaError` naming every missing or mis-shaped key and how to fix it.
    """
    check_obs_space(obs_space)
    if space_info(obs_space).control == "oracle" and PRIVILEGED_STATE_KEY not in features:
        raise SchemaError(ORACLE_HINT.format(obs_space=obs_space))
    needed = space_info(obs_space).sensors
    if not needed:
        return []
    recorded = sorted(k for k in features if k.startswith(OBS_PREFIX))  # LeRobot's depth maps included
    uncalibrated = stock_depth_cameras(features)
    features = with_calibrated_depth(features, calibration or {})
    uncalibrated = [c for c in uncalibrated if depth_key(c) not in features] if DEPTH_PREFIX in needed else []
    if cameras is None or len(cameras) == 0:
        cameras = [c for c in cameras_in(features) if all(p + c in features for p in needed)]
        if not cameras and uncalibrated:
            raise _uncalibrated(obs_space, uncalibrated[0])
        if not cameras:
            # the policy's read declaration (lerobot-train) passes the features with an uncalibrated LeRobot depth
            # map already left out, so the way to calibrate one is named wherever depth is needed
            calibrate = (
                f"; for LeRobot's own depth recording ({stock_depth_key('<cam>')}) "
                + ATTACH_CALIBRATION_HINT.format(cam="CAM")
                if DEPTH_PREFIX in needed
                else ""
            )
            raise SchemaError(
                f"obs_space={obs_space!r} needs, for at least one camera <cam>, the keys "
                f"{', '.join(p + '<cam>' for p in needed)}; the dataset has {recorded}. Record them with the "
                f"frames (see the schema in lerobot_obsbench/schema.py){calibrate}; or pick an observation space the "
                "dataset supports."
            )
    for cam in cameras:
        if cam in uncalibrated:
            raise _uncalibrated(obs_space, cam)
    problems = []
    for cam in cameras:
        for prefix in needed:
            key = prefix + cam
            if key not in features:
                problems.append(f"missing key {key!r}")
                continue
            ok, what = _expected(prefix, _shape(features[key]))
            if not ok:
                problems.append(f"{key!r} has shape {_shape(features[key])}, expected {what}")
            dtype = _dtype(features[key])
            if prefix == DEPTH_PREFIX and dtype is not None and dtype not in ("uint16", "uint32", "int32", "int64"):
                problems.append(f"{key!r} has dtype {dtype}, expected uint16 millimetres")
    if problems:
        raise SchemaError(
            f"Dataset does not fit obs_space={obs_space!r} with cameras {list(cameras)}: "
            + "; ".join(problems)
            + ". Fix the recording (schema: lerobot_obsbench/schema.py) or choose --policy.obs_space / "
            "--policy.cameras accordingly."
        )
    return list(cameras)


ORACLE_HINT = (
    f"obs_space={{obs_space!r}} is the oracle control: it reads {PRIVILEGED_STATE_KEY} (the simulator's object "
    "poses), which only simulated demonstrations record (obsbench demos). A real recording cannot have it: compare "
    "real-robot spaces against the blind control obs_space='none'."
)


def _uncalibrated(obs_space: str, cam: str) -> SchemaError:
    return SchemaError(
        f"obs_space={obs_space!r} needs the calibration of camera {cam!r}: {stock_depth_key(cam)} is LeRobot's own "
        "depth recording (depth-camera pixels, no intrinsics or pose); " + ATTACH_CALIBRATION_HINT.format(cam=cam) + "."
    )


def camera_resolution(
    features: Mapping[str, object], obs_space: str, cameras: list[str], calibration: Mapping | None = None
) -> list[int]:
    """(height, width) of the first camera's frames (colour, else depth), as the policy was trained on; empty when
    the space reads no camera."""
    if not cameras:
        return []
    features = with_calibrated_depth(features, calibration or {})
    cam = cameras[0]
    for key in (image_key(cam), depth_key(cam)):
        if key in features and prefix_of(key) in space_info(obs_space).sensors:
            return list(frame_size(key, features[key]))
    return []


def frame_size(key: str, feature: object) -> tuple[int, int]:
    """(height, width) of a colour or depth feature, channel-first (policy features) or channel-last (dataset)."""
    shape = _shape(feature)
    channel_first = key.startswith(IMAGE_PREFIX) and shape[0] == 3 and shape[-1] != 3
    return (shape[1], shape[2]) if channel_first else (shape[0], shape[1])


# ---- policy <-> env (or robot) compatibility ---------------------------------------------------------------


def compatibility_problems(
    config,
    cameras: list[str] | tuple[str, ...] | None,
    resolution: tuple[int, int] | list[int] | None,
    state_dim: int | None,
    action_dim: int | None,
    objects: list[str] | tuple[str, ...] | None = None,
) -> list[str]:
    """What a policy `config` (the plugin's: `cameras`, `camera_resolution`, state and action features) needs and
    an observation source does not give; one phrase per problem, each naming the flag that fixes it.

    Every evaluation path (obsbench eval, stock lerobot-eval, real-robot rollouts) checks with this, so a
    mismatch reads the same everywhere. A `None` argument is not checked."""
    problems = []
    wanted = list(getattr(config, "cameras", None) or [])
    missing = [c for c in wanted if cameras is not None and c not in cameras]
    if missing:
        problems.append(f"the policy reads cameras {wanted} but the env renders {list(cameras)} (--env.cameras)")
    trained = list(getattr(config, "camera_resolution", None) or [])
    if trained and resolution is not None and list(resolution) != trained:
        problems.append(
            f"the policy was trained on {trained[0]}x{trained[1]} frames but the env renders "
            f"{resolution[0]}x{resolution[1]} (--env.image_size={trained[0]})"
        )
    state = config.robot_state_feature
    if state is not None and state_dim is not None and state.shape[0] != state_dim:
        problems.append(f"the policy expects observation.state of size {state.shape[0]}, the env gives {state_dim}")
    problems += oracle_problems(config, objects)
    action = config.action_feature
    if action is not None and action_dim is not None and action.shape[0] != action_dim:
        problems.append(
            f"the policy outputs {action.shape[0]}-D actions but the env's controller takes {action_dim} "
            "(--env.control_mode)"
        )
    return problems


def privileged_state_names(objects: list[str] | tuple[str, ...]) -> list[str]:
    """LeRobot feature names of observation.privileged_state for `objects`' poses, in order."""
    return [f"{name}.{component}" for name in objects for component in POSE_COMPONENTS]


def privileged_state_objects(names: list[str]) -> list[str]:
    """The objects whose poses `privileged_state_names` named, in order."""
    return list(dict.fromkeys(name.rsplit(".", 1)[0] for name in names))


def oracle_problems(config, objects: list[str] | tuple[str, ...] | None) -> list[str]:
    """Whether an oracle policy's object poses are the task's `objects` (None: not checked): the objects it was
    trained on where the checkpoint names them, else the number of values."""
    if objects is None or getattr(config, "obs_space", None) not in available_spaces(lambda s: s.control == "oracle"):
        return []
    trained = privileged_state_objects(list(getattr(config, "privileged_state_names", None) or []))
    if trained and trained != list(objects):
        return [
            f"the oracle policy was trained on the poses of {trained} but this task gives the poses of "
            f"{list(objects)} (evaluate it on a task with those objects, in that order)"
        ]
    width = getattr(config, "privileged_state_dim", 0)
    if width and width != len(objects) * POSE_SIZE:
        return [
            f"the oracle policy reads {width} object-pose values ({width // POSE_SIZE} objects) but this task gives "
            f"{len(objects) * POSE_SIZE} ({list(objects)})"
        ]
    return []


def check_compatibility(config, cameras=None, resolution=None, state_dim=None, action_dim=None, objects=None) -> None:
    """Raise `SchemaError` listing every `compatibility_problems`."""
    problems = compatibility_problems(config, cameras, resolution, state_dim, action_dim, objects)
    if problems:
        raise SchemaError("Policy and env do not match: " + "; ".join(problems) + ".")


# ---- the env <-> policy passthrough ----------------------------------------------------------------------
# Stock lerobot-eval's `preprocess_observation` keeps only `pixels`, `agent_pos`, `environment_state` and the
# nested `robot_state` dict; the OBSBench env therefore sends depth, intrinsics and cam2world inside
# `robot_state` under their schema names without the "observation." prefix.
ENV_PASSTHROUGH_KEY = OBS_PREFIX + "robot_state"


def frame_to_env_observation(frame: Mapping[str, object]) -> dict:
    """Schema-keyed frame -> the env observation dict lerobot-eval understands."""
    out: dict = {"pixels": {}, "robot_state": {}}
    for key, value in frame.items():
        if key.startswith(IMAGE_PREFIX):
            out["pixels"][key.removeprefix(IMAGE_PREFIX)] = value
        elif key == STATE_KEY:
            out["agent_pos"] = value
        elif key == ENV_STATE_KEY:
            out["environment_state"] = value
        else:
            out["robot_state"][key.removeprefix(OBS_PREFIX)] = value
    return out


def env_observation_to_frame(obs: Mapping[str, object]) -> dict:
    """Inverse of `frame_to_env_observation` (e.g. to record what an env returned)."""
    frame = {IMAGE_PREFIX + cam: img for cam, img in obs.get("pixels", {}).items()}
    if "agent_pos" in obs:
        frame[STATE_KEY] = obs["agent_pos"]
    if "environment_state" in obs:
        frame[ENV_STATE_KEY] = obs["environment_state"]
    frame.update({OBS_PREFIX + name: v for name, v in obs.get("robot_state", {}).items()})
    return frame


def unpack_passthrough(batch: dict) -> dict:
    """Policy side: move `observation.robot_state` entries (after lerobot-eval's preprocessing) to their
    schema keys. Batches without the passthrough (training) are returned unchanged."""
    nested = batch.get(ENV_PASSTHROUGH_KEY)
    if not isinstance(nested, Mapping):
        return batch
    out = {k: v for k, v in batch.items() if k != ENV_PASSTHROUGH_KEY}
    out.update({OBS_PREFIX + name: v for name, v in nested.items()})
    return out
