"""Open-loop replay of recorded scripted demonstrations in the evaluation env: does each episode's recorded action
sequence, replayed from its recorded seed, succeed where the recording did?

A cloned policy can only be as good as the agreement between the data and the env it is evaluated in: the
controller, the seeds' initial states and the simulation backend. `obsbench demos` stops an episode at its first
successful step, so an episode replays faithfully when its success comes at its last action, and not before.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from lerobot_obsbench.datasets.sim_demos import SIDECAR
from lerobot_obsbench.errors import ConfigError, MissingFileError
from lerobot_obsbench.schema import ACTION_KEY


class DemoFileError(ConfigError):
    """A demonstrations folder whose files cannot be read as `obsbench demos` writes them."""


def recorded_actions(root: Path) -> dict[int, np.ndarray]:
    """episode index -> its actions (T, A), read from the dataset's parquet files."""
    files = sorted((root / "data").glob("*/*.parquet"))
    if not files:
        raise MissingFileError(f"{root}: no data/*/*.parquet files; is this a LeRobot dataset of `obsbench demos`?")
    actions: dict[int, list] = {}
    for file in files:
        try:
            table = pq.read_table(file, columns=[ACTION_KEY, "episode_index", "frame_index"]).to_pydict()
        except Exception as err:  # pyarrow's errors for a cut or foreign file have no common base
            raise DemoFileError(
                f"{file}: cannot be read as a LeRobot data file ({type(err).__name__}: {str(err).splitlines()[0]}); "
                "record the demonstrations again (`obsbench demos` resumes a folder it left unfinished)"
            ) from None
        rows = sorted(zip(table["episode_index"], table["frame_index"], table[ACTION_KEY], strict=True))
        for episode, _, action in rows:
            actions.setdefault(int(episode), []).append(action)
    return {episode: np.asarray(rows, dtype=np.float32) for episode, rows in sorted(actions.items())}


def replay_demonstrations(root: str | Path, episodes: int | None = None) -> dict:
    """Replay the first `episodes` (None: all) recorded episodes of `root` (an `obsbench demos` dataset) open-loop
    from their seeds, without cameras (they do not change the physics), in its task's own simulator (ManiSkill or
    Meta-World); per episode the step of its first success (None: none), and how many reproduce their recording
    (success exactly at their last action)."""
    from lerobot_obsbench.envs.catalog import make_task_env

    root = Path(root)
    info = demos_sidecar(root)
    actions = recorded_actions(root)
    count = len(actions) if episodes is None else min(episodes, len(actions))
    if len(info["seeds"]) < count:
        raise DemoFileError(
            f"{root / SIDECAR} names {len(info['seeds'])} seeds for {count} recorded episodes: the file and the data "
            "are not of one recording; record the demonstrations again"
        )
    env = make_task_env(info["task"], cameras=(), image_size=info["image_size"])
    per_episode = []
    try:
        for index in range(count):
            seed, steps = info["seeds"][index], actions[index]
            env.reset(seed=seed)
            success_at = None
            for step, action in enumerate(steps, start=1):
                info_step = env.step(action)[4]
                if info_step["is_success"]:
                    success_at = step
                    break
            per_episode.append({"episode": index, "seed": seed, "length": len(steps), "success_at": success_at})
    finally:
        env.close()
    reproduced = sum(e["success_at"] == e["length"] for e in per_episode)
    return {"task": info["task"], "episodes": count, "reproduced": reproduced, "per_episode": per_episode}


def demos_sidecar(root: Path) -> dict:
    """The sidecar `obsbench demos` writes beside its dataset (task, image size, seeds), checked readable."""
    sidecar = root / SIDECAR
    if not sidecar.is_file():
        raise MissingFileError(
            f"{root}: no {SIDECAR}; replay checks demonstrations recorded by `obsbench demos` (it names their task "
            "and seeds)"
        )
    try:
        info = json.loads(sidecar.read_text())
    except (ValueError, UnicodeDecodeError) as err:
        raise DemoFileError(f"{sidecar}: cannot be read as JSON ({err}); record the demonstrations again") from None
    missing = [key for key in ("task", "image_size", "seeds") if not isinstance(info, dict) or key not in info]
    if missing:
        raise DemoFileError(f"{sidecar}: no {', '.join(missing)}; it is not what `obsbench demos` writes")
    return info
