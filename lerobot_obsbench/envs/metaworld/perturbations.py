"""The zero-shot perturbations on Meta-World's Sawyer scene, with ManiSkill's names and meaning
(envs/perturbations.py), applied to the MuJoCo model once, before the first frame:

- `camera_yaw` / `camera_pitch`: each scene camera (fixed in the world) orbits its look-at point, the point where
  its optical axis meets the table top (the model's table geom), by `orbit_rotation`: its position about that point
  and its orientation alike, so it keeps looking at the point, at the same distance and with the same field of view;
- `light`: the scene's three lights and MuJoCo's headlight, every component, scaled by I / 0.3 (`light:0.3` is the
  scene as Meta-World lights it);
- `background`: the table top and the floor drawn in the flat colour (their textured materials taken off).

`depth_noise` is applied to the frames, not the model (`MetaWorldEnv`). The objects, the robot and the episode a
seed gives are left as they are: the perturbations change what the cameras see and nothing the physics reads.
"""

from __future__ import annotations

import numpy as np

from lerobot_obsbench.envs.perturbations import DEFAULT_AMBIENT, Perturbation, PerturbationError, orbit_rotation

TABLE_BODY = "tablelink"  # the table's body; its largest box is the top
FLOOR_GEOM = "floor"


def table_top(model, data) -> tuple[int, float]:
    """(geom id, height in metres) of the table top: the widest box of the table's body, its upper face."""
    import mujoco

    body = model.body(TABLE_BODY).id
    boxes = [
        g
        for g in range(model.ngeom)
        if model.geom_bodyid[g] == body and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX
    ]
    top = max(boxes, key=lambda g: model.geom_size[g][0] * model.geom_size[g][1])
    return top, float(data.geom_xpos[top][2] + model.geom_size[top][2])


def look_at_point(position: np.ndarray, rotation: np.ndarray, height: float) -> np.ndarray:
    """Where a MuJoCo camera at `position` with `rotation` (3, 3; it looks along its -z axis) sees the plane at
    `height`."""
    forward = -np.asarray(rotation).reshape(3, 3)[:, 2]
    if forward[2] >= 0:
        raise PerturbationError("a camera that does not look down at the table has no look-at point on it to orbit")
    return position + forward * (height - position[2]) / forward[2]


def orbit_camera(model, data, camera: str, yaw_deg: float, pitch_deg: float) -> None:
    """Move `camera` (fixed in the world) on its orbit about its look-at point on the table top."""
    import mujoco

    index = model.camera(camera).id
    if model.cam_bodyid[index] != 0:
        raise PerturbationError(f"camera {camera!r} moves with the robot: it has no fixed look-at point to orbit")
    _, height = table_top(model, data)
    position = model.cam_pos[index].copy()
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.cam_quat[index])
    target = look_at_point(position, rotation, height)
    turn = orbit_rotation(position, target, yaw_deg, pitch_deg)
    model.cam_pos[index] = target + turn @ (position - target)
    quaternion = np.zeros(4)
    mujoco.mju_mat2Quat(quaternion, (turn @ rotation.reshape(3, 3)).flatten())
    model.cam_quat[index] = quaternion


def scale_lights(model, factor: float) -> None:
    """Every light of the scene, the headlight among them, `factor` times as bright."""
    for values in (model.light_ambient, model.light_diffuse, model.light_specular):
        values *= factor
    headlight = model.vis.headlight
    headlight.ambient, headlight.diffuse, headlight.specular = (
        np.asarray(headlight.ambient) * factor,
        np.asarray(headlight.diffuse) * factor,
        np.asarray(headlight.specular) * factor,
    )


def background_geoms(model, data) -> list[int]:
    """The table top and the floor."""
    return [table_top(model, data)[0], model.geom(FLOOR_GEOM).id]


def flat_background(model, data, colour: tuple[float, ...]) -> None:
    """The table top and the floor in the flat `colour` (RGB in [0, 1]): their materials (textures) taken off."""
    for geom in background_geoms(model, data):
        model.geom_matid[geom] = -1
        model.geom_rgba[geom] = [*colour, 1.0]


def apply_perturbation(model, data, cameras, perturbation: Perturbation | None) -> None:
    """Change the model for `perturbation` (camera, light or background; nothing for the others)."""
    import mujoco

    if perturbation is None:
        return
    if perturbation.kind in ("camera_yaw", "camera_pitch"):
        yaw = perturbation.scalar if perturbation.kind == "camera_yaw" else 0.0
        pitch = perturbation.scalar if perturbation.kind == "camera_pitch" else 0.0
        for camera in cameras:
            orbit_camera(model, data, camera, yaw, pitch)
    elif perturbation.kind == "light":
        scale_lights(model, perturbation.scalar / DEFAULT_AMBIENT)
    elif perturbation.kind == "background":
        flat_background(model, data, perturbation.value)
    mujoco.mj_forward(model, data)  # the cameras' world poses follow the model
