"""`obsbench` command line: what LeRobot has no command for.

Simulation (doctor, demos, import-h5, import-rlbench, eval, eval-rlbench), the benchmark (train, run, report,
convert-results), the Hub (push, push-dataset), datasets and configs (validate, encoders, preset, view,
attach-calibration) and real robots (find-cameras, calibrate-cameras, refine-cameras, record, rollout).
Training and stock evaluation stay with LeRobot (`lerobot-train --policy.type=obs_act ...`, `lerobot-eval`).
Each command is a module of `lerobot_obsbench.commands`; `obsbench COMMAND --help` shows its options and an example.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from lerobot_obsbench import __version__
from lerobot_obsbench.commands import COMMANDS, common


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="obsbench", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"lerobot-obsbench {__version__}")
    sub = parser.add_subparsers(dest="command_name", metavar="COMMAND", required=True)
    for module_name in COMMANDS:
        command = importlib.import_module(f"lerobot_obsbench.commands.{module_name}")
        summary = command.HELP.replace("%", "%%")  # argparse %-formats help texts
        common.configure(sub.add_parser(command.NAME, help=summary, description=command.HELP), command)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = common.parse(build_parser(), sys.argv[1:] if argv is None else list(argv))
    return common.run(args.command, args)


if __name__ == "__main__":
    sys.exit(main())
