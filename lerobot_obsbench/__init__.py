"""lerobot-obsbench: OBSBench as a LeRobot plugin.

Importing the package registers the `obs_act` and `obs_diffusion` policy types, the `obsbench` env type, the
real-robot hardware types (`obsbench_realsense_rgbd`, `obsbench_koch_follower`, `obsbench_bi_koch_follower`,
`obsbench_bi_koch_leader`) and the encoder registry with LeRobot, and applies the plugin's narrow LeRobot
data-loading fixes (see `lerobot_obsbench.patches`); lerobot-train then loads only what the plugin's policies
read, decoded once (`lerobot_obsbench.dataset_reads`).
"""

import os
from importlib.metadata import version

# SVT-AV1, LeRobot's video encoder, prints ~20 banner lines per encoded episode; keep its errors only.
os.environ.setdefault("SVT_LOG", "1")

from lerobot_obsbench import dataset_reads, patches

if patches.apply():
    dataset_reads.install()
from lerobot_obsbench import encoders, envs, policies, robots  # (registration side effects)
from lerobot_obsbench.encoders import available_encoders, make_encoder
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter

dataset_reads.announce()  # shown where logging is set up before plugins are imported (lerobot-eval)
patches.refusals_in_one_line()  # in a stock lerobot-* command: the plugin's refusals as one line, as obsbench prints
__version__ = version("lerobot_policy_obsbench")  # one source: pyproject.toml (the distribution name)
__all__ = [
    "AdapterConfig",
    "ObservationAdapter",
    "available_encoders",
    "encoders",
    "envs",
    "make_encoder",
    "policies",
    "robots",
    "__version__",
]
