"""LiftPegUpright-v1.

**Task Description:** stand the peg lying on the table upright.

**Randomizations:** the peg's xy position in [-0.1, 0.1]^2, lying along its length, and its rotation about z.

**Success Conditions:** the peg's axis within 0.08 rad of vertical and its centre within 5 mm of its
half-length above the table.

**Expert:** pinch the lying peg lightly near one end and lift that end: the peg swings about the finger axis
until it hangs upright below the fingers; lower it onto the table and let go (turning a firmly grasped peg by
90 degrees instead stalls near the Panda's wrist limit). Its success rate: docs/simulation.md#tasks.

Its camera looks down at the region the lying peg can cover (ManiSkill's sees it from the robot's side); point
clouds are cropped to the box the peg lies and stands in.
"""

from __future__ import annotations

import numpy as np

from lerobot_obsbench.envs.base_task import Task, register_task
from lerobot_obsbench.envs.experts import OPEN, Phase, WaypointExpert, above, grasp_yaw, top_down


class LiftPegUprightExpert(WaypointExpert):
    pinch = 0.05  # gripper command that touches the peg with little force, so it can pivot between the fingers

    def plan(self):
        half_length = float(self.env.peg_half_length)
        peg = lambda s: s.matrix_of(s.env.peg.pose)
        near_end = lambda s: (peg(s) @ np.array([-(half_length - 0.02), 0, 0, 1]))[:3]
        rotation = lambda s: top_down(grasp_yaw(s.tcp()[1], s.pose_of(s.env.peg)[1], np.pi))
        self.raised = None

        def high(s):
            if s.raised is None:
                s.raised = s.tcp()[0] * [1, 1, 0] + [0, 0, 0.32]
            return s.raised

        def standing(s):  # lower until the peg's centre is at its standing height
            return s.tcp()[0] + [0, 0, half_length + 0.003 - s.pose_of(s.env.peg)[0][2]]

        return [
            Phase("pre-grasp", lambda s: above(near_end(s), 0.06), OPEN, rotation),
            Phase("descend", near_end, OPEN, rotation, tol=0.005),
            Phase("pinch", near_end, self.pinch, rotation, tol=1.0, min_steps=5, max_steps=5),
            Phase("raise", high, self.pinch, rotation, tol=0.01, max_steps=30),
            Phase("swing", high, self.pinch, rotation, tol=1.0, min_steps=5, max_steps=5),
            Phase("lower", standing, self.pinch, rotation, tol=0.003, max_steps=40, gain=1.0),
            Phase("release", lambda s: s.tcp()[0], OPEN, tol=1.0, min_steps=5, max_steps=5),
        ]


@register_task
class LiftPegUpright(Task):
    name = "LiftPegUpright-v1"
    max_steps = 70  # ManiSkill's: 50
    description = "lift the lying peg into an upright pose"
    expert = LiftPegUprightExpert
    privileged_actors = ("peg",)
    objects = {"peg": 0.125}  # 12 cm half-length peg
    # looking down from in front of the table at the region the lying peg can cover and the height it stands to
    camera = ((0.45, 0.0, 0.55), (0.0, 0.0, 0.1), 1.0)
    # the lying peg anywhere in its spawn square and standing upright, from 5 mm above the table (drops it)
    workspace = (-0.3, 0.3, -0.3, 0.3, 0.005, 0.35)
