"""Tests of lerobot_obsbench.encoders: the registry, the compact encoders and the zoo."""
