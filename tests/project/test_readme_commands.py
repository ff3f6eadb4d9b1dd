"""Every `obsbench` and `lerobot-*` command line in the shell code blocks of README.md, of every docs/*.md page and of
every published run's docs/results/*/README.md parses as written: the plugin's own commands through `obsbench`'s
argparse parser (a device command's `--robot.*` / `--teleop.*` options through LeRobot's draccus configs), LeRobot's
through the config classes its scripts parse (with the plugin's types registered). Nothing runs; a renamed flag, a
removed choice or a type the plugin no longer registers fails here, naming the page, not in a reader's terminal.
Also: README links every docs/ page, and every relative link in these pages points at a file that exists.

The pages' notation: `[--flag value]` is an optional part (checked too, its first `a|b` alternative), `...`
stands for elided arguments (such a line is checked up to it), `NAME="..."` defines a shell variable used below."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from tests.support.paths import REPO_ROOT as ROOT

# the front door, the reference pages, and the pages that present a published run
PAGES = [
    ROOT / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "docs").glob("results/*/README.md")),
]
COMMAND = re.compile(r"^(?:[A-Z_]+=\S+\s+)*(?:\.venv/bin/)?(obsbench|lerobot-[a-z-]+)\b(.*)$")
# LeRobot scripts whose configuration the pages' lines are parsed into: (module, config class)
LEROBOT_CONFIGS = {
    "lerobot-train": ("lerobot.configs.train", "TrainPipelineConfig"),
    "lerobot-eval": ("lerobot.configs.eval", "EvalPipelineConfig"),
    "lerobot-calibrate": ("lerobot.scripts.lerobot_calibrate", "CalibrateConfig"),
    "lerobot-teleoperate": ("lerobot.scripts.lerobot_teleoperate", "TeleoperateConfig"),
}
NO_ARGUMENTS = ("lerobot-find-port",)


def _page_name(page: Path) -> str:
    return str(page.relative_to(ROOT))


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
    """What `$(obsbench preset ...)` prints: the command itself, run in this process."""
    from lerobot_obsbench.cli import main

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(shlex.split(match.group(1))) == 0, match.group(0)
    return printed.getvalue().strip()


def shell_blocks(text: str) -> list[str]:
    """The text of every fenced block marked bash, sh or nothing (indented ones included); not text, yaml, ..."""
    blocks, language, lines = [], None, []
    for line in text.splitlines():
        fence = re.match(r"^\s*```(\S*)\s*$", line)
        if fence and language is None:
            language, lines = fence.group(1), []
        elif fence:
            if language in ("", "bash", "sh"):
                blocks.append("\n".join(lines) + "\n")
            language = None
        elif language is not None:
            lines.append(line)
    return blocks


def page_commands(page: Path) -> list[tuple[str, list[str]]]:
    """(program, arguments) of every command line in the page's shell blocks."""
    found = []
    for block in shell_blocks(page.read_text()):
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


COMMANDS = [(_page_name(page), program, args) for page in PAGES for program, args in page_commands(page)]


def test_pages_have_the_commands_they_document():
    programs = {program for _, program, _ in COMMANDS}
    assert {"obsbench", "lerobot-train", "lerobot-eval", "lerobot-calibrate", "lerobot-teleoperate"} <= programs
    assert len(COMMANDS) >= 30
    readme = {program for page, program, _ in COMMANDS if page == "README.md"}
    assert {"obsbench", "lerobot-train", "lerobot-eval"} <= readme  # the front door shows training with stock LeRobot


def test_readme_links_every_docs_page():
    readme = (ROOT / "README.md").read_text()
    missing = [_page_name(page) for page in PAGES[1:] if f"]({_page_name(page)})" not in readme]
    assert not missing, f"README's Documentation list does not link {missing}"


def test_readme_names_every_env_type():
    from lerobot_obsbench.envs.configuration import NAMED_ENVS

    readme = (ROOT / "README.md").read_text()
    missing = sorted(name for name in NAMED_ENVS if f"`{name}`" not in readme)
    assert not missing, f"README's list of env types leaves out {missing}"


def _anchors(page: Path) -> set[str]:
    """GitHub's anchors of a Markdown page's headings (code blocks left out)."""
    text = re.sub(r"^\s*```.*?^\s*```", "", page.read_text(), flags=re.S | re.M)
    headings = re.findall(r"^#{1,6}\s+(.+?)\s*$", text, re.M)
    return {re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-") for heading in headings}


@pytest.mark.parametrize("page", PAGES, ids=_page_name)
def test_relative_links_resolve(page):
    """`[text](path)`, `[text](path#anchor)` and `[text](#anchor)` within the repository: the file exists and,
    for a Markdown page, has a heading with that anchor."""
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
        path, _, anchor = target.partition("#")
        if re.match(r"^[a-z]+:", path):
            continue  # a web address
        file = (page.parent / path) if path else page
        if not file.exists() or (anchor and file.suffix == ".md" and anchor not in _anchors(file)):
            broken.append(target)
    assert not broken, f"{_page_name(page)} links to missing files or headings: {broken}"


def _parse_devices(groups: tuple[str, ...], options: list[str]) -> None:
    """A device command's `--robot.*` / `--teleop.*` options, parsed by LeRobot's own configs (draccus)."""
    from dataclasses import field, make_dataclass

    import draccus
    from lerobot.robots import RobotConfig
    from lerobot.teleoperators import TeleoperatorConfig

    kinds = {"robot": RobotConfig, "teleop": TeleoperatorConfig}
    devices = make_dataclass("Devices", [(group, kinds[group] | None, field(default=None)) for group in groups])
    draccus.parse(devices, args=options)


def _parse_obsbench(args: list[str]) -> None:
    import importlib

    from lerobot_obsbench.cli import build_parser

    parsed, rest = build_parser().parse_known_args(args)
    assert parsed is not None
    command = importlib.import_module(f"lerobot_obsbench.commands.{args[0].replace('-', '_')}")
    groups = tuple(getattr(command, "DEVICE_OPTIONS", ()))
    unknown = [a for a in rest if not a.startswith(tuple(f"--{group}." for group in groups))]
    assert not unknown, f"obsbench {args[0]} does not take {unknown}"
    if groups:
        _parse_devices(groups, rest)


def _parse_lerobot(program: str, args: list[str]) -> None:
    import importlib

    import draccus

    module, name = LEROBOT_CONFIGS[program]
    # --policy.path loads a checkpoint's config (LeRobot's parser does it before draccus): not a parse check
    kept = [a for a in args if not a.startswith("--policy.path=")]
    draccus.parse(getattr(importlib.import_module(module), name), args=kept)


@pytest.mark.parametrize(
    "page, program, args", COMMANDS, ids=[f"{page}: {p} {' '.join(a)[:60]}" for page, p, a in COMMANDS]
)
def test_page_command_parses(page, program, args):
    from lerobot.teleoperators import koch_leader  # noqa: F401  (registered by LeRobot's own scripts)

    import lerobot_obsbench  # noqa: F401  (the plugin's policies, envs, robots and cameras)

    if program in NO_ARGUMENTS:
        assert args == [], f"{page}: {program} takes no arguments"
    elif program == "obsbench":
        _parse_obsbench(args)
    else:
        assert program in LEROBOT_CONFIGS, f"{page} runs {program}: add its config class to LEROBOT_CONFIGS"
        _parse_lerobot(program, args)
