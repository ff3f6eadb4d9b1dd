"""`obsbench train`: stock `lerobot-train` in the brief's spelling (`policy=act_pcd env=obsbench_pickcube ...`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.errors import MissingFileError, UsageError

NAME = "train"
HELP = (
    "train with stock lerobot-train in the brief's spelling: obsbench train policy=act_pcd "
    "env=obsbench_pickcube [dataset=DIR] [preset=cpu] [policy.field=value ...] [--lerobot.flag=value ...]"
)
EXAMPLE = """obsbench train policy=act_pcd env=obsbench_pickcube preset=cpu --steps=2000"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dry-run", action="store_true", help="print the lerobot-train command and stop")
    p.add_argument("items", nargs=argparse.REMAINDER, help="key=value items and --flags passed to lerobot-train")


def run(args: argparse.Namespace) -> int:
    import shlex
    import subprocess

    command = [sys.executable, "-m", "lerobot.scripts.lerobot_train", *lerobot_train_args(args.items)]
    print("lerobot-train " + shlex.join(command[3:]), flush=True)
    if args.dry_run:
        return 0
    return subprocess.run(command).returncode


def lerobot_train_args(items: list[str]) -> list[str]:
    """The brief's spelling -> stock lerobot-train arguments: `policy=act_pcd env=obsbench_pickcube
    [dataset=DIR] [preset=cpu] [key.sub=value ...] [--any.lerobot=flag ...]`. The dataset defaults to
    data/<task> (what `obsbench demos` is told to write there); a missing one is refused naming that command. The
    preset's fields come last, but for the `--policy.*` fields the user sets: each once, with the user's value."""
    from lerobot.envs.configs import EnvConfig

    from lerobot_obsbench.envs.configuration import env_type_name
    from lerobot_obsbench.policies.named import NAMED_POLICIES
    from lerobot_obsbench.presets import check_preset_policy, preset_args

    values, flags = {}, []
    for item in items:
        if item.startswith("--"):
            flags.append(item)
        elif "=" in item:
            key, value = item.split("=", 1)
            values[key] = value
        else:
            raise UsageError(f"{item!r} is neither key=value nor a --lerobot.flag")
    policy, env = values.pop("policy", None), values.pop("env", None)
    if policy is None or env is None:
        raise UsageError(
            "give policy=TYPE and env=TYPE, e.g. obsbench train policy=act_pcd env=obsbench_pickcube "
            f"(named policy types: {', '.join(NAMED_POLICIES)})"
        )
    preset = values.pop("preset", None)
    if preset is not None:  # a preset that does not describe the policy is refused before the dataset is looked for
        check_preset_policy(preset, NAMED_POLICIES.get(policy, (policy,))[0])
    task = values.get("env.task") or getattr(EnvConfig.get_choice_class(env)(), "task", None)
    root = values.pop("dataset", None) or (f"data/{env_type_name(task).removeprefix('obsbench_')}" if task else None)
    if not any(f.startswith("--dataset.root") for f in flags):
        if root is None:
            raise UsageError(f"env={env} names no OBSBench task; give dataset=DIR")
        if not (Path(root) / "meta" / "info.json").is_file():
            raise MissingFileError(
                f"no dataset at {root}: record it with `obsbench demos --task {task} --episodes 100 --out {root}` "
                "(or pass dataset=DIR)"
            )
        flags += [f"--dataset.root={root}", f"--dataset.repo_id=local/{Path(root).name}"]
    command = [f"--policy.type={policy}", f"--env.type={env}", *(f"--{k}={v}" for k, v in values.items()), *flags]
    if preset is not None:
        user = _policy_values(command)  # given as policy.field=value or --policy.field=value
        base, space, _ = NAMED_POLICIES.get(policy, (policy, user.get("obs_space", "pointcloud"), None))
        command += preset_args(preset, base, space, user.get("encoder"), user_fields=user)
    return command


def _policy_values(command: list[str]) -> dict[str, str]:
    """The `--policy.<field>=<value>` arguments of a command line, as field -> value."""
    return dict(a.removeprefix("--policy.").split("=", 1) for a in command if a.startswith("--policy.") and "=" in a)


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
