"""Stock `lerobot-train` trains every (policy x observation space) pair on a dataset written by non-plugin code,
offline, on CPU, and writes a checkpoint — no plugin flag, no --policy.repo_id (the rgb and point-cloud pairs of both
policies: the grid of tests/bench/test_bench_run.py; the others here)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_obsbench.cli import main
from lerobot_obsbench.commands.train import lerobot_train_args
from lerobot_obsbench.presets import PRESETS, PROTOCOL_OF, preset_args, preset_encoder, preset_overrides
from lerobot_obsbench.schema import POLICY_TYPES, available_spaces, space_info

BIN = Path(sys.executable).parent
SPACES = ["depth", "rgbd", "pointmap"]  # rgb and pointcloud: the bench grid trains both policies on them


def policy_fields(command: list[str]) -> dict[str, list[str]]:
    """Each `--policy.<field>` of a lerobot-train command line -> every value the line gives it, in order."""
    fields: dict[str, list[str]] = {}
    for arg in command:
        if arg.startswith("--policy."):
            name, value = arg.removeprefix("--policy.").split("=", 1)
            fields.setdefault(name, []).append(value)
    return fields


def preset_cases() -> list[tuple[str, str, str, str]]:
    """Every (preset, policy type, space, encoder) a preset has fields for: each encoder that accepts the space (a
    fused space: the preset's pair), so the fields a preset keys by encoder are among them."""
    from lerobot_obsbench.encoders import available_encoders

    return [
        (preset, policy, space, encoder)
        for preset in PRESETS
        for policy in POLICY_TYPES
        if PROTOCOL_OF.get(preset, policy) == policy  # a preset of one policy's protocol describes no other
        for space in available_spaces()
        for encoder in ([preset_encoder(preset, space)] if space_info(space).fused else available_encoders(space))
    ]


def lerobot_train(
    dataset: Path, out: Path, policy_type: str, obs_space: str | None, *extra: str, preset_for: str | None = None
) -> subprocess.CompletedProcess:
    """Stock lerobot-train at tiny sizes; `obs_space=None` leaves the space to a named type (`preset_for`: the
    base type and space whose tiny preset to use)."""
    preset_type, preset_space = (policy_type, obs_space) if preset_for is None else preset_for
    cmd = [
        str(BIN / "lerobot-train"),
        f"--policy.type={policy_type}",
        *([f"--policy.obs_space={obs_space}"] if obs_space else []),
        "--policy.device=cpu",
        "--dataset.repo_id=local/synthetic",
        f"--dataset.root={dataset}",
        "--policy.workspace=[-0.5,0.5,-0.5,0.5,0.005,0.5]",
        "--batch_size=2",
        "--steps=2",
        "--save_freq=2",
        "--log_freq=1",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--output_dir={out}",
        *preset_args("tiny", preset_type, preset_space),
        *extra,
    ]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
    return subprocess.run(cmd, capture_output=True, text=True, env=env, stdin=subprocess.DEVNULL, timeout=600)


@pytest.mark.slow
@pytest.mark.parametrize("obs_space", SPACES)
@pytest.mark.parametrize("policy_type", ["obs_act", "obs_diffusion"])
def test_lerobot_train_every_pair(tiny_dataset, tmp_path, policy_type, obs_space):
    proc = lerobot_train(tiny_dataset, tmp_path / "run", policy_type, obs_space)
    assert proc.returncode == 0, proc.stderr[-4000:]
    ckpt = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    assert (ckpt / "model.safetensors").is_file()
    config = json.loads((ckpt / "config.json").read_text())
    assert config["type"] == policy_type and config["obs_space"] == obs_space
    assert config["cameras"] == ["base_camera"]
    assert "step:2" in proc.stdout + proc.stderr


@pytest.mark.parametrize("spelling", ["policy.{}={}", "--policy.{}={}"])
def test_obsbench_train_gives_lerobot_train_each_preset_field_once_with_the_users_value(spelling):
    """`obsbench train ... preset=tiny policy.encoder=spatial_softmax` used to train resnet18: the preset's fields
    came after the user's on the command line, so the preset won."""
    for preset, policy, space, encoder in preset_cases():
        user = {
            name: encoder if name == "encoder" else f"user_{name}"
            for name in preset_overrides(preset, policy, space, encoder)
        }
        user.update(obs_space=space, encoder=encoder)
        items = [spelling.format(name, value) for name, value in user.items()]
        command = lerobot_train_args(
            [f"policy={policy}", "env=obsbench_pushcube", "--dataset.root=data/x", f"preset={preset}", *items]
        )
        assert policy_fields(command) == {"type": [policy], **{name: [value] for name, value in user.items()}}, (
            preset,
            policy,
            space,
            encoder,
        )


def test_obsbench_train_dry_run_shows_the_users_encoder_and_token_count(capsys):
    common = ["train", "--dry-run", "env=obsbench_pushcube", "--dataset.root=data/x", "preset=tiny"]
    assert main([*common, "policy=obs_act", "policy.obs_space=rgb", "policy.encoder=spatial_softmax"]) == 0
    assert policy_fields(capsys.readouterr().out.split())["encoder"] == ["spatial_softmax"]
    assert main([*common, "policy=act_pcd", "--policy.num_tokens=64"]) == 0
    assert policy_fields(capsys.readouterr().out.split())["num_tokens"] == ["64"]
    # a named type's encoder is a default the preset may change (cpu: ResNet-18); the user's still wins
    assert main([*common, "policy=act_rgb", "policy.encoder=spatial_softmax"]) == 0
    assert policy_fields(capsys.readouterr().out.split())["encoder"] == ["spatial_softmax"]


def test_obsbench_preset_prints_the_users_encoder_where_the_preset_sets_one(capsys):
    """Pasted after `--policy.encoder=spatial_softmax`, the printed preset used to set ResNet-18 back."""
    assert main(["preset", "--preset", "tiny", "--obs-space", "rgb", "--encoder", "spatial_softmax"]) == 0
    assert policy_fields(capsys.readouterr().out.split())["encoder"] == ["spatial_softmax"]


def _zero_depth(frames):
    """A frame hook blanking the depth of the listed (episode, frame) pairs: a RealSense dropout."""

    def hook(episode, index, frame):
        if (episode, index) in frames:
            key = "observation.depth.base_camera"
            frame = {**frame, key: frame[key] * 0}
        return frame

    return hook


@pytest.mark.slow
def test_training_goes_through_an_empty_depth_frame(tmp_path, synthetic_module):
    # 3 episodes x 12 frames, one with no depth at all; batch 4 x 9 steps is one epoch: every frame is trained on
    root = synthetic_module.write_dataset(
        tmp_path / "dropout", episodes=3, frames=12, size=32, seed=5, use_video=False, frame_hook=_zero_depth({(1, 5)})
    )
    proc = lerobot_train(
        root, tmp_path / "run", "obs_act", "pointcloud", "--batch_size=4", "--steps=9", "--save_freq=9"
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "1 of " in proc.stderr and "had no valid point inside the workspace" in proc.stderr
    assert (tmp_path / "run" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").is_file()


@pytest.mark.slow
def test_training_on_mostly_empty_frames_stops_early(tmp_path, synthetic_module):
    empty = {(e, i) for e in range(3) for i in range(12) if e != 0}  # 2 of 3 episodes without depth
    root = synthetic_module.write_dataset(
        tmp_path / "blind_camera",
        episodes=3,
        frames=12,
        size=32,
        seed=6,
        use_video=False,
        frame_hook=_zero_depth(empty),
    )
    proc = lerobot_train(root, tmp_path / "run", "obs_act", "pointcloud", "--batch_size=4", "--steps=200")
    assert proc.returncode != 0
    assert "training frames have no valid point inside the workspace" in proc.stderr
    assert "obsbench validate --root DATASET" in proc.stderr
    assert "step:50" not in proc.stdout + proc.stderr  # stopped within its first batches, not hours in


@pytest.mark.slow
@pytest.mark.parametrize("named, base, space", [("dp_rgb", "obs_diffusion", "rgb")])  # act_pcd: test_stock_depth.py
def test_a_named_type_trains_and_loads_back_under_its_name(tiny_dataset, tmp_path, named, base, space):
    import torch

    from lerobot_obsbench.policies.loading import load_policy
    from tests.support.helpers import first_batch, training_setup

    proc = lerobot_train(tiny_dataset, tmp_path / "run", named, None, preset_for=(base, space))
    assert proc.returncode == 0, proc.stderr[-4000:]
    ckpt = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((ckpt / "config.json").read_text())
    assert config["type"] == named and config["obs_space"] == space
    first, pre, _ = load_policy(ckpt)
    second, _, _ = load_policy(ckpt)
    assert (
        first.config.type == named
        and type(first).__name__ == "".join(p.capitalize() for p in named.split("_")) + "Policy"
    )
    assert isinstance(first, type(training_setup(base, space, tiny_dataset)[0]))  # obs_act / obs_diffusion code
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    batch = first_batch(LeRobotDataset("local/test", root=tiny_dataset), pre, batch_size=2)
    batch = {k: v for k, v in batch.items() if k.startswith("observation.")}
    torch.manual_seed(0)
    a = first.select_action(batch)
    torch.manual_seed(0)
    b = second.select_action(batch)
    assert torch.equal(a, b)
