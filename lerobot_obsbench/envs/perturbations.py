"""Zero-shot evaluation perturbations (paper §5.3), applied to the env without new demonstrations.

A perturbation is written `kind:value` (grid files, `--env.perturbation`):

- `camera_yaw:DEG` / `camera_pitch:DEG` — every camera moves on a circle about its look-at point, horizontally
  (about the world z axis) or vertically (towards / away from the table), keeping its distance and target.
  The paper uses 5 and 10 degrees.
- `light:I` — ambient light intensity I (ManiSkill's default 0.3; the paper tries 0.03 ... 3); the
  directional lights are scaled by the same factor I / 0.3.
- `background:R,G,B` — the table top and floor take this flat colour (0..1) instead of their texture; the
  paper varies the red and green channels over 0.2 / 0.6 / 1.0.
- `noise:SPP` — render with ray tracing at SPP samples per pixel and no denoiser (the paper: 2, 16, 32, 64),
  which leaves Monte-Carlo noise in the colour image. Slow on a CPU renderer.

`none` is the unperturbed env.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lerobot_obsbench.errors import ObsBenchError

# kind -> how it is written, with an example
FORMS = {
    "camera_yaw": "camera_yaw:DEG (e.g. camera_yaw:10)",
    "camera_pitch": "camera_pitch:DEG (e.g. camera_pitch:10)",
    "light": "light:I (e.g. light:0.03)",
    "background": "background:R,G,B (e.g. background:1,0.2,0.2)",
    "noise": "noise:SPP (e.g. noise:16)",
}
KINDS = tuple(FORMS)
DEFAULT_AMBIENT = 0.3
NOMINAL_VALUE = {"camera_yaw": 0.0, "camera_pitch": 0.0, "light": DEFAULT_AMBIENT, "noise": None, "background": None}


class PerturbationError(ObsBenchError, ValueError):
    """A perturbation written wrongly (`kind:value`)."""


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
    kind, _, raw = str(text).partition(":")
    if kind not in KINDS or not raw:
        raise PerturbationError(
            f"unknown perturbation {text!r}; write one of {', '.join(form.split()[0] for form in FORMS.values())} "
            "(or none)"
        )
    try:
        value = tuple(float(v) for v in raw.split(","))
    except ValueError:
        value = ()
    if not value or not all(math.isfinite(v) for v in value):
        raise PerturbationError(f"perturbation {text!r}: expected {FORMS[kind]}, with finite numbers")
    expected = 3 if kind == "background" else 1
    if len(value) != expected:
        raise PerturbationError(f"perturbation {text!r}: {kind} takes {expected} number(s)")
    if kind == "light" and value[0] < 0 or kind == "background" and not all(0 <= v <= 1 for v in value):
        raise PerturbationError(f"perturbation {text!r}: light must be >= 0 and colours in [0, 1]")
    if kind == "noise" and (value[0] < 1 or value[0] != int(value[0])):
        raise PerturbationError(f"perturbation {text!r}: noise takes a whole number of samples per pixel >= 1")
    if kind.startswith("camera") and abs(value[0]) >= 80:
        raise PerturbationError(f"perturbation {text!r}: camera angles must be within +-80 degrees")
    return Perturbation(kind, value)


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.deg2rad(degrees)).as_matrix()


def orbit_eye(eye, target, yaw_deg: float = 0.0, pitch_deg: float = 0.0) -> np.ndarray:
    """Move `eye` on a sphere about `target`: yaw about the world z axis, then pitch about the horizontal axis
    perpendicular to the viewing direction (positive pitch raises the camera)."""
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    offset = _rotation(np.array([0.0, 0.0, 1.0]), yaw_deg) @ (eye - target)
    side = np.cross(offset, [0.0, 0.0, 1.0])
    if np.linalg.norm(side) > 1e-9:
        offset = _rotation(side, pitch_deg) @ offset
    return target + offset


def capture_look_at(ms_env) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(eye, target) of each default camera of a ManiSkill env, read by re-evaluating its camera configs with
    `sapien_utils.look_at` instrumented (the configs keep only the resulting pose)."""
    from mani_skill.utils import sapien_utils

    calls = []
    original = sapien_utils.look_at

    def recording(eye, target, up=(0, 0, 1)):
        calls.append((np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)))
        return original(eye, target, up)

    sapien_utils.look_at = recording
    try:
        configs = ms_env._default_sensor_configs
    finally:
        sapien_utils.look_at = original
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
