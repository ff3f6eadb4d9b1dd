"""`obsbench eval`: a checkpoint's success rate on a ManiSkill task's fixed held-out seeds, optionally
under one zero-shot perturbation (`envs.evaluate`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench.commands import common
from lerobot_obsbench.commands.common import frame_size, positive_int
from lerobot_obsbench.outputs import check_output_file, check_output_folder

NAME = "eval"
HELP = "success rate of a checkpoint on the task's fixed held-out seeds 0..N-1"
EXAMPLE = """obsbench eval --policy.path=outputs/train/pickcube/checkpoints/last/pretrained_model \\
    --env.task=PickCube-v1 --episodes 50 --eval.batch_size=2 --env.perturbation=camera_yaw:10 --out eval.json"""
INTERRUPTED = "no result was written (--out is written once every episode is done)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lerobot_obsbench.envs.maniskill import CONTROL_MODES, DEFAULT_CONTROL_MODE, SIM_BACKENDS
    from lerobot_obsbench.envs.vector import DEFAULT_BATCH_SIZE

    p.add_argument("--policy.path", dest="policy_path", required=True, help="pretrained_model directory")
    p.add_argument("--env.task", dest="task", required=True)
    p.add_argument("--episodes", type=positive_int, default=50)
    p.add_argument(
        "--env.image_size",
        dest="image_size",
        type=frame_size,
        default=None,
        help="default: the resolution the policy was trained on",
    )
    p.add_argument("--env.control_mode", dest="control_mode", default=DEFAULT_CONTROL_MODE, choices=CONTROL_MODES)
    p.add_argument(
        "--env.episode_length",
        dest="episode_length",
        type=positive_int,
        default=None,
        help="steps per episode (default: the task's)",
    )
    p.add_argument("--env.asset_dir", dest="asset_dir", default=None)
    p.add_argument(
        "--env.perturbation",
        dest="perturbation",
        default=None,
        help="zero-shot perturbation kind:value, e.g. camera_yaw:10, light:0.03, background:1,0.2,0.2, noise:16",
    )
    p.add_argument("--policy.device", dest="device", type=common.torch_device, default="cpu")
    p.add_argument(
        "--eval.batch_size",
        dest="batch_size",
        type=positive_int,
        default=None,
        help="episodes run in lockstep, one batched policy call per step (default: the measured best for the "
        f"device, {DEFAULT_BATCH_SIZE['cpu']} on cpu); 1: one episode at a time in this process",
    )
    p.add_argument(
        "--eval.sim_backend",
        dest="sim_backend",
        default="auto",
        choices=("auto", *SIM_BACKENDS),
        help="physx_cpu: ManiSkill's CPU simulation, each env in a process of its own; physx_cuda: all N envs in "
        "ManiSkill's GPU simulation in this process (results differ from the CPU simulation's); auto: physx_cuda "
        "for N > 1 on a cuda device, else physx_cpu",
    )
    p.add_argument(
        "--videos",
        type=Path,
        default=None,
        help="write one mp4 per episode here (TASK_seedN.mp4); files of those names are replaced only when an "
        "evaluation of the same checkpoint, task and perturbation wrote them, or with --overwrite",
    )
    p.add_argument("--out", type=Path, default=None, help="write the JSON result here (a file, checked first)")
    p.add_argument(
        "--overwrite", action="store_true", help="replace an existing --out file and --videos files of the same names"
    )


def run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.envs.base_task import eval_seeds
    from lerobot_obsbench.envs.evaluate import evaluate, video_name, videos_made_by, write_result
    from lerobot_obsbench.envs.perturbations import parse_perturbation
    from lerobot_obsbench.envs.vector import default_batch_size

    parse_perturbation(args.perturbation)  # a typo fails before the policy and the simulator load
    if args.out is not None:
        check_output_file(args.out, "--out", args.overwrite)  # before the episodes it would hold
    if args.videos is not None:
        check_output_folder(
            args.videos,
            "--videos",
            inputs=[Path(args.policy_path)],
            files=[video_name(args.task, seed) for seed in eval_seeds(args.episodes)],
            made_by=videos_made_by(
                args.policy_path,
                args.task,
                args.perturbation,
                args.episode_length,
                args.image_size,
                args.control_mode,
            ),
            overwrite=args.overwrite,
        )

    result = evaluate(
        args.policy_path,
        args.task,
        args.episodes,
        image_size=args.image_size,
        control_mode=args.control_mode,
        episode_length=args.episode_length,
        device=args.device,
        video_dir=args.videos,
        asset_dir=args.asset_dir,
        perturbation=args.perturbation,
        batch_size=args.batch_size or default_batch_size(args.device),
        sim_backend=args.sim_backend,
    )
    write_result(result, args.out)
    lo, hi = result["ci95"]
    sub = "".join(f", {k} {v:.0%}" for k, v in result["sub_success"].items())
    print(
        f"{result['task']}: success {result['successes']}/{result['episodes']} = {result['success_rate']:.1%} "
        f"(95% CI {lo:.1%}-{hi:.1%}){sub}; mean episode length {result['episode_length_mean']}"
        + (f"; written to {args.out}" if args.out else "")
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return common.main(sys.modules[__name__], argv)


if __name__ == "__main__":
    sys.exit(main())
