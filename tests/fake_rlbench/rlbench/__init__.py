"""Stand-in RLBench (tests/fake_rlbench/README.md)."""
