"""A wheel built from the repository carries what an installed plugin needs: the preset grids are package data,
so `obsbench run quick` works from a wheel install, not only from a source checkout."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_finds_the_preset_grids(tmp_path):
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(tmp_path / "dist")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("lerobot_policy_obsbench-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        archive.extractall(tmp_path / "site")
    assert (
        "lerobot_obsbench/bench/grids/quick.yaml" in names and "lerobot_obsbench/bench/grids/paper-main.yaml" in names
    )
    # the unpacked wheel comes first on the path; the working directory holds no source checkout
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "site"), "HF_HUB_OFFLINE": "1"}
    script = (
        "import sys, lerobot_obsbench; print(lerobot_obsbench.__file__); from lerobot_obsbench.cli import main; "
        "sys.exit(main(['run', 'quick', '--dry-run', '--out', 'out']))"
    )
    run = subprocess.run(
        [sys.executable, "-c", script],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=300,
    )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    assert run.stdout.splitlines()[0].startswith(str(tmp_path / "site"))
    assert "grid quick:" in run.stdout and "to train" in run.stdout


def test_the_environment_is_consistent():
    """The README's set-up gives one OpenCV (sapien's opencv-python and LeRobot's headless build write the same
    cv2 package) and no broken requirement."""
    from importlib.metadata import version

    import cv2

    assert version("opencv-python") == version("opencv-python-headless")
    assert version("opencv-python-headless").startswith(cv2.__version__)
    check = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True, timeout=300)
    assert check.returncode == 0, check.stdout + check.stderr
