"""Stand-in PyRep (tests/fake_rlbench/README.md)."""
