"""Success-rate evaluation of a trained policy on the fixed held-out seeds of an OBSBench task.

Episode i uses seed `eval_seeds(n, split)[i]` (test: 0, 1, ..., n-1; validation, for checkpoint selection:
10000, ...) for the env and for the policy's sampling noise, so a given checkpoint, task and seed list always
gives the same result on the same machine. The policy sees exactly what stock `lerobot-eval` would feed it
(LeRobot's `preprocess_observation`, then the checkpoint's own pre/post-processors).

Lockstep (`batch_size` N > 1): the seeds run in waves of N episodes that advance together, each env in a worker
process of its own (`envs.vector`), and the policy gets one batch of N observations per step. All episodes of a
wave start together, so LeRobot's own action and observation queues serve every slot, as in stock
`lerobot-eval --eval.batch_size`; a finished episode's slot is left out of stepping and its actions are ignored
until the wave ends. A policy that samples (Diffusion Policy) draws each slot's noise from a generator seeded
with that slot's episode seed, the stream `torch.manual_seed(seed)` gives one episode at a time. Seed for seed,
lockstep therefore computes what sequential evaluation computes; only the batched matrix products round
differently (1e-7 to 1e-6 in the networks' outputs on CPU), and ManiSkill's CPU simulation carries contact state
from one episode into the next in the same env (slot k runs seeds k, k + N, ...): either can flip only an episode
that sits on a knife edge (measured in docs/simulation.md).

On a CUDA device, lockstep defaults to ManiSkill's GPU simulation (`sim_backend` physx_cuda): the wave's N envs
simulate and render in one process and their observations stay on the GPU up to the policy. Its results are not
those of the CPU simulation, seed for seed: the physics engine differs, and ManiSkill seeds a whole batch's
torch-drawn initial states from its first env's seed, so an episode's start depends on the wave it runs in
(deterministic for the same seeds and N). Compare checkpoints within one simulation backend; `physx_cpu` keeps the
CPU simulation on any device. Where SAPIEN's GPU PhysX library is missing (an offline node: SAPIEN downloads it from
GitHub at the first GPU simulation), the evaluation runs on the CPU simulation instead, saying so in one line.
"""

from __future__ import annotations

import json
import sys
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from lerobot_obsbench.envs.base_task import eval_seeds
from lerobot_obsbench.envs.catalog import is_metaworld, make_task_env, task_record
from lerobot_obsbench.envs.maniskill import (
    ACTION_DIMS,
    DEFAULT_CONTROL_MODE,
    SIM_BACKENDS,
    STATE_DIM,
    make_obsbench_env,
    physx_gpu_library,
)
from lerobot_obsbench.envs.metaworld.env import ACTION_SIZE as METAWORLD_ACTION
from lerobot_obsbench.envs.metaworld.env import STATE_SIZE as METAWORLD_STATE
from lerobot_obsbench.envs.metaworld.env import rendered_sensors
from lerobot_obsbench.envs.perturbations import (
    MANISKILL_KINDS,
    METAWORLD_KINDS,
    check_changes,
    check_supported,
    parse_perturbation,
)
from lerobot_obsbench.envs.vector import make_envs
from lerobot_obsbench.errors import ConfigError, UsageError
from lerobot_obsbench.outputs import record_outputs, write_json_atomic, write_text_atomic
from lerobot_obsbench.policies.loading import load_policy
from lerobot_obsbench.schema import IMAGE_PREFIX, check_compatibility
from lerobot_obsbench.stats import per_seed, success_summary


def check_compatible(config, cameras: list[str], image_size: int, control_mode: str, task: str) -> None:
    """Refuse a policy whose cameras, image size, state, action or oracle objects do not match the env."""
    spec = task_record(task)
    state, action = (
        (METAWORLD_STATE, METAWORLD_ACTION) if is_metaworld(spec) else (STATE_DIM, ACTION_DIMS[control_mode])
    )
    check_compatibility(config, cameras, (image_size, image_size), state, action, spec.privileged_actors)


def _metaworld_options(spec, control_mode: str, sim_backend: str) -> None:
    """Refuse the ManiSkill-only settings for a Meta-World task, which would otherwise be ignored."""
    if control_mode not in (DEFAULT_CONTROL_MODE, spec.control_mode):
        raise UsageError(f"Meta-World tasks act by {spec.control_mode} only; got --env.control_mode {control_mode}")
    if sim_backend not in ("auto", "physx_cpu"):
        raise UsageError(
            f"Meta-World tasks run on MuJoCo, one env per worker process; got --eval.sim_backend {sim_backend}"
        )


def policy_observation(observation: dict) -> dict:
    """LeRobot's `preprocess_observation` (what stock `lerobot-eval` feeds a policy), also for an observation
    batch of tensors that a batched simulator keeps on its device: the same keys, layouts and scaling, without a
    round trip through host memory."""
    from lerobot.envs.utils import preprocess_observation
    from lerobot.utils.constants import OBS_ENV_STATE, OBS_IMAGES, OBS_STATE, OBS_STR

    leaves = [*observation.get("pixels", {}).values(), observation.get("agent_pos")]
    if not any(torch.is_tensor(leaf) for leaf in leaves):
        return preprocess_observation(observation)
    batch = {
        f"{OBS_IMAGES}.{cam}": image.permute(0, 3, 1, 2).float() / 255
        for cam, image in observation.get("pixels", {}).items()
    }
    batch[OBS_STATE] = observation["agent_pos"].float()
    if "environment_state" in observation:
        batch[OBS_ENV_STATE] = observation["environment_state"].float()
    if "robot_state" in observation:
        batch[f"{OBS_STR}.robot_state"] = observation["robot_state"]
    return batch


def choose_sim_backend(sim_backend: str, device: str, batch_size: int, perturbation: str | None) -> str:
    """`auto`: ManiSkill's GPU simulation for lockstep (N > 1) on a CUDA device, unless the perturbation ray-traces
    (which ManiSkill renders for one env per process); else its CPU simulation, one env per worker process."""
    if sim_backend not in ("auto", *SIM_BACKENDS):
        raise UsageError(f"--eval.sim_backend must be auto or one of {', '.join(SIM_BACKENDS)}; got {sim_backend!r}")
    if sim_backend == "physx_cuda" and not device.startswith("cuda"):
        raise UsageError("--eval.sim_backend=physx_cuda (ManiSkill's GPU simulation) needs --policy.device=cuda")
    if sim_backend != "auto":
        return sim_backend
    on_gpu = device.startswith("cuda") and batch_size > 1 and not str(perturbation).startswith("noise")
    return "physx_cuda" if on_gpu else "physx_cpu"


def available_sim_backend(sim_backend: str, echo=None) -> str:
    """`sim_backend`, or ManiSkill's CPU simulation where the GPU simulation cannot run here: SAPIEN loads its GPU
    PhysX library from `physx_gpu_library()`, downloading it from GitHub at the first GPU simulation, which an
    offline node cannot. Says why and where the library goes, in one line to `echo` (default: stderr)."""
    if sim_backend != "physx_cuda" or physx_gpu_library().is_file():
        return sim_backend
    echo = echo or (lambda line: print(line, file=sys.stderr))
    echo(
        f"note: ManiSkill's GPU simulation needs SAPIEN's GPU PhysX library at {physx_gpu_library()}, which SAPIEN "
        "downloads from GitHub at its first GPU simulation and is not there: evaluating on the CPU simulation "
        "(physx_cpu; its episodes are not the GPU simulation's). To simulate on the GPU, copy the file there from a "
        "machine that ran one (docs/performance.md#the-device-check-what-runs-on-a-gpu)"
    )
    return "physx_cpu"


def make_eval_envs(env_kwargs: dict, size: int, sim_backend: str):
    """`size` envs for lockstep on `sim_backend`: worker processes on ManiSkill's CPU simulation or MuJoCo
    (Meta-World), or one batched env object on ManiSkill's GPU simulation."""
    if sim_backend == "mujoco":
        return make_envs(make_task_env, env_kwargs, size)
    kwargs = {**env_kwargs, "sim_backend": sim_backend}
    return make_envs(make_obsbench_env, kwargs, size, batched=sim_backend == "physx_cuda")


def _episode_noise(policy, generators: list[torch.Generator]):
    """Within: a policy that samples draws row i's noise from `generators[i]` (a policy that does not sample has
    no such hook and needs none)."""
    return policy.episode_generators(generators) if hasattr(policy, "episode_generators") else nullcontext()


def evaluate(
    policy_path: str | Path,
    task: str,
    episodes: int,
    image_size: int | None = None,
    control_mode: str = DEFAULT_CONTROL_MODE,
    episode_length: int | None = None,
    device: str = "cpu",
    video_dir: Path | None = None,
    asset_dir: str | None = None,
    perturbation: str | None = None,
    progress: bool = True,
    split: str = "test",
    progress_file: Path | None = None,
    batch_size: int = 1,
    sim_backend: str = "auto",
) -> dict:
    """Success rate of a checkpoint over the `split`'s first `episodes` seeds (`eval_seeds`), `batch_size`
    episodes in lockstep. The policy runs on `device` and so does the simulator's renderer (its GPU for cuda).
    `sim_backend` (`choose_sim_backend`): physx_cpu runs each env in a worker process of its own, physx_cuda all
    of them in ManiSkill's GPU simulation. `progress_file` receives {"done", "episodes", "successes"} after every
    finished episode (for a grid's live progress)."""
    spec = task_record(task)
    if batch_size < 1:
        raise ConfigError(f"--eval.batch_size must be >= 1; got {batch_size}")
    seeds = eval_seeds(episodes, split)
    slots = min(batch_size, len(seeds))
    sim = _simulation(spec, control_mode, sim_backend, device, slots, perturbation)
    policy, pre, post = load_policy(policy_path, device)
    env_kwargs = _env_kwargs(policy.config, spec, task, image_size, control_mode, episode_length, perturbation)
    if not is_metaworld(spec):
        env_kwargs.update(asset_dir=asset_dir, device=device)
    steps = env_kwargs["episode_length"]
    start = time.time()
    label = f"eval {task}" + (f" [{perturbation}]" if perturbation not in (None, "none") else "")
    bar = tqdm(total=len(seeds), desc=label, unit="ep", disable=not progress)
    records = {}
    envs = make_eval_envs(env_kwargs, slots, sim)
    try:
        for first in range(0, len(seeds), slots):
            wave = seeds[first : first + slots]
            for record in _run_wave(envs, wave, policy, pre, post, steps, video_dir, device):
                records[record["seed"]] = record
                wins = sum(r["success"] for r in records.values())
                bar.update(1)
                bar.set_postfix(success=f"{wins}/{len(records)}")
                if progress_file is not None:
                    write_json_atomic(progress_file, {"done": len(records), "episodes": len(seeds), "successes": wins})
            if video_dir is not None:
                made_by = videos_made_by(policy_path, task, perturbation, episode_length, image_size, control_mode)
                _write_videos(video_dir, task, wave, records, made_by, spec.fps)
    finally:
        bar.close()
        envs.close()
    ordered = [records[seed] for seed in seeds]
    return {
        "task": task,
        "policy_path": str(policy_path),
        "obs_space": getattr(policy.config, "obs_space", None),
        "policy_type": policy.config.type,
        **success_summary([r["success"] for r in ordered]),
        "seeds": seeds,
        "sub_success": {name: round(sum(r[name] for r in ordered) / len(ordered), 4) for name in spec.sub_success},
        "episode_length_mean": round(float(np.mean([r["length"] for r in ordered])), 2),
        "per_episode": ordered,  # each wave's frames went to its videos
        "per_seed": per_seed(seeds, [r["success"] for r in ordered], [r["length"] for r in ordered]),
        "image_size": env_kwargs["image_size"],
        "control_mode": control_mode,
        "perturbation": perturbation or "none",
        "batch_size": slots,
        "sim_backend": sim,
        "wall_s": round(time.time() - start, 1),
    }


def _simulation(spec, control_mode: str, sim_backend: str, device: str, slots: int, perturbation: str | None) -> str:
    """The simulation an evaluation of `slots` episodes at a time runs on, its settings and perturbation refused
    where the task's family takes none such (before the policy loads)."""
    perturbed = parse_perturbation(perturbation)
    if is_metaworld(spec):
        _metaworld_options(spec, control_mode, sim_backend)
        check_supported(perturbed, METAWORLD_KINDS, "Meta-World")
        return "mujoco"
    check_supported(perturbed, MANISKILL_KINDS, "ManiSkill")
    return available_sim_backend(choose_sim_backend(sim_backend, device, slots, perturbation))


def _env_kwargs(
    config, spec, task: str, image_size: int | None, control_mode: str, episode_length: int | None, perturbation
) -> dict:
    """The env of an evaluation of a policy with `config`: its cameras (the plugin's policies name those they read,
    none for the controls; a stock policy reads the task camera), its training size, and on Meta-World only the
    sensors it reads; the policy and the perturbation checked against it before any simulator starts."""
    plugin = hasattr(config, "obs_space")
    cameras = list(config.cameras) if plugin else ["base_camera"]
    resolution = getattr(config, "camera_resolution", None)
    size = image_size or (resolution[0] if resolution else 128)
    check_compatible(config, cameras, size, control_mode, task)
    perturbed = parse_perturbation(perturbation)
    if plugin:
        check_changes(perturbed, config.obs_space, config.point_features)
    else:  # a stock policy sees colour
        check_changes(perturbed, "rgb")
    steps = episode_length or spec.max_steps
    kwargs = dict(task=task, cameras=cameras, image_size=size, episode_length=steps, perturbation=perturbation)
    if is_metaworld(spec):  # rendering only the sensors the policy reads
        kwargs["sensors"] = rendered_sensors(config.obs_space, config.point_features) if plugin else (IMAGE_PREFIX,)
    else:
        kwargs["control_mode"] = control_mode
    return kwargs


def _run_wave(envs, wave, policy, pre, post, steps, video_dir, device):
    """Run the episodes of `wave` (one seed per slot) together to their ends, yielding each one's record as it
    finishes."""
    torch.manual_seed(wave[0])  # one episode at a time (batch size 1) this is all the seeding there is
    # one noise stream per episode, continued across its steps: what torch.manual_seed(seed) gives it alone
    generators = [torch.Generator(device=device).manual_seed(seed) for seed in wave]
    policy.reset()
    observations = envs.reset(wave)
    frames = [[image] for image in envs.render(range(len(wave)))] if video_dir else None
    lengths, rewards = [0] * len(wave), [0.0] * len(wave)
    running = list(range(len(wave)))
    while running:
        batch = pre(policy_observation(observations))
        with torch.inference_mode(), _episode_noise(policy, generators):
            actions = post(policy.select_action(batch))
        observations, outcomes = envs.step(running, actions)  # a finished slot keeps its last observation
        if frames is not None:
            for slot, image in zip(running, envs.render(running), strict=True):
                frames[slot].append(image)
        still = []
        for slot, (reward, terminated, truncated, info) in zip(running, outcomes, strict=True):
            lengths[slot] += 1
            rewards[slot] += reward
            if info["is_success"] or terminated or truncated or lengths[slot] >= steps:
                yield _record(wave[slot], info, lengths[slot], rewards[slot], frames[slot] if frames else None)
            else:
                still.append(slot)
        running = still


def _record(seed: int, info: dict, length: int, reward_sum: float, frames: list | None) -> dict:
    record = {
        "seed": seed,
        "success": bool(info["is_success"]),
        "length": length,
        "reward_sum": round(float(reward_sum), 6),  # the task's dense reward (ManiSkill's default), summed
        **{k.removeprefix("sub_success/"): bool(v) for k, v in info.items() if k.startswith("sub_success/")},
    }
    if frames is not None:
        record["frames"] = frames
    return record


def video_name(task: str, seed: int) -> str:
    """The file an evaluation writes the episode of `seed` to, in its video folder."""
    return f"{task}_seed{seed}.mp4"


def videos_made_by(
    policy_path: str | Path,
    task: str,
    perturbation: str | None,
    episode_length: int | None = None,
    image_size: int | None = None,
    control_mode: str = DEFAULT_CONTROL_MODE,
) -> dict:
    """What an evaluation's videos show, as the folder's output record keeps it: another evaluation of the same
    checkpoint, task, perturbation, episode budget, image size and controller may replace them, any other needs
    --overwrite (`outputs.check_output_folder`). None: the task's own budget, the policy's own size."""
    checkpoint = str(Path(policy_path).expanduser().resolve())
    return {
        "writer": "obsbench eval",
        "policy_path": checkpoint,
        "task": task,
        "perturbation": perturbation or "none",
        "episode_length": episode_length,
        "image_size": image_size,
        "control_mode": control_mode,
    }


def _write_videos(video_dir: Path, task: str, seeds: list[int], records: dict, made_by: dict, fps: int) -> None:
    from lerobot.utils.io_utils import write_video

    video_dir.mkdir(parents=True, exist_ok=True)
    paths = [video_dir / video_name(task, seed) for seed in seeds]
    for seed, path in zip(seeds, paths, strict=True):
        write_video(str(path), np.stack(records[seed].pop("frames")), fps=fps)
    record_outputs(paths, made_by)  # after each wave, so a rerun of an interrupted evaluation may replace them


def write_result(result: dict, out: Path | None) -> None:
    if out is not None:
        write_text_atomic(out, json.dumps(result, indent=2) + "\n")
