"""PullCube-v1.

**Task Description:** pull the cube back (-x) onto the red/white target behind it; the target position is
given to the policy as observation.environment_state.

**Randomizations:** the cube's xy position in [-0.1, 0.1]^2 on the table; the target is 0.2 m in -x of it.

**Success Conditions:** the cube's xy within 0.1 m of the target's centre.

**Expert:** reach over the cube, lower in front of it with the gripper closed, pull back to the target.
Its success rate: docs/simulation.md#tasks.
"""

from __future__ import annotations

import numpy as np

from lerobot_obsbench.envs.base_task import CUBE_HALF_SIZE, Task, bounding_radius, first, register_task
from lerobot_obsbench.envs.experts import CLOSED, Phase, WaypointExpert, above


class PullCubeExpert(WaypointExpert):
    def plan(self):
        cube = lambda s: s.pose_of(s.env.obj)[0]
        goal = lambda s: first(s.env.goal_region.pose.p)
        half = 0.02
        front = lambda s: np.array([cube(s)[0] + half + 0.03, cube(s)[1], 0.02])
        return [
            Phase("above front", lambda s: above(front(s), 0.08), CLOSED),
            Phase("down front", front, CLOSED, tol=0.005),
            Phase(
                "pull",
                lambda s: np.array([goal(s)[0] + half + 0.01, goal(s)[1], 0.02]),
                CLOSED,
                tol=0.005,
                max_steps=60,
            ),
        ]


@register_task
class PullCube(Task):
    name = "PullCube-v1"
    max_steps = 50
    description = "pull the cube back into the goal region"
    goal = {"goal_pos": 3}
    privileged_actors = ("obj", "goal_region")
    objects = {"obj": bounding_radius(CUBE_HALF_SIZE, CUBE_HALF_SIZE, CUBE_HALF_SIZE)}
    expert = PullCubeExpert
