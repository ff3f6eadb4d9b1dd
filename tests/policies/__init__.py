"""Tests of lerobot_policy_obsbench: obs_act / obs_diffusion, the controls, old checkpoints, the paper protocol."""
