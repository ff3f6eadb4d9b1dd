"""Official ManiSkill trajectories (`.h5` + `.json`, as written by `RecordEpisode`) -> the OBSBench schema.

Each episode is re-rendered by replaying its recorded env states: reset with the episode's seed, then for every
step set the simulator to the recorded state, render the sensor frame and pair it with the recorded action.
No physics is re-simulated, so the frames show exactly the recorded trajectory whatever controller made it.
Resumable like `obsbench demos`: converted episodes are staged one file each.
"""

from __future__ import annotations

import json
import shutil
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
from lerobot_obsbench.envs.base_task import TaskError, task_spec
from lerobot_obsbench.envs.maniskill import CONTROL_FPS, DEFAULT_CONTROL_MODE, ROBOT_TYPE
from lerobot_obsbench.errors import ConfigError, MissingFileError
from lerobot_obsbench.locks import exclusive_output
from lerobot_obsbench.schema import ACTION_KEY, PRIVILEGED_STATE_KEY, privileged_state_names

SIDECAR = "obsbench_import.json"


def read_trajectory_metadata(h5_path: Path) -> dict:
    json_path = Path(h5_path).with_suffix(".json")
    if not json_path.is_file():
        raise MissingFileError(f"{json_path} not found: ManiSkill trajectories come as a .h5 + .json pair.")
    meta = json.loads(json_path.read_text())
    if "env_info" not in meta or "episodes" not in meta:
        raise ConfigError(f"{json_path} is not a ManiSkill trajectory description (no env_info / episodes).")
    return meta


def import_trajectories(
    h5_path: Path,
    out: Path,
    image_size: int = 128,
    cameras=("base_camera",),
    max_episodes: int | None = None,
    only_success: bool = True,
    repo_id: str | None = None,
    asset_dir: str | None = None,
    overwrite: bool = False,
) -> dict:
    """Replay the trajectories of `h5_path` into a LeRobotDataset in `out` (resumable; one importer per `out`; the
    same import finished: returned; anything else in `out` refused unless `overwrite`)."""
    h5_path, out = Path(h5_path), Path(out)
    meta = read_trajectory_metadata(h5_path)
    task = meta["env_info"]["env_id"]
    try:
        task_spec(task)
    except TaskError as err:
        raise TaskError(f"{h5_path} records {task!r}, not an OBSBench task. {err}") from err
    control_mode = meta["env_info"]["env_kwargs"].get("control_mode", DEFAULT_CONTROL_MODE)
    episodes = [ep for ep in meta["episodes"] if not only_success or ep.get("success", True)]
    episodes = episodes[:max_episodes] if max_episodes else episodes
    if not episodes:
        raise ConfigError(f"{h5_path}: no{' successful' if only_success else ''} episodes to import.")
    settings = {
        "source": str(h5_path),
        "task": task,
        "episode_ids": [ep["episode_id"] for ep in episodes],
        "image_size": image_size,
        "cameras": list(cameras),
    }
    with exclusive_output(out, "obsbench import-h5"):
        prepare_dataset_out(out, settings, SIDECAR, lambda info: settings_differences(info, settings), overwrite)
        if (out / SIDECAR).is_file():
            print(f"{out}: {len(episodes)} {task} episodes already imported")
            return json.loads((out / SIDECAR).read_text())
        return _import_locked(h5_path, out, task, episodes, image_size, cameras, control_mode, repo_id, asset_dir)


def _import_locked(h5_path, out, task, episodes, image_size, cameras, control_mode, repo_id, asset_dir) -> dict:
    import h5py
    from mani_skill.trajectory.dataset import load_h5_data
    from mani_skill.trajectory.utils import dict_to_list_of_dicts
    from mani_skill.utils import common

    from lerobot_obsbench.envs.maniskill import ObsBenchEnv

    staging = out / STAGING
    staging.mkdir(parents=True, exist_ok=True)
    drop_unfinished(staging)
    env = ObsBenchEnv(task, cameras=cameras, image_size=image_size, control_mode=control_mode, asset_dir=asset_dir)
    files = []
    with h5py.File(h5_path, "r") as f:
        for ep in tqdm(episodes, desc=f"import {task}", unit="ep"):
            target = staging / f"episode_{ep['episode_id']}.npz"
            files.append(target)
            if target.is_file():
                continue
            traj = f[f"traj_{ep['episode_id']}"]
            states = dict_to_list_of_dicts(load_h5_data(traj["env_states"]))
            actions = np.asarray(traj["actions"], dtype=np.float32)
            seed = ep.get("reset_kwargs", {}).get("seed", ep.get("episode_seed"))
            env.reset(seed=seed[0] if isinstance(seed, list) else seed)
            frames = []
            for t, action in enumerate(actions):
                env.unwrapped_ms.set_state_dict(common.batch(states[t]))
                frames.append({**env.schema_frame(env.raw_observation()), ACTION_KEY: action})
            save_episode_file(target, {k: np.stack([fr[k] for fr in frames]) for k in frames[0]})
    env.close()
    assemble(
        out,
        files,
        task_spec(task).description,
        repo_id=repo_id or f"local/obsbench_{task}_imported",
        fps=CONTROL_FPS,
        robot_type=ROBOT_TYPE,
        feature_names={PRIVILEGED_STATE_KEY: privileged_state_names(task_spec(task).privileged_actors)},
    )
    info = {
        "task": task,
        "source": str(h5_path),
        "episode_ids": [ep["episode_id"] for ep in episodes],
        "control_mode": control_mode,
        "image_size": image_size,
        "cameras": list(cameras),
    }
    (out / SIDECAR).write_text(json.dumps(info, indent=2) + "\n")
    shutil.rmtree(staging)
    return info
