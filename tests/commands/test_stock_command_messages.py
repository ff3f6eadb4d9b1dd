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


@pytest.mark.slow
def test_a_refusal_while_stock_lerobot_train_runs_is_one_line_and_comes_before_any_step(tmp_path, synthetic_module):
    """Refusals raised once the command runs (the dataset's loading, the first step) used to end in a traceback;
    an all-zero depth recording used to train 15 steps before the adapter stopped it. Now stock lerobot-train
    refuses it as the dataset loads, in the one line `obsbench` would print."""
    import numpy as np

    from lerobot_obsbench.presets import preset_args

    key = "observation.depth.base_camera"

    def zero_depth(episode, index, frame):
        return {**frame, key: np.zeros_like(frame[key])}

    root = synthetic_module.write_dataset(tmp_path / "d", episodes=2, frames=6, size=32, seed=0, frame_hook=zero_depth)
    proc = subprocess.run(
        [
            str(Path(sys.executable).parent / "lerobot-train"),
            *f"{ACT_ON}pointcloud --policy.device=cpu --policy.push_to_hub=false".split(),
            *preset_args("tiny", "obs_act", "pointcloud"),
            "--policy.workspace=[-0.5,0.5,-0.5,0.5,0.005,0.5]",
            f"--dataset.root={root}",
            "--dataset.repo_id=local/d",
            "--steps=20",
            "--batch_size=2",
            "--num_workers=0",
            "--wandb.enable=false",
            f"--output_dir={tmp_path / 'out'}",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        stdin=subprocess.DEVNULL,
        env={**__import__("os").environ, "HF_HUB_OFFLINE": "1"},
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith(f"lerobot-train: error: {key}: every frame's depth is 0 (invalid)"), proc.stderr[-2000:]
    assert "obsbench validate --root" in last and "Traceback" not in proc.stderr
    assert "step:" not in proc.stdout + proc.stderr  # refused before the first optimizer step


def test_only_the_plugins_own_refusals_lose_their_traceback():
    code = (
        "import sys; sys.argv = ['lerobot-eval']; import lerobot_obsbench\n"
        "from lerobot_obsbench.schema import SchemaError\n"
        "if sys.argv[1:] == []: raise RuntimeError('first step') from SchemaError('cameras: the policy reads x')\n"
    )
    refused = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert refused.returncode == 1 and refused.stderr.strip().splitlines() == [
        "lerobot-eval: error: cameras: the policy reads x"
    ]
    other = subprocess.run(
        [sys.executable, "-c", code.replace("from SchemaError('cameras: the policy reads x')", "")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert other.returncode == 1 and "Traceback" in other.stderr and "RuntimeError: first step" in other.stderr
