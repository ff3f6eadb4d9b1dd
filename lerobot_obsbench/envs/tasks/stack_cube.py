"""StackCube-v1.

**Task Description:** pick up the red cube, stack it on the green cube and let go.

**Randomizations:** both cubes' xy positions on the table (without collision) and their rotations about z.

**Success Conditions:** the red cube rests on the green one (within half a cube size), static and released.
Sub-success: `grasp` (the red cube was held at some step).

**Expert:** top-down grasp of the red cube, lift 10 cm, move above the green cube, lower, release, retreat.
19/20 over seeds 100000.. (mean 34.5 steps).
"""

from __future__ import annotations

from lerobot_obsbench.envs.base_task import Task, first, register_task
from lerobot_obsbench.envs.experts import CLOSED, OPEN, Phase, WaypointExpert, above


class StackCubeExpert(WaypointExpert):
    def plan(self):
        cube_a = lambda s: s.pose_of(s.env.cubeA)[0]
        yaw = self.aligned(self.env.cubeA)
        half = float(first(self.env.cube_half_size)[0]) if hasattr(self.env, "cube_half_size") else 0.02
        on_b = lambda s: above(s.pose_of(s.env.cubeB)[0], 2 * half)
        return [
            Phase("pre-grasp", lambda s: above(cube_a(s), 0.05), OPEN, yaw),
            Phase("descend", cube_a, OPEN, yaw, tol=0.005),
            Phase("grasp", cube_a, CLOSED, yaw, tol=1.0, min_steps=4, max_steps=4),
            Phase("lift", lambda s: above(cube_a(s), 0.0) * [1, 1, 0] + [0, 0, 0.1], CLOSED),
            Phase("above B", lambda s: above(on_b(s), 0.04), CLOSED),
            Phase("lower", lambda s: above(on_b(s), 0.005), CLOSED, tol=0.005),
            Phase("release", lambda s: above(on_b(s), 0.005), OPEN, tol=1.0, min_steps=5, max_steps=5),
            Phase("retreat", lambda s: above(on_b(s), 0.08), OPEN, max_steps=30),
        ]


@register_task
class StackCube(Task):
    name = "StackCube-v1"
    max_steps = 50
    description = "stack the red cube on the green cube"
    grasped = "cubeA"
    privileged_actors = ("cubeA", "cubeB")
    camera_names = ("base_camera", "hand_camera")  # ManiSkill runs it with the wrist-camera Panda
    objects = {"cubeA": 0.035, "cubeB": 0.035}  # 2 cm half-size cubes
    sub_success = ("grasp",)
    expert = StackCubeExpert
