"""Tests of lerobot_obsbench.bench: grids, the runner end to end, the report, the paper's tables, the Hub."""
