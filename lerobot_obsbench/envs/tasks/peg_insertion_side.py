"""PegInsertionSide-v1.

**Task Description:** pick up the orange-white peg and insert its orange end into the hole of the box, from
the side.

**Randomizations:** (at reconfiguration) the peg's half length 0.085..0.125 m, the box as long, the peg's half
width 0.015..0.025 m with 3 mm of clearance in the hole; (every episode) the peg's and the box's xy positions
and rotations about z, both lying on the table.

**Success Conditions:** the peg's head within 1.5 cm of the box's centre (inserted half way). Sub-success, as
the paper reports: `grasp` (the peg was held), `align` (the peg's head within the hole's cross-section at the
entrance or inside), `insert` (= success).

**Expert:** grasp the peg behind its middle, lift, line it up 2 cm out of the hole's entrance, push it home
along its axis, closing the loop on the peg's pose in the gripper. It fails
more often than it succeeds (docs/simulation.md#tasks), so recording screens seeds without cameras first.

**OBSBench's camera and crop box:** ManiSkill's camera stands at the back edge of the peg's region looking
along the table, so a peg near it falls out of the frame in about a third of the episodes; the task camera looks
across both regions from the front, and point clouds are cropped to them (tests/envs/test_task_cameras.py checks both).
"""

from __future__ import annotations

from lerobot_obsbench.envs.base_task import Task, bounding_radius, first, register_task
from lerobot_obsbench.envs.experts import InsertionExpert

PEG = "peg"
# the largest peg ManiSkill builds (metres): the bounds of its randomized half length and half width
PEG_HALF_LENGTH, PEG_HALF_WIDTH = 0.125, 0.025


class PegInsertionSideExpert(InsertionExpert):
    object_name = PEG

    def grasp_offset(self):  # behind the middle, leaving the head free
        return -0.5 * float(first(self.env.peg_half_sizes)[0])

    def line_up_offset(self):  # the hole runs through a box as long as the peg: head 2 cm out of the entrance
        return -(float(first(self.env.peg_half_sizes)[0]) + 0.02)


@register_task
class PegInsertionSide(Task):
    name = "PegInsertionSide-v1"
    max_steps = 120  # ManiSkill's: 100
    description = "insert the peg into the hole of the box from the side"
    grasped = PEG
    privileged_actors = (PEG, "box")
    camera_names = ("base_camera", "hand_camera")  # ManiSkill runs it with the wrist-camera Panda
    sub_success = ("grasp", "align", "insert")
    expert = PegInsertionSideExpert
    expert_success_rate = 0.26  # as measured: docs/simulation.md#tasks
    # the longest peg and its box (a cube of half side the peg's half length)
    objects = {
        PEG: bounding_radius(PEG_HALF_LENGTH, PEG_HALF_WIDTH, PEG_HALF_WIDTH),
        "box": bounding_radius(*[PEG_HALF_LENGTH] * 3),
    }
    # from the front (+x), high enough to see the peg's and the box's regions (1 m along y) side by side
    camera = ((0.7, 0.07, 0.6), (0.0, 0.07, 0.05), 1.1)
    # the peg's (x in [-0.1, 0.1], y in [-0.3, 0]) and the box's (x in [-0.05, 0.05], y in [0.2, 0.4]) spawn
    # regions plus their bounding radii, from 5 mm above the table (dropping it) to above the tallest box (0.25 m)
    workspace = (-0.27, 0.27, -0.45, 0.62, 0.005, 0.3)

    def milestone(self, name: str, ms_env, info: dict, success, start: dict):
        if name == "insert":
            return success
        if name == "align":  # peg head within the hole's cross-section (before or while inserting)
            head = info["peg_head_pos_at_hole"].reshape(-1, 3)
            radius = ms_env.box_hole_radii.reshape(-1)
            return (head[:, 1].abs() <= radius) & (head[:, 2].abs() <= radius) & (head[:, 0] >= -0.05)
        return super().milestone(name, ms_env, info, success, start)
