"""TurnFaucet-v1.

**Task Description:** turn the faucet's handle past a target angle.

**Randomizations:** the faucet model (PartNet-Mobility), its pose on the table, and the target angle.

**Success Conditions:** the handle's joint beyond the target angle.

**Expert:** none; the PartNet-Mobility assets cannot be downloaded on these machines. Record demonstrations
with ManiSkill elsewhere and convert them with `obsbench import-h5 --h5 FILE.h5 --out DIR --asset-dir ASSETS`;
evaluate with `--env.asset_dir=ASSETS`.
"""

from __future__ import annotations

from lerobot_obsbench.envs.base_task import Task, register_task


@register_task
class TurnFaucet(Task):
    name = "TurnFaucet-v1"
    max_steps = 200
    description = "turn the faucet handle (needs PartNet-Mobility assets)"
    asset_group = "partnet_mobility_faucet"
    camera_names = ("base_camera", "hand_camera")  # ManiSkill runs it with the wrist-camera Panda
