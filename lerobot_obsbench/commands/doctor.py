"""`obsbench doctor`: check in plain words that the simulator renders here and which tasks can run offline."""

from __future__ import annotations

import argparse
import sys

from lerobot_obsbench.commands import common

NAME = "doctor"
HELP = "check simulator rendering and which tasks can run on this machine"
EXAMPLE = """obsbench doctor"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--asset-dir", default=None, help="ManiSkill asset directory (MS_ASSET_DIR)")


def run(args: argparse.Namespace) -> int:
    """Plain-words check of the simulator set-up: rendering, and which tasks run here."""
    import time

    from lerobot_obsbench.envs.base_task import TASKS, asset_help, missing_assets
    from lerobot_obsbench.envs.maniskill import ObsBenchEnv, RenderingError

    problems = 0
    try:
        start = time.time()
        env = ObsBenchEnv("PickCube-v1", image_size=32, asset_dir=args.asset_dir)
        env.reset(seed=0)
        frame = env.render()
        env.close()
        print(
            f"ok      rendering works (PickCube-v1 made, reset and rendered {frame.shape} in "
            f"{time.time() - start:.1f} s)"
        )
    except RenderingError as err:
        print(f"FAILED  rendering: {err}")
        return 1
    for name, spec in TASKS.items():
        missing = missing_assets(spec)
        if missing:
            problems += 1
            print(f"assets  {name}: " + asset_help(spec, args.asset_dir).replace("\n", "\n        "))
        else:
            print(f"ok      {name} runs offline")
    return 0 if problems == 0 else 2


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
