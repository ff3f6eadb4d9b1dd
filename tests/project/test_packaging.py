"""A wheel built from the repository carries what an installed plugin needs: the preset grids (configs/) are
package data, so `obsbench run quick` works from a wheel install, not only from a source checkout."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile

import pytest

from tests.support.paths import REPO_ROOT as ROOT


@pytest.mark.slow
def test_a_wheel_installed_in_a_scratch_venv_finds_the_preset_grids(tmp_path):
    """configs/grids/ (top level in the repository) ships inside the wheel; the installed `obsbench` finds the
    `quick` grid by name, away from any source checkout."""
    import sysconfig

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
    assert "lerobot_obsbench/configs/grids/quick.yaml" in names
    assert "lerobot_obsbench/configs/grids/paper-main.yaml" in names
    assert "lerobot_obsbench/bench/tables/table2_dp.csv" in names
    assert "lerobot_obsbench/bench/rates.json" in names  # the cost model the dry run below prices with
    assert "lerobot_obsbench/envs/metaworld/workspaces.json" in names  # the Meta-World tasks' crop boxes
    assert not any(name.startswith("tests/") for name in names)  # test support stays out of the package
    venv = tmp_path / "scratch"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    install = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(venv / "bin" / "python"),
            "install",
            "--no-deps",
            "-q",
            str(wheel),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        # a PYTHONPATH holding the checkout (and the egg-info the wheel build left there) would make pip think the
        # plugin is installed already and skip it
        env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"},
    )
    assert install.returncode == 0, install.stderr[-3000:]
    # the dependencies (LeRobot, ManiSkill, ...) come from this environment's site-packages, where the plugin
    # itself is only an editable-install hook that a PYTHONPATH entry does not run: the plugin is the wheel's
    env = {**os.environ, "PYTHONPATH": sysconfig.get_paths()["purelib"], "HF_HUB_OFFLINE": "1"}
    where = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import lerobot_obsbench; print(lerobot_obsbench.__file__)"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert where.stdout.startswith(str(venv)), where.stdout + where.stderr[-2000:]
    run = subprocess.run(
        [str(venv / "bin" / "obsbench"), "run", "quick", "--dry-run", "--out", "out"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=300,
    )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
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
