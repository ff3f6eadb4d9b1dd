"""Scripted demonstrations -> a LeRobotDataset in the OBSBench schema, resumable after a kill: a ManiSkill task
with the plugin's expert, or a Meta-World task with Meta-World's own scripted policy.

Each attempted episode is simulated, and successful ones are staged as one compressed `.npz` file in
`OUT/.episodes/` (`datasets.staging`: written under a temporary name, then renamed); failed attempts are logged in
`OUT/.episodes/attempts.jsonl`. A rerun skips every seed already attempted, so a killed run loses at most the
episodes in flight and never repeats one. Once N episodes exist, the LeRobotDataset is (re)assembled from the
episode files in seed order, then the staging files are removed; a kill during assembly just redoes it.

With `workers` W > 1, W worker processes each hold an env and record whole episodes side by side
(`envs.vector.SubprocessEnvs`), in waves of the next W seeds, worker k taking the wave's k-th. The dataset holds
the first N successful seeds, as with one worker, but not always the same frames: ManiSkill's CPU simulation
carries state from one episode into the next in the same env (the order of its contact pairs, measured in
docs/simulation.md), so an episode recorded after another seed can drift by a millimetre once contacts begin.
A given W (and the same resume points) records the same dataset every time.

A task whose expert fails often (`Task.expert_success_rate` below SCREEN_BELOW: PegInsertionSide, PlugCharger)
first tries each seed in a second env without cameras, where a step costs physics only, and renders the seed only
if the expert succeeds there: the rendered attempt decides (rendering does not move the simulation), and a seed
screened out is logged as a failed attempt of 0 recorded steps.
"""

from __future__ import annotations

import itertools
import json
import re
import shutil
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lerobot_obsbench.datasets.staging import (
    STAGING,
    assemble,
    drop_unfinished,
    prepare_dataset_out,
    save_episode_file,
    settings_differences,
)
from lerobot_obsbench.envs.base_task import DEMO_SEED_START, check_cameras
from lerobot_obsbench.envs.catalog import make_task_env, task_record
from lerobot_obsbench.envs.vector import make_envs
from lerobot_obsbench.errors import ObsBenchError, UsageError
from lerobot_obsbench.locks import exclusive_output
from lerobot_obsbench.schema import (
    ACTION_KEY,
    MIN_IMAGE_SIZE,
    PRIVILEGED_STATE_KEY,
    env_observation_to_frame,
    privileged_state_names,
)

ATTEMPTS_LOG = "attempts.jsonl"
# The expert success rate below which seeds are screened without cameras first: above it, screening would
# simulate most seeds twice to save little rendering.
SCREEN_BELOW = 0.8
SIDECAR = "obsbench_demos.json"
EPISODE_FILE = re.compile(r"seed_(\d+)\.npz")


class DemoRecordingError(ObsBenchError, RuntimeError):
    """The expert did not succeed on enough seeds within the attempts allowed."""


def expert_episode(env, spec, seed: int) -> tuple[bool, dict[str, np.ndarray]]:
    """One episode of the task's expert; returns (success, per-key stacked frames incl. `action`)."""
    obs, _ = env.reset(seed=seed)
    expert = spec.make_expert(env)
    frames: list[dict[str, np.ndarray]] = []
    success = False
    while True:
        action = expert.act()
        if action is None:  # script finished without success
            break
        frames.append({**env_observation_to_frame(obs), ACTION_KEY: action})
        obs, _, terminated, truncated, info = env.step(action)
        if info["is_success"]:
            success = True
            break
        if terminated or truncated:
            break
    stacked = {k: np.stack([f[k] for f in frames]) for k in frames[0]} if frames else {}
    return success, stacked


class ExpertRecorder:
    """An env and the task's expert, recording one whole episode per call (in a worker process, or this one)."""

    def __init__(self, task: str, cameras, image_size: int):
        self.spec = task_record(task)
        self.env = make_task_env(task, cameras=cameras, image_size=image_size)
        screens = bool(cameras) and self.spec.expert_success_rate < SCREEN_BELOW
        self.screen = make_task_env(task, cameras=(), image_size=image_size) if screens else None

    def episode(self, seed: int) -> tuple[bool, dict[str, np.ndarray]]:
        if self.screen is not None and not expert_episode(self.screen, self.spec, seed)[0]:
            return False, {}
        return expert_episode(self.env, self.spec, seed)

    def close(self) -> None:
        self.env.close()
        if self.screen is not None:
            self.screen.close()


def make_expert_recorder(task: str, cameras, image_size: int) -> ExpertRecorder:
    return ExpertRecorder(task, cameras, image_size)


def _attempted(staging: Path) -> dict[int, bool]:
    """Seeds already attempted (seed -> success), from the staged episode files and the attempts log.

    A kill can leave a half-written episode file (deleted: that episode is simulated again) and a truncated
    last log line (dropped, and the log rewritten so the next line starts clean: that attempt is redone).
    """
    drop_unfinished(staging)
    done = {int(m[1]): True for p in staging.iterdir() if (m := EPISODE_FILE.fullmatch(p.name))}
    log = staging / ATTEMPTS_LOG
    if log.is_file():
        kept, dropped = [], 0
        for line in log.read_text().splitlines():
            try:
                rec = json.loads(line)
                done.setdefault(int(rec["seed"]), bool(rec["success"]))
                kept.append(line)
            except (ValueError, KeyError, TypeError):
                dropped += 1  # blank or cut off by a kill mid-write
        if dropped:
            log.write_text("".join(f"{line}\n" for line in kept))
    return done


def record_demos(
    task: str,
    episodes: int,
    out: Path,
    image_size: int = 128,
    cameras=None,
    seed_start: int = DEMO_SEED_START,
    max_attempts: int | None = None,
    repo_id: str | None = None,
    keep_staging: bool = False,
    overwrite: bool = False,
    workers: int = 1,
) -> dict:
    """Record `episodes` successful expert demonstrations of `task` into `out` (resumable; one recorder per
    `out`: a second one is refused with `OutputLockedError`). What `out` already holds is kept: the same
    recording (finished: returned; interrupted: resumed), anything else refused before the simulator starts,
    unless `overwrite` (then it is deleted first). `workers` processes record episodes side by side (module
    docstring)."""
    spec = task_record(task)  # unknown task -> TaskError naming the closest ones
    if spec.expert is None:
        spec.make_expert(None)  # raises the explanatory NotImplementedError
    if seed_start < DEMO_SEED_START:
        raise UsageError(f"--seed-start must be >= {DEMO_SEED_START} (below are evaluation seeds); got {seed_start}")
    if episodes < 1:
        raise UsageError(f"--episodes must be >= 1; got {episodes}")
    if workers < 1:
        raise UsageError(f"--workers must be >= 1; got {workers}")
    if image_size < MIN_IMAGE_SIZE:
        raise UsageError(
            f"--image-size must be >= {MIN_IMAGE_SIZE} pixels (LeRobot's video encoder fails below); got {image_size}"
        )
    cameras = (spec.default_camera,) if cameras is None else tuple(cameras)
    check_cameras(spec, cameras)
    settings = {"task": spec.name, "image_size": image_size, "cameras": list(cameras), "seed_start": seed_start}
    with exclusive_output(out, "obsbench demos"):
        prepare_dataset_out(
            Path(out),
            settings,
            SIDECAR,
            lambda info: settings_differences(
                {**info, "episodes": len(info["seeds"])}, {**settings, "episodes": episodes}
            ),
            overwrite,
        )
        return _record_locked(
            spec, episodes, Path(out), image_size, cameras, seed_start, max_attempts, repo_id, keep_staging, workers
        )


def _record_locked(
    spec, episodes, out, image_size, cameras, seed_start, max_attempts, repo_id, keep_staging, workers
) -> dict:
    task = spec.name
    sidecar = out / SIDECAR
    if sidecar.is_file() and (out / "meta" / "info.json").is_file():  # the same recording (prepare_dataset_out)
        print(f"{out}: {episodes} {task} demonstrations already recorded")
        return json.loads(sidecar.read_text())
    staging = out / STAGING
    staging.mkdir(parents=True, exist_ok=True)
    attempted = _attempted(staging)
    successes = sorted(s for s, ok in attempted.items() if ok)
    max_attempts = max_attempts or 10 * episodes + 10
    pending = (s for s in range(seed_start, seed_start + max_attempts) if s not in attempted)
    recorder_kwargs = dict(task=task, cameras=list(cameras), image_size=image_size)
    start = time.time()
    bar = tqdm(total=episodes, initial=min(len(successes), episodes), desc=f"{task} demos", unit="ep")
    recorders = make_envs(make_expert_recorder, recorder_kwargs, workers)
    try:
        while len(successes) < episodes:
            wave = list(itertools.islice(pending, workers))  # worker k records the wave's k-th seed
            if not wave:
                break
            for worker, seed in enumerate(wave):
                recorders.call(worker, "episode", seed)
            for worker, seed in enumerate(wave):
                ok, frames = recorders.result(worker)
                if ok:
                    save_episode_file(staging / f"seed_{seed}.npz", frames)
                    successes.append(seed)
                    bar.update(int(bar.n < episodes))  # the wave's later episodes finish too
                with open(staging / ATTEMPTS_LOG, "a") as log:
                    log.write(json.dumps({"seed": seed, "success": ok, "steps": len(frames.get("action", []))}) + "\n")
                attempted[seed] = ok
                bar.set_postfix(
                    success=f"{len([s for s in attempted.values() if s])}/{len(attempted)}",
                    ep_per_min=f"{60 * bar.n / max(time.time() - start, 1e-6):.1f}",
                )
    finally:
        bar.close()
        recorders.close()
    if len(successes) < episodes:
        raise DemoRecordingError(f"only {len(successes)}/{episodes} successes after {max_attempts} attempts")
    seeds = sorted(successes)[:episodes]
    assemble(
        out,
        [staging / f"seed_{s}.npz" for s in seeds],
        spec.description,
        repo_id=repo_id or f"local/obsbench_{task}",
        fps=spec.fps,
        robot_type=spec.robot_type,
        feature_names={PRIVILEGED_STATE_KEY: privileged_state_names(spec.privileged_actors)},
    )
    tried = sum(s <= seeds[-1] for s in attempted)  # what one worker attempts (more workers try a few more)
    info = {
        "task": task,
        "seeds": seeds,
        "expert_success_rate": round(episodes / tried, 4),
        "attempts": tried,
        "image_size": image_size,
        "cameras": list(cameras),
        "seed_start": seed_start,
    }
    sidecar.write_text(json.dumps(info, indent=2) + "\n")
    if not keep_staging:
        shutil.rmtree(staging)
    return info
