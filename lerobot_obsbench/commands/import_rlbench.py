"""`obsbench import-rlbench`: PerAct-format RLBench demonstrations of one task into the schema, optionally with
CLIP language goals (`datasets.rlbench_import`; resumable)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.commands.common import positive_int
from lerobot_obsbench.schema import QUATERNION_MODES

NAME = "import-rlbench"
HELP = "convert PerAct-format RLBench demonstrations (one task folder of a split) into the schema"
EXAMPLE = """obsbench import-rlbench --data data/rlbench/train/open_drawer --out data/rlbench_open_drawer \\
    --clip-weights data/clip/ViT-B-16.pt"""
INTERRUPTED = "the converted episodes are kept in --out; run the same command to go on"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, required=True, help="the task's folder, e.g. data/rlbench/train/open_drawer")
    p.add_argument("--out", type=Path, required=True, help="dataset folder: new, empty, or this import's (resumed)")
    p.add_argument("--overwrite", action="store_true", help="delete what --out holds first")
    p.add_argument("--strict", action="store_true", help="stop at the first unreadable episode (default: skip it)")
    p.add_argument("--task", default=None, help="RLBench task name (default: the folder's name)")
    p.add_argument("--cameras", nargs="+", default=["front"], help="front (the paper), left_shoulder, wrist, ...")
    p.add_argument("--max-episodes", type=positive_int, default=None)
    p.add_argument(
        "--clip-weights",
        default=None,
        help="language goals as observation.environment_state: a local CLIP ViT-B/16 checkpoint, or 'openai' "
        "to download it (default: no language goal)",
    )
    p.add_argument("--quaternion", default="pcm_compat", choices=QUATERNION_MODES)


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.rlbench_import import import_rlbench

    info = import_rlbench(
        args.data,
        args.out,
        task=args.task,
        cameras=tuple(args.cameras),
        text_encoder=_text_encoder(args.clip_weights),
        max_episodes=args.max_episodes,
        quaternion=args.quaternion,
        overwrite=args.overwrite,
        strict=args.strict,
    )
    skipped = f"; {len(info['skipped'])} unreadable episodes skipped (listed in obsbench_import.json)"
    print(
        f"{args.out}: {len(info['episodes'])} {info['task']} episodes imported from {args.data}"
        + (skipped if info["skipped"] else "")
    )
    return 0


def _text_encoder(weights: str | None):
    from lerobot_obsbench.rlbench.text import load_clip_text_encoder

    return load_clip_text_encoder(weights) if weights else None


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
