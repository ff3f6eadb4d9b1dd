"""What RLBench work needs on this machine, checked before any of it starts: PerAct's data holding enough episodes
of each task in each split, the CLIP weights of a language goal, and the simulator stack."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

from lerobot_obsbench.rlbench.evaluate import RLBenchUnavailable, require_rlbench
from lerobot_obsbench.rlbench.format import RLBenchFormatError, find_episodes

PERACT_DATA_HELP = (
    "PerAct's pre-generated data: https://github.com/peract/peract, 'Pre-generated datasets'; one folder per "
    "split, train / val / test, holding one folder per task"
)


def data_problems(
    data: str | Path, tasks: Iterable[str], needed: Mapping[str, tuple[int, str]], clip_weights: str | None = None
) -> list[str]:
    """What `data` (DATA/<split>/<task>) lacks for RLBench `tasks`: `needed` maps each split to the episodes every
    task folder of it must hold (0: the split is not read) and who asks for them, as the message names it; and
    whether `clip_weights`, when given, is a file."""
    data = Path(data).expanduser()
    folders = [(data / split / task, *needed[split]) for task in tasks for split in needed]
    missing = [str(folder) for folder, count, _ in folders if count and not folder.is_dir()]
    problems = []
    for folder, count, asked_by in folders:
        if count and folder.is_dir():
            try:
                found = len(find_episodes(folder))
            except RLBenchFormatError:
                found = 0
            if found < count:
                problems.append(f"{folder} holds {found} episodes; {asked_by} needs {count}")
    if missing:
        problems.append(
            f"rlbench_data lacks {len(missing)} task folder(s): {', '.join(missing[:3])}"
            + (" ..." if len(missing) > 3 else "")
            + f" ({PERACT_DATA_HELP})"
        )
    if clip_weights and not Path(clip_weights).expanduser().is_file():
        problems.append(f"clip_weights {clip_weights} is not a file (a local CLIP ViT-B/16 checkpoint)")
    return problems


def simulator_problem() -> str | None:
    """What the simulator stack lacks here (CoppeliaSim, PyRep, RLBench's fork, a display), or None."""
    try:
        require_rlbench()
    except RLBenchUnavailable as err:
        return str(err)
    return None
