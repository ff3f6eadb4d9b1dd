"""Stand-in RLBench (tests/support/fake_rlbench/README.md)."""
