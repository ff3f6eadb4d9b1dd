"""A run resumed from a checkpoint trains what the uninterrupted run trains (patches.py, fix 5): the same batches in
the same order and the same random draws after the resume step, whether it resumes inside an epoch or at an epoch
boundary, in the first epoch or a later one. Driven through the pieces lerobot-train itself uses (its sampler, the
state it computes on resume, accelerate's loader, its RNG checkpoint functions and its `cycle`); the end-to-end
kill-and-resume of a grid's run is tests/bench/test_bench_one_run.py's."""

from __future__ import annotations

import pytest
import torch
from accelerate import Accelerator
from lerobot.datasets import EpisodeAwareSampler
from lerobot.scripts import lerobot_train
from lerobot.utils.random_utils import load_rng_state, save_rng_state, set_seed

from lerobot_obsbench import patches

FRAMES, BATCH, SEED = 30, 4, 7  # 8 batches an epoch, the last one short


class Frames(torch.utils.data.Dataset):
    def __len__(self):
        return FRAMES

    def __getitem__(self, index):
        return torch.tensor(index)


def loader():
    """lerobot-train's data pipeline on a toy dataset of frame indices: its sampler, a DataLoader, accelerate."""
    sampler = EpisodeAwareSampler([0, 12], [12, FRAMES], shuffle=True, seed=SEED)
    data = torch.utils.data.DataLoader(Frames(), batch_size=BATCH, sampler=sampler, num_workers=0)
    return sampler, Accelerator(cpu=True).prepare(data)


def train(steps: int, resume_dir=None, save_at: int | None = None, save_dir=None) -> list[tuple[list[int], float]]:
    """(batch, random draw) of each step after the start (or the resume), as lerobot-train's loop makes them: the
    draw stands for dropout and the other random draws of an update."""
    set_seed(SEED)
    sampler, data = loader()
    start = 0
    if resume_dir is not None:
        start = save_at
        load_rng_state(resume_dir)  # what lerobot-train's load_training_state does
        sampler.load_state_dict(lerobot_train.compute_sampler_state(start, len(sampler), BATCH, 1))
    batches = lerobot_train.cycle(data)
    made = []
    for step in range(start + 1, steps + 1):
        batch = next(batches)
        made.append((batch.tolist(), torch.rand(()).item()))
        if step == save_at and save_dir is not None:
            save_rng_state(save_dir)
    return made


@pytest.mark.parametrize(
    "save_at",
    [5, 8, 16, 21],
    ids=["inside the first epoch", "at the first epoch's end", "at a later epoch's end", "inside a later epoch"],
)
def test_a_resumed_run_continues_the_uninterrupted_one(tmp_path, save_at):
    assert lerobot_train.cycle is patches.cycle_keeping_restored_rng  # the plugin's import applied it
    uninterrupted = train(30, save_at=save_at, save_dir=tmp_path)
    resumed = train(30, resume_dir=tmp_path, save_at=save_at)
    assert resumed == uninterrupted[save_at:]


def test_lerobots_own_resume_is_what_the_fix_is_for(tmp_path, monkeypatch):
    """The control: with LeRobot's own `cycle`, a run resumed inside a later epoch replays the first epoch's order
    (accelerate's loader sets the sampler's epoch to its own count) and every draw after it is shifted."""
    monkeypatch.setattr(lerobot_train, "cycle", patches.RESUME_PATCHES[1].stock)
    uninterrupted = train(30, save_at=21, save_dir=tmp_path)
    resumed = train(30, resume_dir=tmp_path, save_at=21)
    assert [b for b, _ in resumed] != [b for b, _ in uninterrupted[21:]]
    assert [d for _, d in resumed] != [d for _, d in uninterrupted[21:]]
