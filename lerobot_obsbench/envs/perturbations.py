"""Zero-shot evaluation perturbations (paper §5.3, and a real depth sensor's noise), applied to the env without new
demonstrations, with the same names and meaning on every task family that supports them.

A perturbation is written `kind:value` (grid files, `--env.perturbation`):

- `camera_yaw:DEG` / `camera_pitch:DEG` — every scene camera moves on a circle about its look-at point,
  horizontally (about the world z axis) or vertically (towards / away from the table), keeping its distance,
  target and intrinsics. The paper uses 5 and 10 degrees.
- `light:I` — the scene's light at intensity I against the default 0.3 (ManiSkill's ambient light): ManiSkill's
  ambient light is set to I and its directional lights scaled by I / 0.3; Meta-World's lights (three directional
  ones and the headlight) are all scaled by I / 0.3, so `light:0.3` is each scene as its simulator lights it. The
  paper tries 0.03 ... 3.
- `background:R,G,B` — the table top and the floor take this flat colour (0..1) instead of their texture; the
  paper varies the red and green channels over 0.2 / 0.6 / 1.0.
- `noise:SPP` — render with ray tracing at SPP samples per pixel and no denoiser (the paper: 2, 16, 32, 64),
  which leaves Monte-Carlo noise in the colour image. ManiSkill only; slow on a CPU renderer.
- `depth_noise:L` — every depth image as a stereo depth camera reports it (`lerobot_obsbench/depth_noise.py`: axial
  noise growing with the square of the distance, holes beside near edges and at random, millimetre steps), at
  level L (1: a RealSense D415 by its datasheet; 2: twice its disparity error and random holes). It changes what
  spaces built from depth see (depth, rgbd, pointmap, point clouds) and nothing else; the noise of an episode is
  drawn from its seed.

`none` is the unperturbed env. A kind is a `PerturbationKind` record: its form, its numbers' range, its nominal
value (where a generalization curve places the unperturbed scene) and which spaces it can change; each task family
names the kinds its env applies (`MANISKILL_KINDS`, `METAWORLD_KINDS`), and `check_supported` refuses the others
before anything slow starts.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lerobot_obsbench.depth_noise import MAX_LEVEL, noisy_depth
from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.schema import (
    DEFAULT_POINT_FEATURES,
    DEPTH_PREFIX,
    IMAGE_PREFIX,
    depth_key,
    intrinsics_key,
    is_control,
    read_sensors,
)

DEFAULT_AMBIENT = 0.3


def _camera_angle(value: tuple[float, ...]) -> str | None:
    return "camera angles must be within +-80 degrees" if abs(value[0]) >= 80 else None


def _light(value: tuple[float, ...]) -> str | None:
    return "light must be >= 0" if value[0] < 0 else None


def _rgb(value: tuple[float, ...]) -> str | None:
    return "colours must be in [0, 1]" if not all(0 <= v <= 1 for v in value) else None


def _samples(value: tuple[float, ...]) -> str | None:
    ok = value[0] >= 1 and value[0] == int(value[0])
    return None if ok else "noise takes a whole number of samples per pixel >= 1"


def _level(value: tuple[float, ...]) -> str | None:
    ok = 0 < value[0] <= MAX_LEVEL
    return None if ok else f"depth_noise takes a level in (0, {MAX_LEVEL:g}] (1: a D415 by its datasheet)"


def _any(sensors: tuple[str, ...]) -> bool:
    return bool(sensors)


def _colour(sensors: tuple[str, ...]) -> bool:
    return IMAGE_PREFIX in sensors


def _depth(sensors: tuple[str, ...]) -> bool:
    return DEPTH_PREFIX in sensors


@dataclass(frozen=True)
class PerturbationKind:
    """One kind of perturbation: how it is written, the numbers it takes and their check, its nominal value (None:
    no value is the unperturbed scene's) and the sensors it changes: a policy that reads none of them sees the
    unperturbed scene (the light does not change the depth; a DP3 cloud of xyz points reads no colour)."""

    name: str
    form: str
    numbers: int
    check: Callable[[tuple[float, ...]], str | None]  # the problem with a value, or None
    nominal: float | None
    changes: Callable[[tuple[str, ...]], bool]  # the sensors a policy reads -> whether it can change what it sees
    changes_text: str  # what `changes` asks, as a refusal says it


KINDS: dict[str, PerturbationKind] = {
    kind.name: kind
    for kind in (
        PerturbationKind("camera_yaw", "camera_yaw:DEG (e.g. camera_yaw:10)", 1, _camera_angle, 0.0, _any, "a camera"),
        PerturbationKind(
            "camera_pitch", "camera_pitch:DEG (e.g. camera_pitch:10)", 1, _camera_angle, 0.0, _any, "a camera"
        ),
        PerturbationKind("light", "light:I (e.g. light:0.03)", 1, _light, DEFAULT_AMBIENT, _colour, "colour"),
        PerturbationKind(
            "background", "background:R,G,B (e.g. background:1,0.2,0.2)", 3, _rgb, None, _colour, "colour"
        ),
        PerturbationKind("noise", "noise:SPP (e.g. noise:16)", 1, _samples, None, _colour, "colour"),
        PerturbationKind("depth_noise", "depth_noise:L (e.g. depth_noise:1)", 1, _level, 0.0, _depth, "depth"),
    )
}
NOMINAL_VALUE = {name: kind.nominal for name, kind in KINDS.items()}
# the kinds each family's env applies
MANISKILL_KINDS = tuple(KINDS)
METAWORLD_KINDS = ("camera_yaw", "camera_pitch", "light", "background", "depth_noise")


class PerturbationError(ObsBenchError, ValueError):
    """A perturbation written wrongly (`kind:value`), or one a task family or a space cannot take."""


@dataclass(frozen=True)
class Perturbation:
    kind: str
    value: tuple[float, ...]

    @property
    def name(self) -> str:
        return f"{self.kind}:{','.join(f'{v:g}' for v in self.value)}"

    @property
    def scalar(self) -> float:
        """The x value of a generalization curve (first channel for colours)."""
        return self.value[0]


def parse_perturbation(text: str) -> Perturbation | None:
    """`kind:value` -> Perturbation; `none` -> None. Raises PerturbationError naming the valid forms."""
    if text in (None, "", "none"):
        return None
    name, _, raw = str(text).partition(":")
    if name not in KINDS or not raw:
        raise PerturbationError(
            f"unknown perturbation {text!r}; write one of {', '.join(k.form.split()[0] for k in KINDS.values())} "
            "(or none)"
        )
    kind = KINDS[name]
    try:
        value = tuple(float(v) for v in raw.split(","))
    except ValueError:
        value = ()
    if not value or not all(math.isfinite(v) for v in value):
        raise PerturbationError(f"perturbation {text!r}: expected {kind.form}, with finite numbers")
    if len(value) != kind.numbers:
        raise PerturbationError(f"perturbation {text!r}: {name} takes {kind.numbers} number(s)")
    problem = kind.check(value)
    if problem:
        raise PerturbationError(f"perturbation {text!r}: {problem}")
    return Perturbation(name, value)


def check_supported(perturbation: Perturbation | None, supported: tuple[str, ...], family: str) -> None:
    """Refuse a perturbation kind that `family`'s env does not apply (its kinds: `supported`)."""
    if perturbation is not None and perturbation.kind not in supported:
        raise PerturbationError(
            f"{perturbation.name}: {family} tasks do not support {perturbation.kind} perturbations; they take "
            f"{', '.join(supported)}"
        )


def check_changes(
    perturbation: Perturbation | None, obs_space: str, point_features: str = DEFAULT_POINT_FEATURES
) -> None:
    """Refuse a perturbation that cannot change what a policy on `obs_space` (its points carrying `point_features`)
    sees, whose episodes would replay the unperturbed ones: `depth_noise` on a space built from no depth, the
    light, background and render noise on a space that reads no colour, any perturbation on the blind and oracle
    controls."""
    if perturbation is not None and not applies_to(perturbation.name, obs_space, point_features):
        names = {IMAGE_PREFIX: "colour", DEPTH_PREFIX: "depth"}
        read = [names[p] for p in read_sensors(obs_space, point_features) if p in names]
        reads = " and ".join(read) if read and not is_control(obs_space) else "nothing"
        raise PerturbationError(
            f"{perturbation.name} changes only what policies reading {KINDS[perturbation.kind].changes_text} see, "
            f"and obs_space {obs_space!r} (point_features {point_features}) reads {reads}: its episodes would "
            "replay the unperturbed ones"
        )


def applies_to(text: str, obs_space: str, point_features: str = DEFAULT_POINT_FEATURES) -> bool:
    """Whether the perturbation written `text` can change what a policy on `obs_space`, its points carrying
    `point_features`, sees."""
    perturbation = parse_perturbation(text)
    if perturbation is None:
        return True
    return not is_control(obs_space) and KINDS[perturbation.kind].changes(read_sensors(obs_space, point_features))


class DepthNoiser:
    """The `depth_noise` perturbation of an env of `num_envs` slots: every depth image of a frame as the sensor model
    reports it at the perturbation's level, each slot's noise drawn from a generator seeded by its episode's seed
    (`reset`), so an episode's noise repeats with its seed."""

    SEED_OFFSET = 7_919  # the noise's stream is not the one the env or the policy draw from the same seed

    def __init__(self, perturbation: Perturbation, num_envs: int = 1, device=None):
        import torch

        self.level = perturbation.scalar
        self.generators = [torch.Generator(device=device or "cpu") for _ in range(num_envs)]

    def reset(self, seeds) -> None:
        """Seed each slot's noise from its episode's seed (None: an unseeded episode, unseeded noise)."""
        for generator, seed in zip(self.generators, seeds, strict=True):
            if seed is None:
                generator.seed()
            else:
                generator.manual_seed(int(seed) + self.SEED_OFFSET)

    def apply(self, frames: dict, cameras) -> dict:
        """`frames` (schema keys, batched over the slots: torch tensors or NumPy arrays) with each camera's depth
        made noisy."""
        import torch

        for cam in cameras:
            key = depth_key(cam)
            if key not in frames:
                continue
            depth, numpy = frames[key], isinstance(frames[key], np.ndarray)
            depth = torch.from_numpy(depth) if numpy else depth
            fx = torch.as_tensor(frames[intrinsics_key(cam)], device=depth.device)[..., 0, 0].reshape(-1)
            rows = [
                noisy_depth(depth[i, ..., 0][None], fx[i : i + 1], self.level, generator=self.generators[i])
                for i in range(len(self.generators))
            ]
            noisy = torch.cat(rows)[..., None]
            frames[key] = noisy.numpy() if numpy else noisy
        return frames


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.deg2rad(degrees)).as_matrix()


def orbit_rotation(eye, target, yaw_deg: float = 0.0, pitch_deg: float = 0.0) -> np.ndarray:
    """The rotation (3, 3) that orbits a camera at `eye` about `target`: yaw about the world z axis, then pitch about
    the horizontal axis perpendicular to the viewing direction (positive pitch raises the camera). Applied to the
    camera's offset from its target and to its orientation, it keeps the camera looking at the target."""
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    yaw = _rotation(np.array([0.0, 0.0, 1.0]), yaw_deg)
    side = np.cross(yaw @ (eye - target), [0.0, 0.0, 1.0])
    pitch = _rotation(side, pitch_deg) if np.linalg.norm(side) > 1e-9 else np.eye(3)
    return pitch @ yaw


def orbit_eye(eye, target, yaw_deg: float = 0.0, pitch_deg: float = 0.0) -> np.ndarray:
    """`eye` moved on a sphere about `target` (`orbit_rotation`)."""
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    return target + orbit_rotation(eye, target, yaw_deg, pitch_deg) @ (eye - target)


def capture_look_at(ms_env) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(eye, target) of each default camera of a ManiSkill env, read by re-evaluating its camera configs with
    `sapien_utils.look_at` instrumented (the configs keep only the resulting pose) — in `sapien_utils` and wherever
    the env's classes imported it by name (`from mani_skill.utils.sapien_utils import look_at`, as PullCube does)."""
    from mani_skill.utils import sapien_utils

    calls = []
    original = sapien_utils.look_at

    def recording(eye, target, up=(0, 0, 1)):
        calls.append((np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)))
        return original(eye, target, up)

    modules = {sapien_utils} | {
        module
        for module in (sys.modules.get(cls.__module__) for cls in type(ms_env).__mro__)
        if getattr(module, "look_at", None) is original
    }
    for module in modules:
        module.look_at = recording
    try:
        configs = ms_env._default_sensor_configs
    finally:
        for module in modules:
            module.look_at = original
    configs = configs if isinstance(configs, (list, tuple)) else [configs]
    if len(calls) != len(configs):
        raise PerturbationError(f"cannot find the look-at points of {type(ms_env).__name__}'s cameras")
    return {config.uid: call for config, call in zip(configs, calls, strict=True)}


def camera_overrides(ms_env, cameras, perturbation: Perturbation, task_camera=None) -> dict:
    """`sensor_configs` entries moving each scene camera for a camera perturbation; `task_camera` (eye, target,
    fov): the task's own `base_camera`, moved instead of ManiSkill's. A camera mounted on the robot (a wrist
    camera) has no look-at point in the scene and stays where the hand carries it."""
    from mani_skill.utils import sapien_utils

    yaw = perturbation.scalar if perturbation.kind == "camera_yaw" else 0.0
    pitch = perturbation.scalar if perturbation.kind == "camera_pitch" else 0.0
    looks = capture_look_at(ms_env)
    if task_camera is not None:
        looks["base_camera"] = tuple(np.asarray(p, dtype=np.float64) for p in task_camera[:2])
    return {
        cam: {"pose": sapien_utils.look_at(orbit_eye(*looks[cam], yaw, pitch).tolist(), looks[cam][1].tolist())}
        for cam in cameras
        if cam in looks
    }


def apply_scene_perturbation(ms_env, perturbation: Perturbation) -> None:
    """Change lights or surface colours of a built scene in place (they persist across resets)."""
    import sapien

    for scene in ms_env.scene.sub_scenes:
        if perturbation.kind == "light":
            factor = perturbation.scalar / DEFAULT_AMBIENT
            scene.ambient_light = [perturbation.scalar] * 3
            for entity in scene.entities:
                for comp in entity.components:
                    if isinstance(comp, sapien.render.RenderDirectionalLightComponent):
                        comp.color = (np.asarray(comp.color) * factor).tolist()
        elif perturbation.kind == "background":
            surfaces = [getattr(ms_env, "table_scene", None)]
            actors = [
                a for s in surfaces if s is not None for a in (getattr(s, "table", None), getattr(s, "ground", None))
            ]
            if not any(a is not None for a in actors):
                raise PerturbationError(f"{type(ms_env).__name__} has no table scene whose colour could change")
            # A flat texture of the colour: the renderer's material update path ignores base_color alone.
            pixel = np.round(np.array([*perturbation.value, 1.0]) * 255).astype(np.uint8)
            flat = sapien.render.RenderTexture2D(np.tile(pixel, (4, 4, 1)), "R8G8B8A8Unorm", srgb=True)
            for actor in (a for a in actors if a is not None):
                for obj in actor._objs:
                    for comp in obj.components:
                        if isinstance(comp, sapien.render.RenderBodyComponent):
                            for shape in comp.render_shapes:
                                for part in getattr(shape, "parts", [shape]):
                                    part.material.base_color = [1.0, 1.0, 1.0, 1.0]
                                    part.material.base_color_texture = flat
