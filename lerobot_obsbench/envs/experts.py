"""The scripted experts' machinery, driving the `pd_ee_delta_pose` controller (each task's own expert lives in
its task module, `lerobot_obsbench.envs.tasks`).

ManiSkill's own motion-planning solutions need mplib, which cannot run next to LeRobot's numpy >= 2,
so demonstrations come from privileged (they read object poses from the simulator) waypoint followers: a
proportional controller moves the tool-centre point (TCP) and its orientation towards the current waypoint; a
phase ends when its waypoint is reached (or after a step budget), then the next begins.

Action layout (pd_ee_delta_pose): [dx, dy, dz] in [-1, 1] -> ±0.1 m; [drx, dry, drz] in [-1, 1] -> ±0.1 rad,
which (measured on ManiSkill 3.0.1's Panda) turns the TCP by the world-frame rotation vector -(drx, dry, drz);
gripper +1 open / -1 closed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from lerobot_obsbench.envs.base_task import first

POS_SCALE = 0.1
ROT_SCALE = 0.1
OPEN, CLOSED = 1.0, -1.0


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a (w, x, y, z) quaternion."""
    return Rotation.from_quat(q, scalar_first=True).as_matrix()


def yaw_of(q: np.ndarray) -> float:
    """Heading of a frame's x axis in the world xy plane."""
    R = quat_to_matrix(q)
    return float(np.arctan2(R[1, 0], R[0, 0]))


def wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def grasp_yaw(tcp_yaw: float, object_yaw: float, symmetry: float = np.pi / 2) -> float:
    """The object-aligned gripper yaw (object yaw + k * symmetry) closest to the current gripper yaw."""
    k = np.round(wrap(tcp_yaw - object_yaw) / symmetry)
    return wrap(object_yaw + k * symmetry)


def top_down(yaw: float) -> np.ndarray:
    """TCP orientation pointing straight down with its x axis at heading `yaw` (fingers close along its y)."""
    x = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    return np.stack([x, np.cross(z, x), z], axis=1)


def pose_matrix(p: np.ndarray, R: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


@dataclass
class Phase:
    """Move the TCP to `target(expert)` with `gripper` and orientation `rotation(expert)` (a world 3x3 matrix;
    None keeps the current one) until within `tol` metres and 0.05 rad, or `max_steps` have passed.
    `min_steps` holds the phase (e.g. to let the gripper close). A `gain` below 1 moves slowly."""

    name: str
    target: Callable
    gripper: float
    rotation: Callable | None = None
    tol: float = 0.01
    max_steps: int = 40
    min_steps: int = 0
    gain: float | None = None
    rot_tol: float = 0.05


class WaypointExpert:
    """Runs a list of phases; `act(env)` returns the next 7-D action (or None when the script is finished)."""

    gain = 2.0

    def __init__(self, env):
        self.env = env.unwrapped_ms if hasattr(env, "unwrapped_ms") else env
        self.phases = self.plan()
        self.index = 0
        self.steps_in_phase = 0

    def plan(self) -> list[Phase]:
        raise NotImplementedError

    def tcp(self) -> tuple[np.ndarray, float]:
        return self.pose_of(self.env.agent.tcp)

    def tcp_matrix(self) -> np.ndarray:
        return self.matrix_of(self.env.agent.tcp.pose)

    def act(self) -> np.ndarray | None:
        while self.index < len(self.phases):
            phase = self.phases[self.index]
            tcp = self.tcp_matrix()
            err = np.asarray(phase.target(self), dtype=np.float64) - tcp[:3, 3]
            # rotation error as a world-frame rotation vector (see the module docstring for the controller's sign)
            rot_err = (
                np.zeros(3)
                if phase.rotation is None
                else Rotation.from_matrix(phase.rotation(self) @ tcp[:3, :3].T).as_rotvec()
            )
            reached = np.linalg.norm(err) < phase.tol and np.linalg.norm(rot_err) < phase.rot_tol
            if (reached and self.steps_in_phase >= phase.min_steps) or self.steps_in_phase >= phase.max_steps:
                self.index += 1
                self.steps_in_phase = 0
                continue
            self.steps_in_phase += 1
            gain = self.gain if phase.gain is None else phase.gain
            action = np.zeros(7)
            action[:3] = np.clip(gain * err / POS_SCALE, -1, 1)
            action[3:6] = np.clip(-rot_err / ROT_SCALE, -1, 1)
            action[6] = phase.gripper
            return action.astype(np.float32)
        return None

    # helpers for plans
    def pose_of(self, actor) -> tuple[np.ndarray, float]:
        return first(actor.pose.p), yaw_of(first(actor.pose.q))

    def matrix_of(self, pose) -> np.ndarray:
        return pose_matrix(first(pose.p), quat_to_matrix(first(pose.q)))


def above(p: np.ndarray, dz: float) -> np.ndarray:
    return p + np.array([0.0, 0.0, dz])


class InsertionExpert(WaypointExpert):
    """Grasp an object along its x axis, lift it, line it up a little short of `env.goal_pose` (the object's
    inserted pose), then push it home along its x axis.

    Once grasped, targets are object poses; the TCP target is derived through the object-in-gripper transform
    measured at every step, so the loop closes on the object and one that shifts in the fingers is still aimed.
    Subclasses give the object, where to grasp it and how far out to line up (metres along its x axis).
    """

    object_name: str

    def grasp_offset(self) -> float:
        raise NotImplementedError

    def line_up_offset(self) -> float:
        raise NotImplementedError

    def plan(self):
        grasp_dx, out, inside = self.grasp_offset(), self.line_up_offset(), 0.01

        def obj(s):
            return s.matrix_of(getattr(s.env, s.object_name).pose)

        def grasp_point(s):
            return (obj(s) @ np.array([grasp_dx, 0, 0, 1]))[:3]

        grasp_rotation = lambda s: top_down(grasp_yaw(s.tcp()[1], s.pose_of(getattr(s.env, s.object_name))[1], np.pi))

        def tcp_for(s, dx):
            target = s.matrix_of(s.env.goal_pose) @ pose_matrix(np.array([dx, 0, 0]), np.eye(3))
            return target @ np.linalg.inv(np.linalg.inv(s.tcp_matrix()) @ obj(s))

        def lifted(s):
            return s.tcp()[0] * [1, 1, 0] + [0, 0, tcp_for(s, out)[2, 3] + 0.05]

        return [
            Phase("pre-grasp", lambda s: above(grasp_point(s), 0.06), OPEN, grasp_rotation),
            Phase("descend", grasp_point, OPEN, grasp_rotation, tol=0.005),
            Phase("grasp", grasp_point, CLOSED, grasp_rotation, tol=1.0, min_steps=4, max_steps=4),
            Phase("lift", lifted, CLOSED, tol=0.02),
            Phase(
                "line up",
                lambda s: tcp_for(s, out)[:3, 3],
                CLOSED,
                lambda s: tcp_for(s, out)[:3, :3],
                tol=0.0015,
                rot_tol=0.01,
                max_steps=60,
            ),
            Phase(
                "insert",
                lambda s: tcp_for(s, inside)[:3, 3],
                CLOSED,
                lambda s: tcp_for(s, inside)[:3, :3],
                tol=0.003,
                rot_tol=0.01,
                max_steps=60,
                gain=0.5,
            ),
        ]
