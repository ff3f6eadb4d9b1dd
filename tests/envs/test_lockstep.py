"""Lockstep evaluation (`envs.evaluate`, `envs.vector`): N episodes advance together, each env in a worker process,
one batched policy call per step, and each episode comes out as it would alone. The loop is checked here on a toy
env and policy (seed-dependent lengths and outcomes, actions that carry what the policy saw); the per-episode noise
of Diffusion Policy on a real policy; the ManiSkill runs, sequential against lockstep, are in test_sim.py."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from lerobot_obsbench.envs.evaluate import _run_wave, choose_sim_backend, policy_observation
from lerobot_obsbench.envs.maniskill import check_sim_backend
from lerobot_obsbench.envs.vector import BatchedEnvs, EnvWorkerError, InProcessEnvs, SubprocessEnvs, make_envs
from tests.support.helpers import training_setup
from tests.support.lockstep_envs import EchoPolicy, make_toy_batch_env, make_toy_env


def _identity(x):
    return x


def _wave(envs, seeds, steps=6, policy=None):
    policy = policy or EchoPolicy()
    records = _run_wave(envs, seeds, policy, _identity, _identity, steps, None, "cpu")
    return {r["seed"]: r for r in records}, policy


def _alone(seeds, steps):
    alone = {}
    for seed in seeds:
        envs = InProcessEnvs(make_toy_env, {"tag": "alone"})
        alone.update(_wave(envs, [seed], steps=steps)[0])
        envs.close()
    return alone


def test_a_wave_in_worker_processes_gives_each_episode_what_it_gets_alone():
    seeds = [5, 2, 7]  # successes at steps 3 and 4; seed 7 would need 5 steps and is cut at 4
    alone = _alone(seeds, steps=4)
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


@pytest.mark.parametrize("device, spawned", [("cpu", False), ("cuda", True)])
def test_workers_of_envs_that_render_on_a_gpu_are_spawned(device, spawned):
    """CUDA cannot start in a process forked from one where it started (on the GPU machine, the fork server's): envs
    on a CUDA device get fresh interpreters, children of this process; CPU envs come from the fork server."""
    envs = SubprocessEnvs(make_toy_env, {"device": device}, size=2)
    try:
        for slot in range(2):
            envs.call(slot, "process")
        processes = [envs.result(slot) for slot in range(2)]
    finally:
        envs.close()
    assert len({pid for pid, _ in processes}) == 2
    assert all((parent == os.getpid()) == spawned for _, parent in processes)


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
    from tests.support.helpers import first_batch

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
    from lerobot_obsbench.envs.vector import stacked

    batch = stacked([{"pixels": {"cam": np.zeros((2, 2, 3))}, "agent_pos": np.ones(3)}] * 4)
    assert batch["pixels"]["cam"].shape == (4, 2, 2, 3) and batch["agent_pos"].shape == (4, 3)


def test_one_batched_env_object_gives_each_slot_its_own_episode_and_fills_a_short_wave():
    """`BatchedEnvs` (ManiSkill's GPU simulation's shape: one object, all envs step on every call, tensors): a wave
    of 4 seeds, then a short wave of 2 on the same 4 envs, come out as each episode alone."""
    envs = make_envs(make_toy_batch_env, {"tag": "batched"}, 4, batched=True)
    assert isinstance(envs, BatchedEnvs)
    try:
        first, policy = _wave(envs, [5, 2, 7, 4], steps=4)
        short, short_policy = _wave(envs, [3, 6], steps=6)
        with pytest.raises(ValueError, match="a wave of 5 seeds for 4 batched envs"):
            envs.reset([1, 2, 3, 4, 5])
    finally:
        envs.close()
    assert first == _alone([5, 2, 7, 4], steps=4) and short == _alone([3, 6], steps=6)
    assert [short[s]["length"] for s in (3, 6)] == [5, 4] and all(r["named"] for r in short.values())
    assert envs.env.seeds_seen[1] == [3, 6, 6, 6]  # the spare envs rerun the wave's last seed, unread
    assert set(policy.batch_sizes) == {4} and set(short_policy.batch_sizes) == {2}  # the policy sees the wave only
    assert len(envs.render([0, 1])) == 2


def test_policy_observation_of_device_tensors_is_lerobots_preprocessing():
    """The observation a batched simulator keeps as tensors is turned into exactly what LeRobot's
    `preprocess_observation` makes of the same arrays."""
    from lerobot.envs.utils import preprocess_observation

    rng = np.random.default_rng(0)
    arrays = {
        "pixels": {"base_camera": rng.integers(0, 256, (3, 8, 8, 3), dtype=np.uint8)},
        "agent_pos": rng.normal(size=(3, 16)).astype(np.float32),
        "environment_state": rng.normal(size=(3, 3)).astype(np.float32),
        "robot_state": {"depth.base_camera": rng.integers(0, 2000, (3, 8, 8, 1)).astype(np.uint16)},
    }
    tensors = {
        "pixels": {k: torch.from_numpy(v) for k, v in arrays["pixels"].items()},
        "agent_pos": torch.from_numpy(arrays["agent_pos"]),
        "environment_state": torch.from_numpy(arrays["environment_state"]),
        "robot_state": {k: torch.from_numpy(v) for k, v in arrays["robot_state"].items()},
    }
    stock, ours = preprocess_observation(arrays), policy_observation(tensors)
    assert policy_observation(arrays).keys() == stock.keys() == ours.keys()
    for key, value in stock.items():
        if isinstance(value, dict):
            for name in value:
                assert torch.equal(ours[key][name], value[name]), name
        else:
            assert ours[key].dtype == value.dtype and torch.equal(ours[key], value), key


def test_the_simulation_backend_follows_device_batch_and_perturbation():
    assert choose_sim_backend("auto", "cuda", 64, None) == "physx_cuda"
    assert choose_sim_backend("auto", "cuda:1", 64, "camera_yaw:10") == "physx_cuda"
    assert choose_sim_backend("auto", "cuda", 1, None) == "physx_cpu"  # one env: CPU simulation, GPU rendering
    assert choose_sim_backend("auto", "cuda", 64, "noise:16") == "physx_cpu"  # ray tracing: one env per process
    assert choose_sim_backend("auto", "cpu", 3, None) == "physx_cpu"
    assert choose_sim_backend("physx_cpu", "cuda", 64, None) == "physx_cpu"
    with pytest.raises(ValueError, match="physx_cuda.*needs --policy.device=cuda"):
        choose_sim_backend("physx_cuda", "cpu", 4, None)
    with pytest.raises(ValueError, match="--eval.sim_backend must be auto or one of physx_cpu, physx_cuda"):
        choose_sim_backend("gpu", "cuda", 4, None)
    # the env's own check, before ManiSkill starts
    assert check_sim_backend(None, 1, "cpu") == "physx_cpu" and check_sim_backend(None, 8, "cuda") == "physx_cuda"
    with pytest.raises(ValueError, match=r"GPU simulation \(physx_cuda\) needs a CUDA device"):
        check_sim_backend(None, 8, "cpu")
    with pytest.raises(ValueError, match="CPU simulation holds one env per process; got num_envs=2"):
        check_sim_backend("physx_cpu", 2, "cuda")
    with pytest.raises(ValueError, match="num_envs must be a whole number >= 1"):
        check_sim_backend(None, 0, "cuda")


def test_a_gpu_simulation_without_sapiens_gpu_physx_library_says_how_to_get_it(monkeypatch, tmp_path):
    """On an offline H200 SAPIEN's first GPU simulation tried to download its GPU PhysX library from GitHub
    and failed name resolution (benchmarks/results/device_check_cuda.json): the env says what is missing and what
    to do, not requests' traceback."""
    import gymnasium
    import requests

    from lerobot_obsbench.envs import maniskill

    def offline(*args, **kwargs):
        raise requests.exceptions.ConnectionError("Failed to resolve 'github.com'")

    monkeypatch.setenv("HOME", str(tmp_path))  # where SAPIEN keeps the library: none there
    monkeypatch.setattr(gymnasium, "make", offline)
    with pytest.raises(maniskill.GpuSimulationError) as raised:
        maniskill.ObsBenchEnv("PushCubeWide-v1", image_size=32, device="cuda", num_envs=2, sim_backend="physx_cuda")
    message = str(raised.value)
    assert str(tmp_path / ".sapien" / "physx") in message and "Failed to resolve 'github.com'" in message
    assert "--eval.sim_backend=physx_cpu" in message and "scripts/device_bundle.py" in message


def test_an_evaluation_without_sapiens_gpu_physx_library_falls_back_to_the_cpu_simulation(monkeypatch, tmp_path):
    """Where the GPU simulation cannot run (its library absent: an offline node), the evaluation degrades to the
    CPU simulation with one line naming the file and where it goes, instead of failing."""
    from lerobot_obsbench.envs import evaluate
    from lerobot_obsbench.envs.maniskill import physx_gpu_library

    monkeypatch.setenv("HOME", str(tmp_path))
    said = []
    assert (
        evaluate.available_sim_backend(evaluate.choose_sim_backend("auto", "cuda", 4, None), said.append) == "physx_cpu"
    )
    (line,) = said
    assert str(physx_gpu_library()) in line and "evaluating on the CPU simulation" in line
    assert evaluate.available_sim_backend("physx_cpu", said.append) == "physx_cpu" and len(said) == 1
    physx_gpu_library().parent.mkdir(parents=True)
    physx_gpu_library().write_bytes(b"\x7fELF")  # there: the GPU simulation is kept
    assert evaluate.available_sim_backend("physx_cuda", said.append) == "physx_cuda" and len(said) == 1


@pytest.mark.parametrize("size", [1, 2])
def test_any_env_method_runs_in_its_slot(size):
    """`call` + `result` (whole expert episodes for `obsbench demos --workers`): each slot's own env answers."""
    envs = make_envs(make_toy_env, {"tag": "calls"}, size)
    try:
        for slot in range(size):
            envs.call(slot, "reset", 4 + slot)
        assert [envs.result(slot)[0]["agent_pos"].tolist() for slot in range(size)] == [[4 + s, 0] for s in range(size)]
        envs.call(0, "step", np.array([9.0, 0.0]))
        assert not envs.result(0)[4]["sub_success/named"]  # the action named another seed
    finally:
        envs.close()
