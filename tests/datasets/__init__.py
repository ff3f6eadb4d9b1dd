"""Tests of lerobot_obsbench.datasets: validation and viewing of recordings."""
