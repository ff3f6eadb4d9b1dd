"""Stand-in PyRep (tests/support/fake_rlbench/README.md)."""
