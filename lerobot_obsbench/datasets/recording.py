"""Scripted demonstrations -> a LeRobotDataset in the OBSBench schema, resumable after a kill.

Each attempted episode is simulated, and successful ones are written as one compressed `.npz` file in
`OUT/.episodes/` (atomically: written under a temporary name, then renamed); failed attempts are logged in
`OUT/.episodes/attempts.jsonl`. A rerun skips every seed already attempted, so a killed run loses at most the
episode in flight and never repeats one. Once N episodes exist, the LeRobotDataset is (re)assembled from the
episode files in seed order, then the staging files are removed; a kill during assembly just redoes it.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lerobot_obsbench.envs.maniskill import CONTROL_FPS
from lerobot_obsbench.envs.task import DEMO_SEED_START, task_spec
from lerobot_obsbench.locks import LOCK_NAME, exclusive_output
from lerobot_obsbench.schema import ACTION_KEY, DEPTH_PREFIX, IMAGE_PREFIX, MIN_IMAGE_SIZE, env_observation_to_frame

STAGING = ".episodes"
ATTEMPTS_LOG = "attempts.jsonl"
TMP_SUFFIX = ".tmp.npz"  # an episode file being written; never read as an episode
SIDECAR = "obsbench_demos.json"
SETTINGS = "settings.json"  # in STAGING: the settings of an interrupted recording
DATASET_ENTRIES = ("meta", "data", "videos", "images", ".assembling")


def rollout(env, spec, seed: int) -> tuple[bool, dict[str, np.ndarray]]:
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


def _attempted(staging: Path) -> dict[int, bool]:
    """Seeds already attempted (seed -> success), from the staged episode files and the attempts log.

    A kill can leave a half-written `seed_N.tmp.npz` (deleted: that episode is simulated again) and a truncated
    last log line (dropped, and the log rewritten so the next line starts clean: that attempt is redone).
    """
    for leftover in staging.glob(f"*{TMP_SUFFIX}"):
        leftover.unlink()
    done = {int(p.name.removeprefix("seed_").removesuffix(".npz")): True for p in staging.glob("seed_*.npz")}
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


def _features(sample: dict[str, np.ndarray]) -> dict:
    feats = {}
    for key, value in sample.items():
        shape = tuple(value.shape[1:])
        if key.startswith(IMAGE_PREFIX):
            feats[key] = {"dtype": "video", "shape": shape, "names": ["height", "width", "channels"]}
        elif key.startswith(DEPTH_PREFIX):
            feats[key] = {"dtype": "uint16", "shape": shape, "names": ["height", "width", "channels"]}
        else:
            feats[key] = {"dtype": "float32", "shape": shape, "names": None}
    return feats


def save_episode_file(path: Path, frames: dict[str, np.ndarray]) -> None:
    """Write one staged episode atomically (a kill leaves either the whole file or none)."""
    tmp = path.with_name(path.stem + TMP_SUFFIX)
    np.savez_compressed(tmp, **frames)
    os.replace(tmp, path)


def assemble(
    out: Path,
    episode_files: list[Path],
    task_text: str | list[str],
    repo_id: str,
    fps: int = CONTROL_FPS,
    robot_type: str = "panda",
) -> None:
    """(Re)write the LeRobotDataset in `out` from staged episode files, in the given order; `task_text` is
    LeRobot's task string, one for all episodes or one per episode."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    for name in DATASET_ENTRIES:  # leftovers of an interrupted assembly
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
    tmp_root = out / ".assembling"
    episodes = [dict(np.load(f)) for f in episode_files]
    ds = LeRobotDataset.create(
        repo_id=repo_id, fps=fps, features=_features(episodes[0]), root=tmp_root, robot_type=robot_type, use_videos=True
    )
    texts = [task_text] * len(episodes) if isinstance(task_text, str) else task_text
    for ep, text in tqdm(zip(episodes, texts, strict=True), desc="writing dataset", unit="ep", total=len(episodes)):
        for t in range(len(ep[ACTION_KEY])):
            ds.add_frame({**{k: v[t] for k, v in ep.items()}, "task": text})
        ds.save_episode()
    ds.finalize()
    for entry in tmp_root.iterdir():
        entry.rename(out / entry.name)
    tmp_root.rmdir()


def record_demos(
    task: str,
    episodes: int,
    out: Path,
    image_size: int = 128,
    cameras=("base_camera",),
    seed_start: int = DEMO_SEED_START,
    max_attempts: int | None = None,
    repo_id: str | None = None,
    keep_staging: bool = False,
    overwrite: bool = False,
) -> dict:
    """Record `episodes` successful expert demonstrations of `task` into `out` (resumable; one recorder per
    `out`: a second one is refused with `OutputLockedError`). What `out` already holds is kept: the same
    recording (finished: returned; interrupted: resumed), anything else refused before the simulator starts,
    unless `overwrite` (then it is deleted first)."""
    spec = task_spec(task)  # unknown task -> TaskError listing the valid ones
    if spec.expert is None:
        spec.make_expert(None)  # raises the explanatory NotImplementedError
    if seed_start < DEMO_SEED_START:
        raise ValueError(f"demonstration seeds must start at >= {DEMO_SEED_START} (below are evaluation seeds)")
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1; got {episodes}")
    if image_size < MIN_IMAGE_SIZE:
        raise ValueError(
            f"--image-size must be >= {MIN_IMAGE_SIZE} pixels (LeRobot's video encoder fails below); got {image_size}"
        )
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
            spec, episodes, Path(out), image_size, cameras, seed_start, max_attempts, repo_id, keep_staging
        )


def settings_differences(found: dict, wanted: dict) -> str:
    """The settings of `wanted` that `found` does not share, as "name X there, Y asked" (empty: none)."""
    return ", ".join(f"{k} {found.get(k)!r} there, {v!r} asked" for k, v in wanted.items() if found.get(k) != v)


def prepare_dataset_out(out: Path, settings: dict, sidecar: str, finished_differences, overwrite: bool) -> None:
    """Before a recording or import writes dataset folder `out` (locked by the caller): keep the same work —
    finished (its `sidecar` file, compared by `finished_differences(sidecar contents)`, empty when the same) or
    interrupted (STAGING's settings file, compared with `settings`) —, refuse anything else with what is there
    and the choices, or with `overwrite` delete it; then record `settings` for a later resume to match."""
    present = sorted(p.name for p in out.iterdir() if p.name != LOCK_NAME)
    choice = "--overwrite to replace it, or another --out"
    if present and overwrite:
        for name in present:
            path = out / name
            shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()
    elif (out / sidecar).is_file():
        different = finished_differences(json.loads((out / sidecar).read_text()))
        if different:
            raise FileExistsError(
                f"--out {out} already holds a dataset made with other settings ({different}); {choice}"
            )
        return
    elif (out / STAGING / SETTINGS).is_file():
        different = settings_differences(json.loads((out / STAGING / SETTINGS).read_text()), settings)
        if different:
            raise FileExistsError(
                f"--out {out} holds an interrupted run with other settings ({different}); rerun with its settings "
                f"to resume it, {choice}"
            )
    elif present:
        shown = ", ".join(present[:5]) + (", ..." if len(present) > 5 else "")
        raise FileExistsError(
            f"--out {out} is not empty ({shown}) and holds nothing this command made; give a new or empty folder, "
            "or --overwrite to replace what is there"
        )
    (out / STAGING).mkdir(parents=True, exist_ok=True)
    (out / STAGING / SETTINGS).write_text(json.dumps(settings) + "\n")


def _record_locked(spec, episodes, out, image_size, cameras, seed_start, max_attempts, repo_id, keep_staging) -> dict:
    from lerobot_obsbench.envs.maniskill import ObsBenchEnv

    task = spec.name
    sidecar = out / SIDECAR
    if sidecar.is_file() and (out / "meta" / "info.json").is_file():  # the same recording (prepare_dataset_out)
        print(f"{out}: {episodes} {task} demonstrations already recorded")
        return json.loads(sidecar.read_text())
    staging = out / STAGING
    staging.mkdir(parents=True, exist_ok=True)
    attempted = _attempted(staging)
    successes = sorted(s for s, ok in attempted.items() if ok)
    env = ObsBenchEnv(task, cameras=cameras, image_size=image_size)
    max_attempts = max_attempts or 10 * episodes + 10
    seed = seed_start
    start = time.time()
    bar = tqdm(total=episodes, initial=min(len(successes), episodes), desc=f"{task} demos", unit="ep")
    try:
        while len(successes) < episodes:
            if seed - seed_start >= max_attempts:
                raise RuntimeError(f"only {len(successes)}/{episodes} successes after {max_attempts} attempts")
            if seed in attempted:
                seed += 1
                continue
            ok, frames = rollout(env, spec, seed)
            if ok:
                save_episode_file(staging / f"seed_{seed}.npz", frames)
                successes.append(seed)
                bar.update(1)
            with open(staging / ATTEMPTS_LOG, "a") as log:
                log.write(json.dumps({"seed": seed, "success": ok, "steps": len(frames.get("action", []))}) + "\n")
            attempted[seed] = ok
            tried = len(attempted)
            bar.set_postfix(
                success=f"{len([s for s in attempted.values() if s])}/{tried}",
                ep_per_min=f"{60 * bar.n / max(time.time() - start, 1e-6):.1f}",
            )
            seed += 1
    finally:
        bar.close()
        env.close()
    seeds = sorted(successes)[:episodes]
    assemble(
        out, [staging / f"seed_{s}.npz" for s in seeds], spec.description, repo_id=repo_id or f"local/obsbench_{task}"
    )
    tried = len(attempted)
    info = {
        "task": task,
        "seeds": seeds,
        "expert_success_rate": round(len(successes) / tried, 4),
        "attempts": tried,
        "image_size": image_size,
        "cameras": list(cameras),
        "seed_start": seed_start,
    }
    sidecar.write_text(json.dumps(info, indent=2) + "\n")
    if not keep_staging:
        shutil.rmtree(staging)
    return info
