"""`obsbench` commands and presets."""

from __future__ import annotations

import re
import shutil

import pytest
import torch

from lerobot_obsbench.cli import main
from lerobot_obsbench.policies.onecycle import OneCycleSchedulerConfig
from lerobot_obsbench.presets import preset_args, preset_encoder, preset_overrides


def test_encoders_lists_spaces(capsys):
    assert main(["encoders", "--obs-space", "pointcloud"]) == 0
    out = capsys.readouterr().out
    assert "pointnet" in out and "resnet18" not in out


def test_validate_reports_every_space(tiny_dataset, capsys):
    assert main(["validate", "--root", str(tiny_dataset)]) == 0
    out = capsys.readouterr().out
    assert all(f"ok      {space}" in out for space in ("rgb", "depth", "rgbd", "pointmap", "pointcloud"))
    assert "6 episodes, 72 frames" in out


def test_validate_names_the_missing_key(tiny_dataset, tmp_path, capsys):
    # the same dataset with its depth feature removed from the metadata
    import json

    root = tmp_path / "nodepth"
    shutil.copytree(tiny_dataset, root)
    info = json.loads((root / "meta" / "info.json").read_text())
    del info["features"]["observation.depth.base_camera"]
    (root / "meta" / "info.json").write_text(json.dumps(info))
    assert main(["validate", "--root", str(root), "--obs-space", "pointcloud"]) == 1
    assert "observation.depth.<cam>" in capsys.readouterr().out
    assert main(["validate", "--root", str(root), "--obs-space", "rgb"]) == 0


def test_preset_flags_parse_back(capsys):
    assert main(["preset", "--preset", "cpu", "--policy", "obs_diffusion", "--obs-space", "rgbd"]) == 0
    out = capsys.readouterr().out.split()
    assert "--policy.down_dims=[64,128,256]" in out and "--policy.encoder=resnet18" in out
    assert "--policy.encoder=resnet18" not in preset_args("cpu", "obs_act", "pointcloud")
    # the paper preset keeps the defaults' model sizes: it sets only the official protocol's fields
    assert sorted(preset_args("paper", "obs_act", "rgb")) == [
        "--policy.action_loss=mse",
        "--policy.image_input_size=224",
        "--policy.optimizer_grad_clip_norm=0.5",
        "--policy.scheduler_pct_start=0.1",
        "--policy.zero_init_extra_channels=True",
    ]
    with pytest.raises(ValueError, match="Unknown preset"):
        preset_args("gpu", "obs_act", "rgb")


def test_preset_takes_the_named_policy_types(capsys):
    """README's own `act_pcd` was refused: a named type is its base type, space and encoder."""
    for named, spelled in (
        (["--policy", "act_pcd"], ["--policy", "obs_act", "--obs-space", "pointcloud", "--encoder", "pointnet"]),
        (["--policy", "dp_rgb"], ["--policy", "obs_diffusion", "--obs-space", "rgb", "--encoder", "resnet18"]),
    ):
        assert main(["preset", "--preset", "cpu", *named]) == 0
        out = capsys.readouterr().out
        assert main(["preset", "--preset", "cpu", *spelled]) == 0
        assert out == capsys.readouterr().out and out.strip()
    assert main(["preset", "--policy", "act_pcd", "--obs-space", "rgb"]) == 2
    assert "act_pcd fixes the observation space to pointcloud" in capsys.readouterr().err


def test_presets_set_only_what_the_space_uses():
    assert "num_tokens" not in preset_overrides("cpu", "obs_act", "rgb")  # a point field would be refused for rgb
    assert preset_overrides("cpu", "obs_act", "pointcloud")["num_tokens"] == 128
    assert "encoder" not in preset_overrides("cpu", "obs_act", "pointcloud")
    assert [preset_encoder(p, s) for p in ("paper", "cpu") for s in ("rgbd", "pointcloud")] == [
        "resnet50",
        "pointnet",
        "resnet18",
        "pointnet",
    ]
    from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig

    for preset in ("paper", "cpu", "tiny"):  # every preset builds for every space
        for space in ("rgb", "depth", "rgbd", "pointmap", "pointcloud"):
            ObsACTConfig(device="cpu", obs_space=space, **preset_overrides(preset, "obs_act", space))
            ObsDiffusionConfig(device="cpu", obs_space=space, **preset_overrides(preset, "obs_diffusion", space))


def test_onecycle_schedule_follows_the_paper():
    opt = torch.optim.AdamW([torch.nn.Parameter(torch.zeros(1))], lr=1e-4)
    sched = OneCycleSchedulerConfig().build(opt, num_training_steps=100)
    lrs = []
    for _ in range(100):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert lrs[0] == pytest.approx(1e-6)  # max / div_factor 100
    assert max(lrs) == pytest.approx(1e-4, rel=1e-3) and lrs.index(max(lrs)) in (14, 15)  # pct_start 0.15
    assert lrs[-1] < 1e-8 * 2  # final lr = initial / 1000


def test_wilson_interval_against_published_values():
    from lerobot_obsbench.stats import wilson_interval

    # Wilson (1927) 95% intervals, as tabulated e.g. by Newcombe (1998), Table I
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    assert wilson_interval(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    assert wilson_interval(81, 263) == pytest.approx((0.2553, 0.3662), abs=1e-4)
    with pytest.raises(ValueError):
        wilson_interval(3, 2)


def test_one_success_summary_for_simulation_rlbench_and_real_robot_results():
    from lerobot_obsbench.stats import success_summary

    summary = success_summary([False] * 5 + [True] * 5)
    assert summary == {"episodes": 10, "successes": 5, "success_rate": 0.5, "ci95": [0.2366, 0.7634]}
    assert success_summary([]) == {"episodes": 0, "successes": 0, "success_rate": None, "ci95": [0.0, 1.0]}


def test_small_probes_get_one_line_answers(tmp_path, capsys):
    """The probes of the robustness issue that need no simulator: each answer is one line naming the fix."""
    from lerobot_obsbench import __version__

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0 and capsys.readouterr().out.strip() == f"lerobot-obsbench {__version__}"

    with pytest.raises(SystemExit):
        main(["demos", "--task", "PushCube-v1", "--episodes", "0", "--out", str(tmp_path / "d")])
    assert "argument --episodes: must be a whole number >= 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()

    missing = tmp_path / "run" / "pretrained_model"
    assert main(["eval", "--policy.path", str(missing), "--env.task", "PushCube-v1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"obsbench eval: error: policy checkpoint {missing} not found (a `pretrained_model` directory written by "
        "lerobot-train, or a Hub repo id ORG/NAME)"
    )

    args = ["eval", "--policy.path", str(missing), "--env.task", "PushCube-v1", "--env.perturbation", "light:nan"]
    assert main(args) == 2  # the perturbation is checked before the checkpoint is even looked for
    assert capsys.readouterr().err.strip() == (
        "obsbench eval: error: perturbation 'light:nan': expected light:I (e.g. light:0.03), with finite numbers"
    )

    args = ["eval", "--policy.path", str(missing), "--env.task", "PushCube-v1", "--eval.sim_backend", "physx_cuda"]
    assert main(args) == 2  # before the checkpoint, too
    assert capsys.readouterr().err.strip() == (
        "obsbench eval: error: --eval.sim_backend=physx_cuda (ManiSkill's GPU simulation) needs --policy.device=cuda"
    )

    assert main(["report", str(tmp_path / "results.jsonl")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"obsbench report: error: results file {tmp_path / 'results.jsonl'} not found (`obsbench run` writes "
        "OUT/results.jsonl)"
    )


@pytest.mark.parametrize(
    "text, message",
    [
        ("light:nan", "expected light:I (e.g. light:0.03), with finite numbers"),
        ("camera_yaw:ten", "expected camera_yaw:DEG (e.g. camera_yaw:10), with finite numbers"),
        ("background:1,x,0", "expected background:R,G,B (e.g. background:1,0.2,0.2)"),
    ],
)
def test_unparsable_perturbations_say_what_is_expected(text, message):
    from lerobot_obsbench.envs.perturbations import parse_perturbation

    with pytest.raises(ValueError, match=re.escape(message)):
        parse_perturbation(text)


def test_asset_hint_names_flags_that_exist():
    from lerobot_obsbench.cli import build_parser
    from lerobot_obsbench.envs.base_task import asset_help, task_spec

    hint = asset_help(task_spec("TurnFaucet-v1"), "/data/ms")
    assert "--asset-dir /data/ms (obsbench doctor, obsbench import-h5)" in hint
    parser = build_parser()
    for command in ("doctor", "import-h5"):
        sub = parser._subparsers._group_actions[0].choices[command]
        assert "--asset-dir" in sub._option_string_actions
    eval_parser = parser._subparsers._group_actions[0].choices["eval"]
    assert "--env.asset_dir" in eval_parser._option_string_actions


def test_train_front_end_speaks_the_brief_and_names_the_missing_dataset(tiny_dataset, tmp_path, capsys):
    from lerobot_obsbench.commands.train import lerobot_train_args

    command = lerobot_train_args(
        [
            "policy=act_pcd",
            "env=obsbench_pickcube",
            f"dataset={tiny_dataset}",
            "preset=tiny",
            "policy.device=cpu",
            "--steps=3",
        ]
    )
    assert command[:3] == ["--policy.type=act_pcd", "--env.type=obsbench_pickcube", "--policy.device=cpu"]
    assert "--steps=3" in command and f"--dataset.root={tiny_dataset}" in command
    assert "--policy.dim_model=32" in command  # the tiny preset of obs_act on pointcloud
    assert main(["train", "--dry-run", "policy=act_pcd", "env=obsbench_pickcube", f"dataset={tmp_path}"]) == 2
    assert (
        f"no dataset at {tmp_path}: record it with `obsbench demos --task PickCube-v1 --episodes 100 --out "
        f"{tmp_path}`" in capsys.readouterr().err
    )
    # the generic env type takes the task from env.task, and the default dataset from the task's name
    assert main(["train", "--dry-run", "policy=act_pcd", "env=obsbench", "env.task=StackCube-v1"]) == 2
    assert (
        "no dataset at data/stackcube: record it with `obsbench demos --task StackCube-v1 --episodes 100 --out "
        "data/stackcube`" in capsys.readouterr().err
    )


def test_every_command_has_its_own_module_whose_example_parses_and_shows_in_help(capsys):
    """Each command is a module of lerobot_obsbench.commands with its own main; its --help ends with an example,
    and that example parses through the same parser (a renamed flag breaks here, not in a reader's terminal)."""
    import importlib
    import shlex

    from lerobot_obsbench.cli import build_parser
    from lerobot_obsbench.commands import COMMANDS, common

    parser = build_parser()
    subparsers = parser._subparsers._group_actions[0].choices
    assert sorted(subparsers) == sorted(name.replace("_", "-") for name in COMMANDS)
    for module_name in COMMANDS:
        command = importlib.import_module(f"lerobot_obsbench.commands.{module_name}")
        assert command.NAME == module_name.replace("_", "-") and callable(command.main)
        with pytest.raises(SystemExit) as stop:
            command.main(["--help"])
        assert stop.value.code == 0
        shown = capsys.readouterr().out
        assert f"usage: obsbench {command.NAME}" in shown and "example:\n  obsbench " + command.NAME in shown
        argv = shlex.split(command.EXAMPLE.replace("\\\n", " "))
        assert argv[:2] == ["obsbench", command.NAME]
        args = common.parse(parser, argv[1:])
        assert args.command is command


def test_device_options_reach_lerobots_parser_with_either_spelling():
    """`--robot.port=/dev/x` and `--robot.port /dev/x` both reach LeRobot's robot config; anything else unknown is
    refused by argparse."""
    from lerobot_obsbench.cli import build_parser
    from lerobot_obsbench.commands import common, rollout

    argv = ["rollout", "--robot.type", "obsbench_koch_follower", "--robot.port=/dev/x", "--policy_path", "ckpt"]
    args = common.parse(build_parser(), argv)
    assert args.device_options == ["--robot.type=obsbench_koch_follower", "--robot.port=/dev/x"]
    robot = common.device_configs(rollout.RobotDevice, args.device_options, "rollout").robot
    assert robot.port == "/dev/x" and args.policy_path == "ckpt"
    with pytest.raises(SystemExit):
        common.parse(build_parser(), [*argv, "--teleop.type=koch_leader"])  # rollout drives no teleoperator
