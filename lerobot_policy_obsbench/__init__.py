"""Shim imported by LeRobot's plugin discovery (distribution names starting with `lerobot_policy_`).

Importing it registers the `obs_act` / `obs_diffusion` policies and applies the plugin's LeRobot fixes.
"""

import lerobot_obsbench  # noqa: F401
