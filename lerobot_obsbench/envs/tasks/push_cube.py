"""PushCube-v1 and its variant PushCubeWide-v1.

**Task Description:** push the blue cube into the red/white target region in front of it (+x).

**Randomizations:** the cube's xy position in [-0.1, 0.1]^2 on the table; the target is always 0.2 m in +x of
the cube, so the policy finds both by seeing the cube (there is no goal observation).

**Success Conditions:** the cube's xy within 0.1 m of the target's centre, still on the table.

**Expert:** get behind the cube with the gripper closed and low, then push along +x to the target. Its
success rate: docs/simulation.md#tasks.

PushCubeWide-v1 (an OBSBench variant, the main job's task): the same task with the cube's y drawn from
[-0.2, 0.2] instead of [-0.1, 0.1] (x unchanged; the target still 0.2 m in +x of the cube). A policy that does
not see the cube pushes where it usually is and misses more often, so seeing policies separate from blind ones.
The same expert solves it.
Its camera looks down at the table region the cube and target can occupy (ManiSkill's looks at the robot from
0.6 m with a 90° field of view, where the cube spans ~2 pixels of a 64² frame), and point clouds are cropped to
the 10 cm above that region, as DP3's code crops to the task's workspace: at the episode's start the cloud is the
cube alone.
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
    privileged_actors = ("obj", "goal_region")
    objects = {"obj": bounding_radius(CUBE_HALF_SIZE, CUBE_HALF_SIZE, CUBE_HALF_SIZE)}


@register_task
class PushCubeWide(PushCube):
    name = "PushCubeWide-v1"
    maniskill_id = "PushCube-v1"
    description = "push the cube, placed anywhere in a 40 cm wide strip, into the goal region"
    # half extents of the cube's xy spawn box (ManiSkill's: 0.1, 0.1)
    spawn_half_size = (0.1, 0.2)
    # looking down from in front of the table at the region x in [-0.15, 0.4], y in [-0.3, 0.3]
    camera = ((0.5, 0.0, 0.6), (0.1, 0.0, 0.0), 1.0)
    # the spawn strip and the target, from 5 mm above the table (drops it and the flat target) to 10 cm
    workspace = (-0.2, 0.45, -0.35, 0.35, 0.005, 0.1)

    def initialize(self, ms_env) -> bool:
        spawn_cube_and_target(ms_env, self.spawn_half_size)
        return True
