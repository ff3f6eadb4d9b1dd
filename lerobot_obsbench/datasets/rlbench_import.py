"""PerAct-format RLBench demonstrations -> the OBSBench dataset schema (`obsbench import-rlbench`).

Per episode, every frame but the last (dense frames, as the paper's code samples them): the chosen cameras'
colour, uint16-millimetre depth, OpenCV K and cam2world (per frame: the wrist camera moves); `observation.state`
= the paper's 11-d encoding of the frame's gripper pose and `action` = that of the next frame
(`lerobot_obsbench.rlbench.format`); `observation.environment_state` = the text feature of the episode's first
variation description (when a text encoder is given); `rlbench.gripper_pose` keeps the raw [x, y, z, qx, qy, qz,
qw]. The conventions (bounds, quaternion mode, text encoder, layouts) go to `obsbench_import.json`.

Resumable like `obsbench demos` (converted episodes are staged one file each); an episode that cannot be read
(truncated pickle, missing PNG) is reported by path and skipped, and listed in the metadata.
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
    commit,
    drop_unfinished,
    prepare_dataset_out,
    save_episode_file,
    settings_differences,
    temporary,
)
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.locks import exclusive_output
from lerobot_obsbench.rlbench.format import (
    ACTION_SIZE,
    RLBenchFormatError,
    camera_frame,
    encode_pose,
    find_episodes,
    low_dim,
    read_episode,
)
from lerobot_obsbench.rlbench.paper_tasks import rlbench_task
from lerobot_obsbench.rlbench.text import TextEncoder
from lerobot_obsbench.schema import (
    ACTION_KEY,
    ENV_STATE_KEY,
    QUATERNION_MODES,
    STATE_KEY,
    cam2world_key,
    check_choice,
    depth_key,
    image_key,
    intrinsics_key,
)

RLBENCH_FPS = 20  # RLBench steps its simulation by 0.05 s
RAW_POSE_KEY = "rlbench.gripper_pose"
SIDECAR = "obsbench_import.json"


def import_rlbench(
    task_dir: Path,
    out: Path,
    task: str | None = None,
    cameras: tuple[str, ...] = ("front",),
    text_encoder: TextEncoder | None = None,
    max_episodes: int | None = None,
    quaternion: str = "pcm_compat",
    repo_id: str | None = None,
    overwrite: bool = False,
    strict: bool = False,
) -> dict:
    """Convert the episodes of one task folder (`<data>/<split>/<task>`) into a LeRobotDataset in `out` (the same
    import finished: returned; interrupted: resumed; anything else in `out` refused unless `overwrite`). An
    unreadable episode is skipped and listed in the sidecar (`strict`: stop at the first one instead)."""
    task_dir, out = Path(task_dir), Path(out)
    spec = rlbench_task(task or task_dir.name)
    check_choice("quaternion", quaternion, QUATERNION_MODES)
    if not cameras:
        raise ConfigError("--cameras: name at least one RLBench camera (front, left_shoulder, right_shoulder, wrist)")
    episodes = find_episodes(task_dir)[:max_episodes]
    language = None if text_encoder is None else text_encoder.name
    settings = {
        "source": str(task_dir),
        "task": spec.name,
        "cameras": list(cameras),
        "quaternion": quaternion,
        "language": language,
    }

    def finished_differences(info: dict) -> str:
        found = {
            "source": info.get("source"),
            "cameras": info.get("cameras"),
            "quaternion": info.get("quaternion"),
            "language": (info.get("language") or {}).get("encoder"),
            "episodes": len(info.get("episodes", [])) + len(info.get("skipped", [])),
        }
        wanted = {k: settings[k] for k in ("source", "cameras", "quaternion", "language")}
        return settings_differences(found, {**wanted, "episodes": len(episodes)})

    with exclusive_output(out, "obsbench import-rlbench"):
        prepare_dataset_out(out, settings, SIDECAR, finished_differences, overwrite)
        if (out / SIDECAR).is_file():
            info = json.loads((out / SIDECAR).read_text())
            print(f"{out}: {len(info['episodes'])} {spec.name} episodes already imported")
            return info
        return _import_locked(task_dir, out, spec, episodes, tuple(cameras), text_encoder, quaternion, repo_id, strict)


def _import_locked(task_dir, out, spec, episodes, cameras, text_encoder, quaternion, repo_id, strict) -> dict:
    staging = out / STAGING
    staging.mkdir(parents=True, exist_ok=True)
    drop_unfinished(staging)
    files, texts, imported, skipped = [], [], [], []
    for ref in tqdm(episodes, desc=f"import {spec.name}", unit="ep"):
        target = staging / f"{ref.path.parent.parent.name}_{ref.path.name}.npz"
        text_file = target.with_suffix(".json")
        if not (target.is_file() and text_file.is_file()):
            try:
                frames, meta = convert_episode(ref, spec, cameras, text_encoder, quaternion)
            except RLBenchFormatError as error:
                if strict:
                    raise
                tqdm.write(f"skipped {ref.path}: {error}")
                skipped.append({"path": str(ref.path), "error": str(error)})
                continue
            # each file written whole; the episode counts as done once both are there
            temporary(text_file).write_text(json.dumps(meta) + "\n")
            commit(text_file)
            save_episode_file(target, frames)
        meta = json.loads(text_file.read_text())
        files.append(target)
        texts.append(meta["description"])
        imported.append({"path": str(ref.path), **meta})
    if not files:
        raise RLBenchFormatError(f"{task_dir}: none of its {len(episodes)} episodes could be read (see above)")
    assemble(
        out, files, texts, repo_id=repo_id or f"local/obsbench_rlbench_{spec.name}", fps=RLBENCH_FPS, robot_type="panda"
    )
    info = {
        "source": str(task_dir),
        "task": spec.name,
        "in_paper": spec.in_paper,
        "cameras": list(cameras),
        "episodes": imported,
        "skipped": skipped,
        "fps": RLBENCH_FPS,
        "state_action_layout": "position (3, (p - lo) / (hi - lo) * 2 - 1), 6-D rotation (first two rows of the "
        "rotation matrix), gripper open, ignore collisions; action[t] = state[t + 1], the last frame dropped",
        "location_bounds": [list(spec.location_low), list(spec.location_high)],
        "quaternion": quaternion,
        "raw_pose": f"{RAW_POSE_KEY} = RLBench gripper_pose [x, y, z, qx, qy, qz, qw], world frame",
        "depth": "uint16 millimetres of z-depth: near + d * (far - near), d the RGB-packed PNG / (2^24 - 1)",
        "camera": "OpenCV K (RLBench's negative focal lengths negated) and cam2world = RLBench extrinsics @ "
        "diag(-1, -1, 1, 1), per frame",
        "language": None if text_encoder is None else {"key": ENV_STATE_KEY, "encoder": text_encoder.name},
    }
    (out / SIDECAR).write_text(json.dumps(info, indent=2) + "\n")
    shutil.rmtree(staging)
    return info


def convert_episode(ref, spec, cameras, text_encoder, quaternion) -> tuple[dict[str, np.ndarray], dict]:
    """One episode's frames in the schema (arrays stacked over frames 0..T-2) and its language metadata."""
    episode = read_episode(ref)
    observations = episode.observations
    if len(observations) < 2:
        raise RLBenchFormatError(f"{ref.path}: {len(observations)} frame(s); an episode needs at least 2")
    poses, gripper, ignore = zip(*(low_dim(o) for o in observations), strict=True)
    encoded = encode_pose(np.stack(poses), gripper, ignore, spec.location_low, spec.location_high, quaternion)
    frames: dict[str, list] = {}
    for t in range(len(observations) - 1):
        for camera in cameras:
            view = camera_frame(ref, observations[t], camera, t)
            frames.setdefault(image_key(camera), []).append(view["rgb"])
            frames.setdefault(depth_key(camera), []).append(view["depth"])
            frames.setdefault(intrinsics_key(camera), []).append(view["K"].astype(np.float32))
            frames.setdefault(cam2world_key(camera), []).append(view["cam2world"].astype(np.float32))
    steps = len(observations) - 1
    out = {key: np.stack(values) for key, values in frames.items()}
    out[STATE_KEY] = encoded[:-1]
    out[ACTION_KEY] = encoded[1:]
    out[RAW_POSE_KEY] = np.stack(poses)[:-1].astype(np.float32)
    description = episode.descriptions[0]
    if text_encoder is not None:
        feature = text_encoder.encode([description])[0]
        out[ENV_STATE_KEY] = np.broadcast_to(feature, (steps, len(feature))).astype(np.float32)
    assert out[ACTION_KEY].shape[1] == ACTION_SIZE
    return out, {"variation": episode.variation, "description": description, "frames": steps}
