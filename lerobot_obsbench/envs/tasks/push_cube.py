"""PushCube-v1.

**Task Description:** push the blue cube into the red/white target region in front of it (+x).

**Randomizations:** the cube's xy position in [-0.1, 0.1]^2 on the table; the target is always 0.2 m in +x of
the cube, so the policy finds both by seeing the cube (there is no goal observation).

**Success Conditions:** the cube's xy within 0.1 m of the target's centre, still on the table.

**Expert:** get behind the cube with the gripper closed and low, then push along +x to the target. 20/20 over
seeds 100000.. (mean 12.3 steps).
"""

from __future__ import annotations

import numpy as np

from lerobot_obsbench.envs.experts import CLOSED, Phase, WaypointExpert, above
from lerobot_obsbench.envs.task import Task, first, register_task


class PushCubeExpert(WaypointExpert):
    def plan(self):
        cube = lambda s: s.pose_of(s.env.obj)[0]
        goal = lambda s: first(s.env.goal_region.pose.p)
        half = 0.02
        behind = lambda s: np.array([cube(s)[0] - half - 0.03, goal(s)[1], 0.02])
        return [
            Phase("above behind", lambda s: above(behind(s), 0.08), CLOSED),
            Phase("down behind", behind, CLOSED, tol=0.005),
            Phase(
                "push",
                lambda s: np.array([goal(s)[0] - half + 0.005, goal(s)[1], 0.02]),
                CLOSED,
                tol=0.005,
                max_steps=60,
            ),
        ]


@register_task
class PushCube(Task):
    name = "PushCube-v1"
    max_steps = 50
    description = "push the cube into the goal region"
    expert = PushCubeExpert
