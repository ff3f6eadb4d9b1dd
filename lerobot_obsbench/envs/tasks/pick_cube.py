"""PickCube-v1.

**Task Description:** grasp the red cube and move it to a goal position in the air (shown as a green sphere,
which the cameras do not see); the goal position is given to the policy as observation.environment_state.

**Randomizations:** the cube's xy position in [-0.1, 0.1]^2 on the table and its rotation about z; the goal's
xy in [-0.1, 0.1]^2 and its height 0..0.3 m above the cube's.

**Success Conditions:** the cube within 2.5 cm of the goal while the robot is static.
Sub-success: `reach` (the gripper's centre within 1.5 cm of the cube's), `grasp`, `lift` (held 2 cm above where it
lay) and `place` (the cube within 2.5 cm of the goal, the robot moving or not).

**Expert:** grasp the cube from above without turning the gripper (its fingers square the cube up as they close;
its rotation actions are all zero), carry it to the goal, hold still. Its success rate and why it does not turn:
docs/simulation.md#tasks.

**OBSBench's camera and crop box:** ManiSkill's camera shows the cube as ~6 pixels of a 64² frame; the task camera
looks at the spawn square from closer, and point clouds are cropped to the square and the air above it up to the
highest goal (the clouds hold what of it the camera sees: a cube carried to the highest goals leaves the frame;
tests/envs/test_task_cameras.py checks the start of every episode).
"""

from __future__ import annotations

from lerobot_obsbench.envs.base_task import CUBE_HALF_SIZE, Task, bounding_radius, first, register_task
from lerobot_obsbench.envs.experts import CLOSED, OPEN, Phase, WaypointExpert, above


class PickCubeExpert(WaypointExpert):
    def plan(self):
        cube = lambda s: s.pose_of(s.env.cube)[0]
        goal = lambda s: first(s.env.goal_site.pose.p)
        return [
            Phase("pre-grasp", lambda s: above(cube(s), 0.05), OPEN),
            Phase("descend", cube, OPEN, tol=0.005),
            Phase("grasp", cube, CLOSED, tol=1.0, min_steps=4, max_steps=4),
            Phase("to goal", goal, CLOSED, tol=0.005, max_steps=60),
            Phase("hold", goal, CLOSED, tol=1.0, min_steps=30, max_steps=30),
        ]


@register_task
class PickCube(Task):
    name = "PickCube-v1"
    max_steps = 50
    description = "pick up the red cube and move it to the goal"
    goal = {"goal_pos": 3}
    privileged_actors = ("cube", "goal_site")
    objects = {"cube": bounding_radius(CUBE_HALF_SIZE, CUBE_HALF_SIZE, CUBE_HALF_SIZE)}
    expert = PickCubeExpert
    grasped = "cube"
    sub_success = ("reach", "grasp", "lift", "place")
    # closer to the spawn square than ManiSkill's camera, with a narrower field of view
    camera = ((0.35, 0.0, 0.45), (0.0, 0.0, 0.05), 0.9)
    # the cube's and the goal's square (±0.1 m) plus the cube's bounding radius, up to above the highest goal
    # (0.3 m over the cube), from 5 mm above the table (dropping it)
    workspace = (-0.15, 0.15, -0.15, 0.15, 0.005, 0.4)

    def milestone(self, name: str, ms_env, info: dict, success, start: dict):
        if name == "place":
            return info["is_obj_placed"].reshape(-1).bool()
        return super().milestone(name, ms_env, info, success, start)
