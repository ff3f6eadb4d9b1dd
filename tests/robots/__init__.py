"""Tests of lerobot_obsbench.robots: Koch arms, RealSense cameras, extrinsics and fusion, stock-recorded depth."""
