"""Scripted experts for the OBSBench ManiSkill tasks, driving the `pd_ee_delta_pose` controller.

ManiSkill's own motion-planning solutions need mplib, which cannot run next to LeRobot's numpy >= 2 (DESIGN §7),
so demonstrations come from these privileged (they read object poses from the simulator) waypoint followers:
a proportional controller moves the tool-centre point (TCP) and its orientation towards the current waypoint;
a phase ends when its waypoint is reached (or after a step budget), then the next begins. Every offline OBSBench task has
one (TurnFaucet's assets are not available here).

Action layout (pd_ee_delta_pose): [dx, dy, dz] in [-1, 1] -> ±0.1 m; [drx, dry, drz] in [-1, 1] -> ±0.1 rad,
which (measured on ManiSkill 3.0.1's Panda) turns the TCP by the world-frame rotation vector -(drx, dry, drz);
gripper +1 open / -1 closed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from lerobot_obsbench.envs.maniskill import to_numpy

POS_SCALE = 0.1
ROT_SCALE = 0.1
OPEN, CLOSED = 1.0, -1.0


def _np(x) -> np.ndarray:
    """A single env's value (ManiSkill returns batches of one) as a flat array."""
    return to_numpy(x).reshape(-1)


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
            rot_err = (np.zeros(3) if phase.rotation is None
                       else Rotation.from_matrix(phase.rotation(self) @ tcp[:3, :3].T).as_rotvec())
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
        return _np(actor.pose.p), yaw_of(_np(actor.pose.q))

    def matrix_of(self, pose) -> np.ndarray:
        return pose_matrix(_np(pose.p), quat_to_matrix(_np(pose.q)))

    def aligned(self, actor) -> Callable:
        """Rotation target: top-down, yaw aligned with `actor`'s faces (closest of the 4 choices)."""
        return lambda s: top_down(grasp_yaw(s.tcp()[1], s.pose_of(actor)[1]))


def _above(p: np.ndarray, dz: float) -> np.ndarray:
    return p + np.array([0.0, 0.0, dz])


class PickCubeExpert(WaypointExpert):
    def plan(self):
        cube = lambda s: s.pose_of(s.env.cube)[0]  # noqa: E731
        yaw = self.aligned(self.env.cube)
        goal = lambda s: _np(s.env.goal_site.pose.p)  # noqa: E731
        return [
            Phase("pre-grasp", lambda s: _above(cube(s), 0.05), OPEN, yaw),
            Phase("descend", cube, OPEN, yaw, tol=0.005),
            Phase("grasp", cube, CLOSED, yaw, tol=1.0, min_steps=4, max_steps=4),
            Phase("to goal", goal, CLOSED, tol=0.005, max_steps=60),
            Phase("hold", goal, CLOSED, tol=1.0, min_steps=30, max_steps=30),
        ]


class StackCubeExpert(WaypointExpert):
    def plan(self):
        cube_a = lambda s: s.pose_of(s.env.cubeA)[0]  # noqa: E731
        yaw = self.aligned(self.env.cubeA)
        half = float(_np(self.env.cube_half_size)[0]) if hasattr(self.env, "cube_half_size") else 0.02
        on_b = lambda s: _above(s.pose_of(s.env.cubeB)[0], 2 * half)  # noqa: E731
        return [
            Phase("pre-grasp", lambda s: _above(cube_a(s), 0.05), OPEN, yaw),
            Phase("descend", cube_a, OPEN, yaw, tol=0.005),
            Phase("grasp", cube_a, CLOSED, yaw, tol=1.0, min_steps=4, max_steps=4),
            Phase("lift", lambda s: _above(cube_a(s), 0.0) * [1, 1, 0] + [0, 0, 0.1], CLOSED),
            Phase("above B", lambda s: _above(on_b(s), 0.04), CLOSED),
            Phase("lower", lambda s: _above(on_b(s), 0.005), CLOSED, tol=0.005),
            Phase("release", lambda s: _above(on_b(s), 0.005), OPEN, tol=1.0, min_steps=5, max_steps=5),
            Phase("retreat", lambda s: _above(on_b(s), 0.08), OPEN, max_steps=30),
        ]


class PushCubeExpert(WaypointExpert):
    """Push along +x: get behind the cube (closed gripper, low), then push until the cube is on the goal."""

    def plan(self):
        cube = lambda s: s.pose_of(s.env.obj)[0]  # noqa: E731
        goal = lambda s: _np(s.env.goal_region.pose.p)  # noqa: E731
        half = 0.02
        behind = lambda s: np.array([cube(s)[0] - half - 0.03, goal(s)[1], 0.02])  # noqa: E731
        return [
            Phase("above behind", lambda s: _above(behind(s), 0.08), CLOSED),
            Phase("down behind", behind, CLOSED, tol=0.005),
            Phase("push", lambda s: np.array([goal(s)[0] - half + 0.005, goal(s)[1], 0.02]), CLOSED, tol=0.005,
                  max_steps=60),
        ]


class PullCubeExpert(WaypointExpert):
    """Pull along -x: reach over the cube, lower in front of it, pull back to the goal."""

    def plan(self):
        cube = lambda s: s.pose_of(s.env.obj)[0]  # noqa: E731
        goal = lambda s: _np(s.env.goal_region.pose.p)  # noqa: E731
        half = 0.02
        front = lambda s: np.array([cube(s)[0] + half + 0.03, cube(s)[1], 0.02])  # noqa: E731
        return [
            Phase("above front", lambda s: _above(front(s), 0.08), CLOSED),
            Phase("down front", front, CLOSED, tol=0.005),
            Phase("pull", lambda s: np.array([goal(s)[0] + half + 0.01, goal(s)[1], 0.02]), CLOSED, tol=0.005,
                  max_steps=60),
        ]


class LiftPegUprightExpert(WaypointExpert):
    """Pinch the lying peg lightly near one end, lift that end: the peg swings about the finger axis until it
    hangs upright below the fingers; lower it onto the table and let go.

    (Turning a firmly grasped peg by 90° instead stalls near the Panda's wrist limit.)
    """

    pinch = 0.05  # gripper command that touches the peg with little force, so it can pivot between the fingers

    def plan(self):
        half_length = float(self.env.peg_half_length)
        peg = lambda s: s.matrix_of(s.env.peg.pose)  # noqa: E731
        near_end = lambda s: (peg(s) @ np.array([-(half_length - 0.02), 0, 0, 1]))[:3]  # noqa: E731
        rotation = lambda s: top_down(grasp_yaw(s.tcp()[1], s.pose_of(s.env.peg)[1], np.pi))  # noqa: E731
        self.raised = None

        def high(s):
            if s.raised is None:
                s.raised = s.tcp()[0] * [1, 1, 0] + [0, 0, 0.32]
            return s.raised

        def standing(s):  # lower until the peg's centre is at its standing height
            return s.tcp()[0] + [0, 0, half_length + 0.003 - s.pose_of(s.env.peg)[0][2]]

        return [
            Phase("pre-grasp", lambda s: _above(near_end(s), 0.06), OPEN, rotation),
            Phase("descend", near_end, OPEN, rotation, tol=0.005),
            Phase("pinch", near_end, self.pinch, rotation, tol=1.0, min_steps=5, max_steps=5),
            Phase("raise", high, self.pinch, rotation, tol=0.01, max_steps=30),
            Phase("swing", high, self.pinch, rotation, tol=1.0, min_steps=5, max_steps=5),
            Phase("lower", standing, self.pinch, rotation, tol=0.003, max_steps=40, gain=1.0),
            Phase("release", lambda s: s.tcp()[0], OPEN, tol=1.0, min_steps=5, max_steps=5),
        ]


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

        grasp_rotation = lambda s: top_down(grasp_yaw(s.tcp()[1], s.pose_of(getattr(s.env, s.object_name))[1], np.pi))  # noqa: E731

        def tcp_for(s, dx):
            target = s.matrix_of(s.env.goal_pose) @ pose_matrix(np.array([dx, 0, 0]), np.eye(3))
            return target @ np.linalg.inv(np.linalg.inv(s.tcp_matrix()) @ obj(s))

        def lifted(s):
            return s.tcp()[0] * [1, 1, 0] + [0, 0, tcp_for(s, out)[2, 3] + 0.05]

        return [
            Phase("pre-grasp", lambda s: _above(grasp_point(s), 0.06), OPEN, grasp_rotation),
            Phase("descend", grasp_point, OPEN, grasp_rotation, tol=0.005),
            Phase("grasp", grasp_point, CLOSED, grasp_rotation, tol=1.0, min_steps=4, max_steps=4),
            Phase("lift", lifted, CLOSED, tol=0.02),
            Phase("line up", lambda s: tcp_for(s, out)[:3, 3], CLOSED, lambda s: tcp_for(s, out)[:3, :3],
                  tol=0.0015, rot_tol=0.01, max_steps=60),
            Phase("insert", lambda s: tcp_for(s, inside)[:3, 3], CLOSED, lambda s: tcp_for(s, inside)[:3, :3],
                  tol=0.003, rot_tol=0.01, max_steps=60, gain=0.5),
        ]


class PegInsertionSideExpert(InsertionExpert):
    object_name = "peg"

    def grasp_offset(self):  # behind the middle, leaving the head free
        return -0.5 * float(_np(self.env.peg_half_sizes)[0])

    def line_up_offset(self):  # the hole runs through a box as long as the peg: head 2 cm out of the entrance
        return -(float(_np(self.env.peg_half_sizes)[0]) + 0.02)


class PlugChargerExpert(InsertionExpert):
    object_name = "charger"

    def grasp_offset(self):  # the middle of the charger's base (its frame sits where the prongs start)
        return -float(self.env._base_size[0])

    def line_up_offset(self):  # prongs 2 cm short of the socket
        return -(2 * float(self.env._peg_size[0]) + 0.02)


EXPERTS: dict[str, type[WaypointExpert]] = {
    "PickCube-v1": PickCubeExpert,
    "StackCube-v1": StackCubeExpert,
    "PushCube-v1": PushCubeExpert,
    "PullCube-v1": PullCubeExpert,
    "PegInsertionSide-v1": PegInsertionSideExpert,
    "PlugCharger-v1": PlugChargerExpert,
    "LiftPegUpright-v1": LiftPegUprightExpert,
}


def make_expert(task: str, env) -> WaypointExpert:
    if task not in EXPERTS:
        raise NotImplementedError(
            f"No scripted expert for {task} yet (experts: {', '.join(EXPERTS)}). Convert official ManiSkill "
            "demonstrations instead: obsbench import-h5 --task ... --h5 FILE.h5."
        )
    return EXPERTS[task](env)
