"""RLBench's on-disk demonstrations (PerAct's format), read without importing `rlbench` or `pyrep`.

Layouts (both accepted):

    <task>/all_variations/episodes/episode<i>/{low_dim_obs.pkl, variation_number.pkl, variation_descriptions.pkl}
    <task>/variation<N>/{variation_descriptions.pkl, episodes/episode<i>/low_dim_obs.pkl}

with `<cam>_rgb/<t>.png` and `<cam>_depth/<t>.png` per frame in each episode folder.

Conventions converted here, once:
- `low_dim_obs.pkl` pickles `rlbench.demo.Demo` / `rlbench.backend.observation.Observation` objects: a
  demonstration file is untrusted input, so `SafeUnpickler` maps those two names to plain stand-in classes and
  allows only the numpy names needed to rebuild arrays; any other global is refused.
- Depth PNGs pack the normalised depth d in [0, 1] into 24 bits (R high byte, B low byte), scaled by 2^24 - 1;
  metres are near + d (far - near) with the frame's own near / far planes (`misc`).
- RLBench's camera has negative focal lengths and an x-left, y-up frame: OpenCV's K negates them, and
  cam2world gains a diag(-1, -1, 1, 1) on the right.
- Poses are [x, y, z, qx, qy, qz, qw] (scalar-last). The paper's code passes that quaternion unreordered to a
  scalar-first function (`quaternion="pcm_compat"`, the default: self-consistent, not the true rotation);
  `quaternion="xyzw"` uses the true rotation.
"""

from __future__ import annotations

import codecs
import pickle
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lerobot_obsbench.errors import MissingFileError, ObsBenchError

DEPTH_SCALE = 2**24 - 1
ACTION_SIZE = 11  # position (3, scaled by the task's bounds), 6-D rotation, gripper open, ignore collisions
EPISODE_PATTERN = re.compile(r"episode(\d+)$")
VARIATION_PATTERN = re.compile(r"variation(\d+)$")


# PIL modes of RLBench's own depth PNGs (its generator writes the packed depth as RGB; RGBA is read the same way)
DEPTH_PNG_MODES = ("RGB", "RGBA")
MAX_FAR_M = np.iinfo(np.uint16).max / 1000  # the farthest depth the schema's uint16 millimetres hold


class RLBenchFormatError(ObsBenchError, ValueError):
    """A demonstration that cannot be read: names the file and what is wrong with it."""


# ---- safe unpickling ------------------------------------------------------------------------------------------


class RLBenchRecord:
    """Stand-in for RLBench's pickled classes: pickle restores the instance `__dict__` without calling
    `__init__`, so any fork's fields come through."""


class Demo(RLBenchRecord):
    pass


class Observation(RLBenchRecord):
    pass


def _latin1_encode(text: str, encoding: str = "latin1") -> bytes:
    """Protocol-2 pickles rebuild bytes with `_codecs.encode(text, 'latin1')`; no other codec is allowed."""
    if encoding not in ("latin1", "latin-1") or not isinstance(text, str):
        raise pickle.UnpicklingError(f"_codecs.encode with {encoding!r} is not allowed in an RLBench demo")
    return codecs.encode(text, "latin1")


def _numpy_core(name: str):
    from numpy._core import multiarray

    return getattr(multiarray, name)


ALLOWED_GLOBALS = {
    ("rlbench.demo", "Demo"): lambda: Demo,
    ("rlbench.backend.observation", "Observation"): lambda: Observation,
    # numpy-1 writers name numpy.core, numpy-2 writers numpy._core
    **{
        (module, "_reconstruct"): lambda: _numpy_core("_reconstruct")
        for module in ("numpy.core.multiarray", "numpy._core.multiarray")
    },
    **{
        (module, "scalar"): lambda: _numpy_core("scalar")
        for module in ("numpy.core.multiarray", "numpy._core.multiarray")
    },
    ("numpy", "ndarray"): lambda: np.ndarray,
    ("numpy", "dtype"): lambda: np.dtype,
    ("_codecs", "encode"): lambda: _latin1_encode,
}


class SafeUnpickler(pickle.Unpickler):
    """Unpickles RLBench demonstrations and nothing else: every global outside ALLOWED_GLOBALS is refused."""

    def find_class(self, module: str, name: str):
        allowed = ALLOWED_GLOBALS.get((module, name))
        if allowed is None:
            raise pickle.UnpicklingError(
                f"refusing to load global {module}.{name}: an RLBench demonstration holds only Demo / Observation "
                "objects and numpy arrays"
            )
        return allowed()


def load_pickle(path: Path):
    """Unpickle one RLBench file safely; a missing, truncated, corrupt or malicious file raises
    RLBenchFormatError."""
    if not Path(path).is_file():
        raise RLBenchFormatError(f"{path} missing (every RLBench episode has one)")
    try:
        with open(path, "rb") as f:
            return SafeUnpickler(f, encoding="latin1").load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError) as error:
        raise RLBenchFormatError(f"{path}: cannot read this RLBench pickle ({error})") from error


# ---- layout ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EpisodeRef:
    """One demonstration folder and where its variation and descriptions come from."""

    path: Path
    variation: int | None  # None: read variation_number.pkl in the episode folder
    descriptions: Path  # variation_descriptions.pkl

    @property
    def name(self) -> str:
        return f"{self.path.parent.parent.name}/{self.path.name}"


def _numbered(folder: Path, pattern: re.Pattern) -> list[tuple[int, Path]]:
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if p.is_dir() and (m := pattern.match(p.name))]
    return sorted(found)


def find_episodes(task_dir: Path) -> list[EpisodeRef]:
    """Every episode of one task folder, in either layout, ordered by variation then episode number."""
    task_dir = Path(task_dir)
    if not task_dir.is_dir():
        raise MissingFileError(f"{task_dir} not found (expected <data>/<split>/<task>, e.g. data/train/open_drawer)")
    episodes = [
        EpisodeRef(path, None, path / "variation_descriptions.pkl")
        for _, path in _numbered(task_dir / "all_variations" / "episodes", EPISODE_PATTERN)
    ]
    for number, variation in _numbered(task_dir, VARIATION_PATTERN):
        episodes += [
            EpisodeRef(path, number, variation / "variation_descriptions.pkl")
            for _, path in _numbered(variation / "episodes", EPISODE_PATTERN)
        ]
    if not episodes:
        raise RLBenchFormatError(
            f"{task_dir}: no episodes (expected all_variations/episodes/episode<i>/ or "
            "variation<N>/episodes/episode<i>/ with low_dim_obs.pkl, as PerAct's and RLBench's dataset generators "
            "write them)"
        )
    return episodes


# ---- depth and cameras ----------------------------------------------------------------------------------------


def decode_depth(packed: np.ndarray) -> np.ndarray:
    """Normalised depth d in [0, 1] (H, W) of an RGB-packed depth PNG (H, W, 3) uint8."""
    if packed.ndim != 3 or packed.shape[-1] != 3 or packed.dtype != np.uint8:
        raise RLBenchFormatError(f"an RLBench depth PNG is (H, W, 3) uint8; got {packed.dtype} {packed.shape}")
    rgb = packed.astype(np.int64)
    return (rgb[..., 0] * 65536 + rgb[..., 1] * 256 + rgb[..., 2]) / DEPTH_SCALE


def encode_depth(normalised: np.ndarray) -> np.ndarray:
    """The inverse of `decode_depth`: (H, W) in [0, 1] -> (H, W, 3) uint8 (as RLBench's dataset generator)."""
    n = np.floor(np.clip(normalised, 0.0, 1.0) * DEPTH_SCALE + 0.5).astype(np.int64)
    return np.stack([(n >> 16) & 255, (n >> 8) & 255, n & 255], axis=-1).astype(np.uint8)


def depth_millimetres(normalised: np.ndarray, near: float, far: float) -> np.ndarray:
    """uint16 millimetres (H, W, 1) of normalised depth with the frame's near / far planes (metres)."""
    metres = near + normalised * (far - near)
    return np.clip(np.round(metres * 1000.0), 0, np.iinfo(np.uint16).max).astype(np.uint16)[..., None]


FLIP_XY = np.diag([-1.0, -1.0, 1.0, 1.0])


def rlbench_to_opencv(intrinsics: np.ndarray, extrinsics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV K (positive focal lengths) and cam2world (x right, y down, z forward) of an RLBench camera
    (negative focal lengths; camera -> world with x left, y up)."""
    K = np.array(intrinsics, dtype=np.float64)
    K[0, 0], K[1, 1] = -K[0, 0], -K[1, 1]
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise RLBenchFormatError(f"RLBench intrinsics have negative focal lengths; got fx={-K[0, 0]}, fy={-K[1, 1]}")
    return K, np.asarray(extrinsics, dtype=np.float64) @ FLIP_XY


# ---- poses <-> the paper's 11-d state / action ----------------------------------------------------------------


def _rotation(quaternion: np.ndarray, mode: str) -> Rotation:
    if mode == "xyzw":
        return Rotation.from_quat(quaternion)
    # pcm_compat: the xyzw array read as (w, x, y, z)
    return Rotation.from_quat(np.concatenate([quaternion[..., 1:4], quaternion[..., :1]], axis=-1))


def quaternion_to_6d(quaternion: np.ndarray, mode: str = "pcm_compat") -> np.ndarray:
    """6-D rotation (..., 6): the first two rows of the rotation matrix, as the paper's code."""
    return (
        _rotation(np.asarray(quaternion, dtype=np.float64), mode)
        .as_matrix()[..., :2, :]
        .reshape(*np.shape(quaternion)[:-1], 6)
    )


def rotation_6d_to_quaternion(rotation_6d: np.ndarray, mode: str = "pcm_compat") -> np.ndarray:
    """The unit quaternion ([qx, qy, qz, qw] as RLBench takes it) of 6-D rotations (..., 6), by Gram-Schmidt."""
    rows = np.asarray(rotation_6d, dtype=np.float64).reshape(*np.shape(rotation_6d)[:-1], 2, 3)
    b1 = rows[..., 0, :] / np.linalg.norm(rows[..., 0, :], axis=-1, keepdims=True)
    a2 = rows[..., 1, :] - (b1 * rows[..., 1, :]).sum(-1, keepdims=True) * b1
    b2 = a2 / np.linalg.norm(a2, axis=-1, keepdims=True)
    matrix = np.stack([b1, b2, np.cross(b1, b2)], axis=-2)
    xyzw = Rotation.from_matrix(matrix).as_quat()
    if mode == "xyzw":
        return xyzw
    return np.concatenate([xyzw[..., 3:4], xyzw[..., :3]], axis=-1)  # back to the array the 6-D came from


def encode_pose(
    pose: np.ndarray, gripper_open, ignore_collisions, low, high, quaternion: str = "pcm_compat"
) -> np.ndarray:
    """The paper's 11-d vector(s): position scaled by the task's bounds to (p - lo) / (hi - lo) * 2 - 1, 6-D
    rotation, gripper open, ignore collisions. `pose` (..., 7) is [x, y, z, qx, qy, qz, qw]."""
    pose = np.asarray(pose, dtype=np.float64)
    low, high = np.asarray(low), np.asarray(high)
    position = (pose[..., :3] - low) / (high - low) * 2 - 1
    quat = pose[..., 3:7] / np.linalg.norm(pose[..., 3:7], axis=-1, keepdims=True)
    extra = np.stack(np.broadcast_arrays(np.asarray(gripper_open, float), np.asarray(ignore_collisions, float)), -1)
    return np.concatenate([position, quaternion_to_6d(quat, quaternion), extra], axis=-1).astype(np.float32)


def decode_action(action: np.ndarray, low, high, quaternion: str = "pcm_compat") -> np.ndarray:
    """RLBench's 9-d action [x, y, z, qx, qy, qz, qw, gripper open, ignore collisions] of the 11-d vector:
    position unscaled, a unit quaternion, both flags thresholded at 0.5."""
    action = np.asarray(action, dtype=np.float64)
    low, high = np.asarray(low), np.asarray(high)
    position = (action[..., :3] + 1) / 2 * (high - low) + low
    quat = rotation_6d_to_quaternion(action[..., 3:9], quaternion)
    flags = (action[..., 9:11] > 0.5).astype(np.float64)
    return np.concatenate([position, quat, flags], axis=-1)


# ---- one episode ----------------------------------------------------------------------------------------------


@dataclass
class RLBenchEpisode:
    """One demonstration, read: per-frame observations (stand-ins) and its language."""

    ref: EpisodeRef
    observations: list
    variation: int
    descriptions: list[str]
    random_seed: object = field(default=None, repr=False)


def read_episode(ref: EpisodeRef) -> RLBenchEpisode:
    """Unpickle an episode's low-dim file, variation and descriptions (RLBenchFormatError names what failed)."""
    demo = load_pickle(ref.path / "low_dim_obs.pkl")
    observations = getattr(demo, "_observations", None)
    if not isinstance(demo, Demo) or not isinstance(observations, list) or not observations:
        raise RLBenchFormatError(f"{ref.path / 'low_dim_obs.pkl'}: not an RLBench Demo with observations")
    variation = ref.variation
    if variation is None:
        variation = load_pickle(ref.path / "variation_number.pkl")
    descriptions = load_pickle(ref.descriptions) if ref.descriptions.is_file() else None
    if not isinstance(descriptions, list) or not descriptions or not all(isinstance(d, str) for d in descriptions):
        raise RLBenchFormatError(f"{ref.descriptions}: expected a non-empty list of variation descriptions")
    return RLBenchEpisode(ref, observations, int(variation), descriptions, getattr(demo, "random_seed", None))


def camera_frame(ref: EpisodeRef, observation, camera: str, t: int) -> dict[str, np.ndarray]:
    """The schema's arrays of camera `camera` at frame t: rgb (H, W, 3) uint8, depth (H, W, 1) uint16 mm, K and
    cam2world."""
    from PIL import Image

    rgb_path, depth_path = ref.path / f"{camera}_rgb" / f"{t}.png", ref.path / f"{camera}_depth" / f"{t}.png"
    for path in (rgb_path, depth_path):
        if not path.is_file():
            raise RLBenchFormatError(f"{path} missing (every frame needs {camera}_rgb and {camera}_depth PNGs)")
    try:
        rgb = np.asarray(Image.open(rgb_path).convert("RGB"))
        with Image.open(depth_path) as depth_png:
            if depth_png.mode not in DEPTH_PNG_MODES:  # converting would read gray levels as packed depth
                raise RLBenchFormatError(
                    f"{depth_path}: a {depth_png.mode} PNG; RLBench's depth PNGs are 8-bit RGB, the depth packed "
                    "into the three channels by its generator (a 1-channel or 16-bit depth image, as other "
                    "exporters write, is not RLBench's format: regenerate the episodes with RLBench's tools)"
                )
            packed = np.asarray(depth_png.convert("RGB"))
    except (OSError, SyntaxError, ValueError) as error:  # PIL raises SyntaxError for a broken PNG stream
        raise RLBenchFormatError(f"{ref.path}: frame {t} of {camera}: unreadable PNG ({error})") from error
    if rgb.shape[:2] != packed.shape[:2]:
        raise RLBenchFormatError(f"{rgb_path}: colour {rgb.shape[:2]} and depth {packed.shape[:2]} differ in size")
    try:
        return camera_views(rgb, decode_depth(packed), getattr(observation, "misc", None) or {}, camera)
    except RLBenchFormatError as error:
        raise RLBenchFormatError(f"{ref.path}: frame {t}: {error}") from error


def camera_views(rgb: np.ndarray, normalised_depth: np.ndarray, misc: dict, camera: str) -> dict[str, np.ndarray]:
    """Schema arrays of one camera from RLBench's colour, normalised depth and `misc` camera parameters (the
    importer's PNGs and a live observation alike)."""
    try:
        near, far = float(misc[f"{camera}_camera_near"]), float(misc[f"{camera}_camera_far"])
        K, cam2world = rlbench_to_opencv(misc[f"{camera}_camera_intrinsics"], misc[f"{camera}_camera_extrinsics"])
    except KeyError as error:
        raise RLBenchFormatError(
            f"no {error.args[0]} in the observation's misc (RLBench records it with the camera enabled)"
        ) from error
    if not 0 <= near < far <= MAX_FAR_M:  # the depth's scale: a wrong plane rescales every point silently
        raise RLBenchFormatError(
            f"{camera}_camera_near = {near:g} m and {camera}_camera_far = {far:g} m in the observation's misc: "
            f"expected 0 <= near < far <= {MAX_FAR_M:g} (RLBench's front camera: 0.01 and 4.5); the episode's "
            "misc is damaged"
        )
    return {"rgb": rgb, "depth": depth_millimetres(normalised_depth, near, far), "K": K, "cam2world": cam2world}


def low_dim(observation) -> tuple[np.ndarray, float, float]:
    """gripper_pose [x, y, z, qx, qy, qz, qw], gripper_open and ignore_collisions (0 where the fork lacks it)."""
    pose = np.asarray(getattr(observation, "gripper_pose", None), dtype=np.float64)
    if pose.shape != (7,):
        raise RLBenchFormatError(f"an observation's gripper_pose has shape {pose.shape}, expected (7,)")
    ignore = getattr(observation, "ignore_collisions", 0.0)
    return pose, float(observation.gripper_open), float(np.asarray(ignore if ignore is not None else 0.0))
