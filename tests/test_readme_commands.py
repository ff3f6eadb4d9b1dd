"""Every `obsbench` and `lerobot-*` command line in README's code blocks parses as written: the plugin's own
commands through their argparse / draccus parsers, LeRobot's through the config classes its scripts parse
(with the plugin's types registered). Nothing runs; a renamed flag, a removed choice or a type the plugin no
longer registers fails here, not in a reader's terminal.

README's notation: `[--flag value]` is an optional part (checked too, its first `a|b` alternative), `...` stands
for elided arguments (such a line is checked up to it), `NAME="..."` defines a shell variable used below."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
COMMAND = re.compile(r"^(?:[A-Z_]+=\S+\s+)*(?:\.venv/bin/)?(obsbench|lerobot-[a-z-]+)\b(.*)$")
# LeRobot scripts whose configuration README's lines are parsed into: (module, config class)
LEROBOT_CONFIGS = {
    "lerobot-train": ("lerobot.configs.train", "TrainPipelineConfig"),
    "lerobot-eval": ("lerobot.configs.eval", "EvalPipelineConfig"),
    "lerobot-calibrate": ("lerobot.scripts.lerobot_calibrate", "CalibrateConfig"),
    "lerobot-teleoperate": ("lerobot.scripts.lerobot_teleoperate", "TeleoperateConfig"),
}
NO_ARGUMENTS = ("lerobot-find-port",)


def _without_comment(line: str) -> str:
    """The line up to a ` #` comment outside quotes."""
    quote = None
    for i, char in enumerate(line):
        if char in "\"'" and quote in (None, char):
            quote = None if quote else char
        elif char == "#" and quote is None and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip()
    return line


def _optional_parts(text: str) -> str:
    """`[--flag a|b]` (a bracket after a space) -> `--flag a`; `--x=[1,2]` (a value) stays."""
    return re.sub(r"(?<=\s)\[([^\]]*)\]", lambda m: re.sub(r"(\S+)\|\S+", r"\1", m.group(1)), text)


def _preset_output(match: re.Match) -> str:
    """What `$(obsbench preset ...)` prints: the preset's --policy.* arguments."""
    from lerobot_obsbench.cli import build_parser
    from lerobot_obsbench.presets import preset_args

    args = build_parser().parse_args(shlex.split(match.group(1)))
    return " ".join(preset_args(args.preset, args.policy, args.obs_space, args.encoder))


def readme_commands() -> list[tuple[str, list[str]]]:
    """(program, arguments) of every command line in README's shell blocks."""
    found = []
    for block in re.findall(r"```(?:bash|sh)?\n(.*?)```", README.read_text(), re.S):
        variables: dict[str, str] = {}
        for raw in block.replace("\\\n", " ").splitlines():
            line = _without_comment(raw.strip())
            assignment = re.match(r'^([A-Z_]+)="(.*)"$', line)
            if assignment:
                variables[assignment.group(1)] = assignment.group(2)
                continue
            match = COMMAND.match(line)
            if not match:
                continue
            text = match.group(2).split(" ...")[0]
            text = re.sub(r"\$\((?:\.venv/bin/)?obsbench (preset [^)]*)\)", _preset_output, text)
            text = re.sub(r'"\$([A-Z_]+)"', lambda m, v=variables: shlex.quote(v[m.group(1)]), text)  # one word
            text = re.sub(r"\$([A-Z_]+)", lambda m, v=variables: v[m.group(1)], text)  # split into words
            args = shlex.split(_optional_parts(" " + text))
            if args or " ..." not in match.group(2):  # a line that is only an ellipsis shows no arguments
                found.append((match.group(1), args))
    return found


COMMANDS = readme_commands()


def test_readme_has_the_commands_it_documents():
    programs = {program for program, _ in COMMANDS}
    assert {"obsbench", "lerobot-train", "lerobot-eval", "lerobot-calibrate", "lerobot-teleoperate"} <= programs
    assert len(COMMANDS) >= 30


def _parse_obsbench(args: list[str]) -> None:
    from lerobot_obsbench.cli import HARDWARE_COMMANDS, build_parser

    if args[0] in HARDWARE_COMMANDS:
        import draccus

        from lerobot_obsbench.datasets.teleop_recording import RecordConfig
        from lerobot_obsbench.robots.rollout import RolloutConfig

        draccus.parse({"record": RecordConfig, "rollout": RolloutConfig}[args[0]], args=args[1:])
    else:
        build_parser().parse_args(args)


def _parse_lerobot(program: str, args: list[str]) -> None:
    import importlib

    import draccus
    from lerobot.teleoperators import koch_leader  # noqa: F401  (registered by LeRobot's own scripts)

    module, name = LEROBOT_CONFIGS[program]
    # --policy.path loads a checkpoint's config (LeRobot's parser does it before draccus): not a parse check
    kept = [a for a in args if not a.startswith("--policy.path=")]
    draccus.parse(getattr(importlib.import_module(module), name), args=kept)


@pytest.mark.parametrize("program, args", COMMANDS, ids=[f"{p} {' '.join(a)[:60]}" for p, a in COMMANDS])
def test_readme_command_parses(program, args):
    import lerobot_obsbench  # noqa: F401  (the plugin's policies, envs, robots and cameras)

    if program in NO_ARGUMENTS:
        assert args == []
    elif program == "obsbench":
        _parse_obsbench(args)
    else:
        assert program in LEROBOT_CONFIGS, f"README runs {program}: add its config class to LEROBOT_CONFIGS"
        _parse_lerobot(program, args)
