"""The plugin's config refusals reach the user of stock `lerobot-train` and `lerobot-eval` (README's training path):
LeRobot's own parser, as the commands call it, prints the plugin's message (field, reason, valid names, the fix) as
its one error line, not draccus' "Couldn't instantiate class" (lerobot_obsbench.patches, fix 4)."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
from pathlib import Path

import pytest
from lerobot.scripts import lerobot_eval, lerobot_train

import lerobot_policy_obsbench  # noqa: F401  (what LeRobot's plugin discovery imports)

TRAIN = ("lerobot-train", lerobot_train.train)
EVAL = ("lerobot-eval", lerobot_eval.eval_main)
ACT_ON = "--policy.type=obs_act --policy.obs_space="

# (command, flags, fragments of the one error line)
ROWS = [
    (
        TRAIN,
        f"{ACT_ON}pointcloud --policy.augment=random_shiftt",
        ["unknown augmentation 'random_shiftt'", "point_jitter"],
    ),
    (
        TRAIN,
        f"{ACT_ON}pointcloud --policy.augment=random_shift",
        ["'random_shift' does not apply to obs_space='pointcloud'"],
    ),
    (
        TRAIN,
        f"{ACT_ON}rgb+pointcloud --policy.encoder=dp3+spatial_softmax",
        ["no fused space has parts", "in this order"],
    ),
    (TRAIN, f"{ACT_ON}rgb --policy.encoder=spatial_softmax --policy.encoder_norm=weird", ["encoder_norm='weird'"]),
    (TRAIN, f"{ACT_ON}pointcloud --policy.encoder=dp3 --policy.knn=8", ["knn=8 is not an option of encoder 'dp3'"]),
    (TRAIN, f"{ACT_ON}pointcloud --policy.encoder=pointclould", ["pointclould"]),
    (TRAIN, f"{ACT_ON}pointclould", ["pointclould"]),
    (TRAIN, f"{ACT_ON}rgb --policy.frame=ee2", ["frame", "ee2"]),
    (TRAIN, f"{ACT_ON}pointcloud --policy.voxel_size=nan", ["voxel_size must be a finite number > 0; got nan"]),
    (TRAIN, f"{ACT_ON}pointcloud --policy.voxel_size=0", ["voxel_size must be a finite number > 0; got 0"]),
    (
        TRAIN,
        f"{ACT_ON}pointcloud --policy.workspace=[nan,1,-1,1,0,1]",
        ["workspace[0] must be a finite number; got nan"],
    ),
    (TRAIN, f"{ACT_ON}pointcloud --policy.workspace=[1,-1,-1,1,0,1]", ["workspace must be", "min < max"]),
    (TRAIN, f"{ACT_ON}pointcloud --policy.workspace_jitter=-0.01", ["workspace_jitter must be a finite number >= 0"]),
    (TRAIN, f"{ACT_ON}depth --policy.depth_clip=[2,inf]", ["depth_clip[1] must be a finite number >= 0; got inf"]),
    (TRAIN, f"{ACT_ON}pointcloud --policy.num_tokens=0", ["num_tokens must be a whole number >= 1; got 0"]),
    (TRAIN, f"{ACT_ON}rgb --policy.optimizer_lr=nan", ["optimizer_lr must be a finite number > 0; got nan"]),
    (
        TRAIN,
        f"{ACT_ON}rgb --policy.scheduler_pct_start=1.5",
        ["scheduler_pct_start must be a finite number > 0 and < 1"],
    ),
    (TRAIN, f"{ACT_ON}rgb --policy.image_input_size=8", ["image_input_size", ">= 16"]),
    (TRAIN, "--policy.type=obs_diffusion --policy.obs_space=rgb --policy.optimizer_eps=-1", ["optimizer_eps"]),
    (EVAL, "--env.type=obsbench_pickcube --env.episode_length=0", ["episode_length", "whole number >= 1; got 0"]),
    (EVAL, "--env.type=obsbench_pickcube --env.episode_length=-5", ["episode_length", "whole number >= 1; got -5"]),
    (EVAL, "--env.type=obsbench_pickcube --env.image_size=16", ["image_size", ">= 32; got 16"]),
    (EVAL, "--env.type=obsbench --env.task=PickCub-v1", ["Unknown task 'PickCub-v1'", "did you mean PickCube-v1"]),
    (EVAL, "--env.type=obsbench_pickcube --env.cameras=[base_camra]", ["base_camra", "no such camera"]),
    (EVAL, "--env.type=obsbench_pickcube --env.perturbation=light:-1", ["perturbation 'light:-1'"]),
]


def stock_error(command, flags: str) -> tuple[int, str]:
    """Exit code and standard error of the stock command's entry point (LeRobot's `parser.wrap` around it) given
    `flags`; training would start on a config it accepts (and fail on the missing dataset)."""
    (name, entry) = command
    extra = ["--dataset.repo_id=local/none"] if name == "lerobot-train" else ["--policy.path=/nonexistent/model"]
    argv, err = [name, *flags.split(), *extra], io.StringIO()
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stderr(err):
        patch.setattr(sys, "argv", argv)
        try:
            entry()
        except SystemExit as stop:
            return stop.code, err.getvalue()
    raise AssertionError(f"{name} {flags}: accepted (no refusal)")


@pytest.mark.parametrize("command, flags, fragments", ROWS, ids=[f"{c[0]} {f[len(ACT_ON) :]}" for c, f, _ in ROWS])
def test_a_plugin_refusal_is_what_the_stock_command_prints(command, flags, fragments):
    code, err = stock_error(command, flags)
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == 1 and len(lines) == 1, err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    assert "Couldn't instantiate" not in err and "Traceback" not in err


def test_the_installed_lerobot_train_prints_the_reason():
    """The real console script: LeRobot's plugin discovery imports the plugin, whose import applies the fix."""
    proc = subprocess.run(
        [
            str(Path(sys.executable).parent / "lerobot-train"),
            *f"{ACT_ON}pointcloud --policy.augment=random_shiftt".split(),
        ]
        + ["--dataset.repo_id=local/none"],
        capture_output=True,
        text=True,
        timeout=600,
        stdin=subprocess.DEVNULL,
    )
    assert proc.returncode == 1
    assert "error: `policy`: unknown augmentation 'random_shiftt'" in proc.stderr, proc.stderr[-2000:]
