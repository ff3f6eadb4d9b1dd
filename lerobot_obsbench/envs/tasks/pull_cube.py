"""PullCube-v1 and its variant PullCubeWide-v1.

**Task Description:** pull the cube back (-x) onto the red/white target behind it; the target position is
given to the policy as observation.environment_state.

**Randomizations:** the cube's xy position in [-0.1, 0.1]^2 on the table; the target is 0.2 m in -x of it.

**Success Conditions:** the cube's xy within 0.1 m of the target's centre.

**Expert:** reach over the cube, lower in front of it with the gripper closed, pull back to the target.
Its success rate: docs/simulation.md#tasks.

PullCubeWide-v1 (an OBSBench variant): the cube's y drawn from [-0.2, 0.2] instead of [-0.1, 0.1] (x unchanged;
the target still 0.2 m in -x of it) and no goal observation: PullCube-v1 gives every policy the target's
position, which places the cube for a blind one too, so only a policy that sees the cube (or the target) knows
where to pull. The same expert solves it. Its camera looks down from beyond the table's far side at the region
the cube and target can occupy; point clouds are cropped to the 10 cm above that region.
"""

from __future__ import annotations

import numpy as np

from lerobot_obsbench.envs.base_task import (
    CUBE_HALF_SIZE,
    Task,
    bounding_radius,
    first,
    register_task,
    spawn_cube_and_target,
)
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


@register_task
class PullCubeWide(PullCube):
    name = "PullCubeWide-v1"
    maniskill_id = "PullCube-v1"
    description = "pull the cube, placed anywhere in a 40 cm wide strip, back into the goal region"
    # no goal observation: the target's position would tell a blind policy where the cube is
    goal = {}
    # half extents of the cube's xy spawn box (ManiSkill's: 0.1, 0.1)
    spawn_half_size = (0.1, 0.2)
    # looking down from beyond the cube at the region x in [-0.45, 0.2], y in [-0.3, 0.3]
    camera = ((0.3, 0.0, 0.6), (-0.1, 0.0, 0.0), 1.0)
    # the spawn strip and the target, from 5 mm above the table (drops it and the flat target) to 10 cm
    workspace = (-0.45, 0.2, -0.35, 0.35, 0.005, 0.1)

    def initialize(self, ms_env) -> bool:
        spawn_cube_and_target(ms_env, self.spawn_half_size)
        return True
