"""Lockstep evaluation (`envs.evaluate`, `envs.vector`): N episodes advance together, each env in a worker process,
one batched policy call per step, and each episode comes out as it would alone. The loop is checked here on a toy
env and policy (seed-dependent lengths and outcomes, actions that carry what the policy saw); the per-episode noise
of Diffusion Policy on a real policy; the ManiSkill runs, sequential against lockstep, are in test_sim.py."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_obsbench.envs.evaluate import _run_wave
from lerobot_obsbench.envs.vector import EnvWorkerError, InProcessEnvs, SubprocessEnvs, make_envs
from tests.helpers import training_setup
from tests.lockstep_envs import EchoPolicy, make_toy_env


def _identity(x):
    return x


def _as_tensors(observation: dict) -> dict:
    return {k: torch.as_tensor(v) for k, v in observation.items()}


def _wave(envs, seeds, steps=6, policy=None):
    policy = policy or EchoPolicy()
    records = _run_wave(envs, seeds, policy, _identity, _identity, _as_tensors, steps, None, "cpu")
    return {r["seed"]: r for r in records}, policy


def test_a_wave_in_worker_processes_gives_each_episode_what_it_gets_alone():
    seeds = [5, 2, 7]  # successes at steps 3 and 4; seed 7 would need 5 steps and is cut at 4
    alone = {}
    for seed in seeds:
        envs = InProcessEnvs(make_toy_env, {"tag": "alone"})
        alone.update(_wave(envs, [seed], steps=4)[0])
        envs.close()
    envs = SubprocessEnvs(make_toy_env, {"tag": "worker"}, size=3)
    try:
        together, policy = _wave(envs, seeds, steps=4)
    finally:
        envs.close()
    assert together == alone
    assert [together[s]["length"] for s in seeds] == [3, 4, 4]
    assert [together[s]["success"] for s in seeds] == [True, True, False]
    assert all(together[s]["named"] for s in seeds)  # every action named its own slot's seed
    # reward = the step each slot's policy row saw: 0 + 1 + 2 (+ 3)
    assert [together[s]["reward_sum"] for s in seeds] == [3.0, 6.0, 6.0]
    # one batched call per step of the wave (finished slots are not stepped again: the toy env would raise)
    assert policy.batch_sizes == [3, 3, 3, 3] and policy.resets == 1


def test_a_worker_error_is_raised_in_the_parent_as_itself_with_the_workers_traceback():
    envs = make_envs(make_toy_env, {}, 2)
    try:
        with pytest.raises(ValueError, match="^seed 13 cannot be reset$") as raised:
            envs.reset([4, 13])
    finally:
        envs.close()
    assert isinstance(raised.value.__cause__, EnvWorkerError)
    assert "in env worker 1:" in str(raised.value.__cause__) and "lockstep_envs.py" in str(raised.value.__cause__)
    with pytest.raises(ValueError, match="batch size must be >= 1"):
        make_envs(make_toy_env, {}, 0)


def test_diffusion_draws_each_rows_noise_from_its_episodes_generator(tiny_dataset):
    """Row i of a lockstep batch samples what episode i alone samples after torch.manual_seed(its seed)."""
    from tests.helpers import first_batch

    policy, pre, _, dataset = training_setup("obs_diffusion", "rgb", tiny_dataset)
    policy.eval()
    batch = first_batch(dataset, pre, batch_size=2, shuffle=True)
    seeds = [11, 12]
    with torch.inference_mode():
        alone = []
        for row, seed in enumerate(seeds):
            torch.manual_seed(seed)
            row_batch = {k: v[row : row + 1] if torch.is_tensor(v) else v for k, v in batch.items()}
            alone.append(policy.diffusion.generate_actions(row_batch))
        generators = [torch.Generator().manual_seed(seed) for seed in seeds]
        with policy.episode_generators(generators):
            together = policy.diffusion.generate_actions(batch)
        torch.manual_seed(seeds[0])
        shared = policy.diffusion.generate_actions(batch)  # one stream for the whole batch: not what row 1 alone sees
    torch.testing.assert_close(together, torch.cat(alone), atol=1e-5, rtol=0)  # batched products round differently
    assert (shared[1] - alone[1][0]).abs().max() > 1e-3
    assert policy.diffusion.episode_generators is None  # only within the context


def test_stacking_per_slot_observations_keeps_the_nesting():
    from lerobot_obsbench.envs.evaluate import _stacked

    stacked = _stacked([{"pixels": {"cam": np.zeros((2, 2, 3))}, "agent_pos": np.ones(3)}] * 4)
    assert stacked["pixels"]["cam"].shape == (4, 2, 2, 3) and stacked["agent_pos"].shape == (4, 3)
