"""Resumable dataset writing, shared by every command that builds a dataset episode by episode (`obsbench demos`,
`import-h5`, `import-rlbench`, `record`).

Finished episodes are staged in `OUT/.episodes/`, each written under a temporary name (`*.tmp`) and renamed whole
once complete, so a kill leaves finished episodes and at most one unfinished one, which a rerun deletes and redoes.
`OUT/.episodes/settings.json` holds the settings of an interrupted run, and a finished dataset has its sidecar
file: a rerun resumes or returns the same work and refuses anything else (`prepare_dataset_out`). Once every
episode is staged, the LeRobotDataset is assembled from them in one pass (`assemble`).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lerobot_obsbench.errors import OutputExistsError
from lerobot_obsbench.locks import LOCK_NAME
from lerobot_obsbench.schema import ACTION_KEY, DEPTH_PREFIX, IMAGE_PREFIX

STAGING = ".episodes"
SETTINGS = "settings.json"  # in STAGING: the settings of an interrupted run
TMP = ".tmp"  # an episode being written: `seed_7.npz.tmp`, `episode_0003.tmp`; never read as an episode
DATASET_ENTRIES = ("meta", "data", "videos", "images", ".assembling")


def temporary(final: Path) -> Path:
    """Where the episode that will be `final` is written until it is complete."""
    return final.with_name(final.name + TMP)


def commit(final: Path) -> None:
    """The episode written at `temporary(final)` is complete: rename it (file or folder) to `final`, atomically."""
    os.replace(temporary(final), final)


def drop_unfinished(staging: Path) -> int:
    """Delete the episodes a kill cut off mid-write (files or folders); returns how many."""
    unfinished = list(staging.glob(f"*{TMP}"))
    for path in unfinished:
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    return len(unfinished)


def dataset_features(sample: dict[str, np.ndarray], names: Mapping[str, list[str]] | None = None) -> dict:
    """LeRobot features of an episode's arrays; `names`: the names of a vector feature's values, by key."""
    feats = {}
    for key, value in sample.items():
        shape = tuple(value.shape[1:])
        if key.startswith(IMAGE_PREFIX):
            feats[key] = {"dtype": "video", "shape": shape, "names": ["height", "width", "channels"]}
        elif key.startswith(DEPTH_PREFIX):
            feats[key] = {"dtype": "uint16", "shape": shape, "names": ["height", "width", "channels"]}
        else:
            feats[key] = {"dtype": "float32", "shape": shape, "names": (names or {}).get(key)}
    return feats


def save_episode_file(path: Path, frames: dict[str, np.ndarray]) -> None:
    """Write one staged episode's frames as a compressed .npz, atomically (a kill leaves the whole file or none)."""
    with open(temporary(path), "wb") as file:
        np.savez_compressed(file, **frames)
    commit(path)


def assemble(
    out: Path,
    episode_files: list[Path],
    task_text: str | list[str],
    repo_id: str,
    fps: int,
    robot_type: str,
    feature_names: Mapping[str, list[str]] | None = None,
) -> None:
    """(Re)write the LeRobotDataset in `out` from staged episode files, in the given order; `task_text` is
    LeRobot's task string, one for all episodes or one per episode; `feature_names` as `dataset_features`'."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    for name in DATASET_ENTRIES:  # leftovers of an interrupted assembly
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
    tmp_root = out / ".assembling"
    episodes = [dict(np.load(f)) for f in episode_files]
    ds = LeRobotDataset.create(
        repo_id=repo_id,
        fps=fps,
        features=dataset_features(episodes[0], feature_names),
        root=tmp_root,
        robot_type=robot_type,
        use_videos=True,
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
            raise OutputExistsError(
                f"--out {out} already holds a dataset made with other settings ({different}); {choice}"
            )
        return
    elif (out / STAGING / SETTINGS).is_file():
        different = settings_differences(json.loads((out / STAGING / SETTINGS).read_text()), settings)
        if different:
            raise OutputExistsError(
                f"--out {out} holds an interrupted run with other settings ({different}); rerun with its settings "
                f"to resume it, {choice}"
            )
    elif present:
        shown = ", ".join(present[:5]) + (", ..." if len(present) > 5 else "")
        raise OutputExistsError(
            f"--out {out} is not empty ({shown}) and holds nothing this command made; give a new or empty folder, "
            "or --overwrite to replace what is there"
        )
    (out / STAGING).mkdir(parents=True, exist_ok=True)
    (out / STAGING / SETTINGS).write_text(json.dumps(settings) + "\n")
