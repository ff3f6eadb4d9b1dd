"""Shared fixtures: datasets in the OBSBench schema written by `scripts/make_synthetic_dataset.py`, which uses
stock LeRobot only (it stands for "someone else's recording code")."""

from __future__ import annotations

from pathlib import Path

import pytest

import lerobot_obsbench  # noqa: F401  (registers obs_act / obs_diffusion, as LeRobot's plugin discovery does)
from scripts import make_synthetic_dataset as synthetic

pytest_plugins = ["tests.support.fault_logs"]  # a crashed worker's own stack, printed in the summary


@pytest.fixture(scope="session")
def synthetic_module():
    return synthetic


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """6 episodes x 12 frames at 40x40, RGB as video."""
    return synthetic.write_dataset(tmp_path_factory.mktemp("ds") / "tiny", episodes=6, frames=12, size=40, seed=0)


@pytest.fixture(scope="session")
def image_dataset(tmp_path_factory) -> Path:
    """Same scene with RGB stored as PNG images instead of video."""
    return synthetic.write_dataset(
        tmp_path_factory.mktemp("ds") / "img", episodes=2, frames=8, size=32, seed=1, use_video=False
    )
