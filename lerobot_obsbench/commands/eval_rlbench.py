"""`obsbench eval-rlbench`: a checkpoint's success rate on an RLBench task's test episodes, the paper's protocol
(`rlbench.evaluate`; needs CoppeliaSim)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.commands.common import positive_int
from lerobot_obsbench.outputs import check_output_file
from lerobot_obsbench.schema import QUATERNION_MODES

NAME = "eval-rlbench"
HELP = "success rate of a checkpoint on an RLBench task's test episodes (needs CoppeliaSim)"
EXAMPLE = """obsbench eval-rlbench --policy.path=outputs/train/open_drawer/checkpoints/last/pretrained_model \\
    --task open_drawer --data data/rlbench/test --camera-view y:5"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy.path", dest="policy_path", required=True, help="pretrained_model directory")
    p.add_argument("--task", required=True)
    p.add_argument("--data", type=Path, required=True, help="the raw test split folder, e.g. data/rlbench/test")
    p.add_argument("--episodes", type=positive_int, default=25)
    p.add_argument("--max-steps", type=positive_int, default=200)
    p.add_argument(
        "--camera-view", type=camera_view, default=None, help="AXIS:DEGREES[,SHIFT_M], e.g. y:-5,0.1 or z:-10"
    )
    p.add_argument("--clip-weights", default=None, help="the CLIP checkpoint the dataset was imported with")
    p.add_argument("--quaternion", default="pcm_compat", choices=QUATERNION_MODES)
    p.add_argument("--policy.device", dest="device", type=common.torch_device, default="cpu")
    p.add_argument("--out", type=Path, default=None, help="write the JSON result here (a file, checked first)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.envs.evaluate import write_result
    from lerobot_obsbench.rlbench.evaluate import CameraView, evaluate_checkpoint
    from lerobot_obsbench.rlbench.paper_tasks import rlbench_task

    task = rlbench_task(args.task)
    view = CameraView(*args.camera_view) if args.camera_view else None
    if args.out is not None:
        check_output_file(args.out, "--out", args.overwrite)  # before the episodes it would hold
    result = evaluate_checkpoint(
        args.policy_path,
        task,
        args.data,
        args.episodes,
        args.max_steps,
        camera_view=view,
        clip_weights=args.clip_weights,
        quaternion=args.quaternion,
        device=args.device,
    )
    write_result(result, args.out)
    lo, hi = result["ci95"]
    print(f"{task.name}: success {result['successes']}/{result['episodes']} (95% CI {lo:.1%}-{hi:.1%})")
    return 0


def camera_view(text: str) -> tuple[str, float, float]:
    """argparse type of --camera-view: AXIS:DEGREES[,SHIFT_M] with AXIS y or z."""
    axis, _, rest = text.partition(":")
    degrees, _, shift = rest.partition(",")
    try:
        values = float(degrees), float(shift or 0.0)
    except ValueError:
        values = None
    if axis not in ("y", "z") or values is None:
        raise argparse.ArgumentTypeError(
            f"expected AXIS:DEGREES[,SHIFT_M] with AXIS y or z (e.g. y:-5,0.1); got {text!r}"
        )
    return (axis, *values)


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
