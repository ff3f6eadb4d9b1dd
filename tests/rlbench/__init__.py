"""Tests of lerobot_obsbench.rlbench: formats, import, evaluation and a grid against the stand-in simulator."""
