"""Real robots (docs/real-robot.md): a RealSense RGB-D camera, Koch follower arms with scene RGB-D cameras (one arm, or
two composed like LeRobot's bimanual SO arms), two Koch leaders, camera extrinsics from a ChArUco board.

Importing this package registers the configuration types with LeRobot (`obsbench_realsense_rgbd`,
`obsbench_koch_follower`, `obsbench_bi_koch_follower`, `obsbench_bi_koch_leader`); LeRobot's factories import the
device modules when a config is used, so neither pyrealsense2 nor dynamixel-sdk is needed to import the plugin.
"""

from lerobot_obsbench.robots.koch.config_bi_koch_leader import BiKochLeaderConfig
from lerobot_obsbench.robots.koch.config_bi_koch_rgbd_follower import BiKochRGBDFollowerConfig
from lerobot_obsbench.robots.koch.config_koch_rgbd_follower import KochRGBDFollowerConfig
from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig

__all__ = ["BiKochLeaderConfig", "BiKochRGBDFollowerConfig", "KochRGBDFollowerConfig", "RealSenseRGBDCameraConfig"]
