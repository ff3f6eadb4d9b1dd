"""StackCube-v1.

**Task Description:** pick up the red cube, stack it on the green cube and let go.

**Randomizations:** both cubes' xy positions on the table (without collision) and their rotations about z.

**Success Conditions:** the red cube rests on the green one (within half a cube size), static and released.
Sub-success: `reach` (the gripper's centre within 1.5 cm of the red cube's), `grasp` (the red cube was held at
some step), `lift` (held 2 cm above where it lay) and `place` (resting on the green one, released or not).

**Expert:** grasp the red cube from above without turning the gripper (its rotation actions are all zero, as
PickCube's expert's), lift 10 cm, move above the green cube, lower, release, retreat. Its success rate:
docs/simulation.md#tasks.

**OBSBench's camera and crop box:** ManiSkill's camera (0.6 m away, 90° field of view) shows a cube as ~6 pixels of
a 64² frame and loses it behind the hand in some episodes; the task camera looks down from the +x, +y side at
the cubes' spawn region, and point clouds are cropped to that region (tests/envs/test_task_cameras.py checks both).
"""

from __future__ import annotations

from lerobot_obsbench.envs.base_task import CUBE_HALF_SIZE, Task, bounding_radius, first, register_task
from lerobot_obsbench.envs.experts import CLOSED, OPEN, Phase, WaypointExpert, above


class StackCubeExpert(WaypointExpert):
    def plan(self):
        cube_a = lambda s: s.pose_of(s.env.cubeA)[0]
        half = float(first(self.env.cube_half_size)[0]) if hasattr(self.env, "cube_half_size") else 0.02
        on_b = lambda s: above(s.pose_of(s.env.cubeB)[0], 2 * half)
        return [
            Phase("pre-grasp", lambda s: above(cube_a(s), 0.05), OPEN),
            Phase("descend", cube_a, OPEN, tol=0.005),
            Phase("grasp", cube_a, CLOSED, tol=1.0, min_steps=4, max_steps=4),
            Phase("lift", lambda s: above(cube_a(s), 0.0) * [1, 1, 0] + [0, 0, 0.1], CLOSED),
            Phase("above B", lambda s: above(on_b(s), 0.04), CLOSED),
            Phase("lower", lambda s: above(on_b(s), 0.005), CLOSED, tol=0.005),
            Phase("release", lambda s: above(on_b(s), 0.005), OPEN, tol=1.0, min_steps=5, max_steps=5),
            Phase("retreat", lambda s: above(on_b(s), 0.08), OPEN, max_steps=30),
        ]


@register_task
class StackCube(Task):
    name = "StackCube-v1"
    max_steps = 70  # ManiSkill's: 50
    description = "stack the red cube on the green cube"
    grasped = "cubeA"
    privileged_actors = ("cubeA", "cubeB")
    camera_names = ("base_camera", "hand_camera")  # ManiSkill runs it with the wrist-camera Panda
    objects = dict.fromkeys(("cubeA", "cubeB"), bounding_radius(CUBE_HALF_SIZE, CUBE_HALF_SIZE, CUBE_HALF_SIZE))
    sub_success = ("reach", "grasp", "lift", "place")
    expert = StackCubeExpert
    expert_success_rate = 0.9  # as measured: docs/simulation.md#tasks
    # looking down at the table from the +x, +y side, so the hand (above x = 0) hides no cube at the start
    camera = ((0.45, 0.25, 0.55), (0.0, 0.0, 0.0), 0.9)
    # both cubes' spawn region (x in [-0.2, 0.2], y in [-0.3, 0.3]) plus a cube's bounding radius, from 5 mm above
    # the table (dropping it) to 20 cm, above the height the expert lifts a cube to
    workspace = (-0.24, 0.24, -0.34, 0.34, 0.005, 0.2)

    def milestone(self, name: str, ms_env, info: dict, success, start: dict):
        if name == "place":
            return info["is_cubeA_on_cubeB"].reshape(-1).bool()
        return super().milestone(name, ms_env, info, success, start)
