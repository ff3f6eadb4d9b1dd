"""PlugCharger-v1.

**Task Description:** pick up the charger and plug it into the receptacle.

**Randomizations:** the charger's and the receptacle's xy positions on the table and rotations about z.

**Success Conditions:** the charger inserted into the receptacle. Sub-success: `grasp` (the charger was held).

**Expert:** grasp the charger's base, lift, line the prongs up 2 cm short of the socket, push them home,
closing the loop on the charger's pose in the gripper. Slow and weak (docs/simulation.md#tasks): prefer
`obsbench import-h5` of official demonstrations.
"""

from __future__ import annotations

from lerobot_obsbench.envs.base_task import Task, register_task
from lerobot_obsbench.envs.experts import InsertionExpert

CHARGER = "charger"


class PlugChargerExpert(InsertionExpert):
    object_name = CHARGER

    def grasp_offset(self):  # the middle of the charger's base (its frame sits where the prongs start)
        return -float(self.env._base_size[0])

    def line_up_offset(self):  # prongs 2 cm short of the socket
        return -(2 * float(self.env._peg_size[0]) + 0.02)


@register_task
class PlugCharger(Task):
    name = "PlugCharger-v1"
    max_steps = 200
    description = "plug the charger into the socket"
    grasped = CHARGER
    sub_success = ("grasp",)
    expert = PlugChargerExpert
    expert_success_rate = 0.25  # as measured: docs/simulation.md#tasks
    privileged_actors = (CHARGER, "receptacle")
    camera_names = ("base_camera", "hand_camera")  # ManiSkill runs it with the wrist-camera Panda
