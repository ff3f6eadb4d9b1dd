"""Tests of lerobot_obsbench.envs: the ManiSkill env, its tasks and cameras, lockstep evaluation."""
