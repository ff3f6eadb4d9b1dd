"""`obsbench` command line: what LeRobot has no command for.

Simulation (doctor, demos, import-h5, eval), the benchmark (run, report, convert-results), the Hub (push,
push-dataset), datasets and configs (validate, encoders, preset, view) and real robots (find-cameras,
calibrate-cameras, record, rollout).
Training and stock evaluation stay with LeRobot (`lerobot-train --policy.type=obs_act ...`, `lerobot-eval`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_obsbench import __version__
from lerobot_obsbench.errors import ObsBenchError, UsageError
from lerobot_obsbench.outputs import OutputPathError, check_output_file, check_output_folder, write_text_atomic
from lerobot_obsbench.schema import MIN_IMAGE_SIZE, OBS_SPACES, POLICY_TYPES, QUATERNION_MODES


def cmd_encoders(args: argparse.Namespace) -> int:
    from lerobot_obsbench.encoders import available_encoders, encoder_info

    for name in available_encoders(args.obs_space):
        info = encoder_info(name)
        weights = f"; pretrained: {info.pretrained}" if info.pretrained else ""
        print(f"{name:10s} spaces: {', '.join(info.spaces):32s} {info.summary}{weights}")
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.validation import validate_dataset

    if not (Path(args.root) / "meta" / "info.json").is_file():
        raise FileNotFoundError(f"{args.root} is not a LeRobot dataset (no meta/info.json)")
    return validate_dataset(args.root, args.repo_id, args.obs_space, args.cameras or None, quick=args.quick)


def cmd_attach_calibration(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.calibration import attach_calibration

    path, calibration = attach_calibration(
        args.root, args.camera, args.from_json, args.from_recording, args.serial, args.cam2world
    )
    print(
        f"camera {args.camera}: colour {calibration.color_size[1]}x{calibration.color_size[0]}, depth "
        f"{calibration.depth_size[1]}x{calibration.depth_size[0]} ({calibration.depth_unit_mm:g} mm per unit, holes "
        f"<= {calibration.depth_min_mm:g}), from {calibration.source}; written to {path}"
    )
    return 0


def cmd_preset(args: argparse.Namespace) -> int:
    from lerobot_obsbench.presets import preset_args

    print(" ".join(preset_args(args.preset, args.policy, args.obs_space, args.encoder)))
    return 0


def cmd_demos(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.recording import record_demos

    info = record_demos(
        args.task,
        args.episodes,
        args.out,
        image_size=args.image_size,
        cameras=args.cameras,
        seed_start=args.seed_start,
        overwrite=args.overwrite,
    )
    print(
        f"{args.out}: {len(info['seeds'])} episodes of {args.task}; expert success rate "
        f"{info['expert_success_rate']:.0%} over {info['attempts']} attempts (seeds {info['seeds'][0]}..)"
    )
    return 0


def cmd_doctor(args: argparse.Namespace) -> int:
    """Plain-words check of the simulator set-up: rendering, and which tasks run here."""
    import time

    from lerobot_obsbench.envs.maniskill import ObsBenchEnv, RenderingError
    from lerobot_obsbench.envs.task import TASKS, asset_help, missing_assets

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


def cmd_import(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.maniskill_import import import_trajectories

    info = import_trajectories(
        args.h5,
        args.out,
        image_size=args.image_size,
        cameras=args.cameras,
        max_episodes=args.max_episodes,
        only_success=not args.all,
        asset_dir=args.asset_dir,
        overwrite=args.overwrite,
    )
    print(f"{args.out}: {len(info['episode_ids'])} {info['task']} episodes imported from {args.h5}")
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


def _text_encoder(weights: str | None):
    from lerobot_obsbench.rlbench.text import load_clip_text_encoder

    return load_clip_text_encoder(weights) if weights else None


def cmd_import_rlbench(args: argparse.Namespace) -> int:
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


def cmd_eval_rlbench(args: argparse.Namespace) -> int:
    from lerobot_obsbench.envs.evaluate import write_result
    from lerobot_obsbench.rlbench.evaluate import CameraView, evaluate_checkpoint
    from lerobot_obsbench.rlbench.tasks import rlbench_task

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


def cmd_eval(args: argparse.Namespace) -> int:
    from lerobot_obsbench.envs.evaluate import evaluate, write_result
    from lerobot_obsbench.envs.perturbations import parse_perturbation

    parse_perturbation(args.perturbation)  # a typo fails before the policy and the simulator load
    if args.out is not None:
        check_output_file(args.out, "--out", args.overwrite)  # before the episodes it would hold

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


def cmd_run(args: argparse.Namespace) -> int:
    from lerobot_obsbench.bench.grid import GridError, load_grid
    from lerobot_obsbench.bench.runner import run_grid

    grid = load_grid(args.grid)
    for flag, value in (("--rlbench-data", args.rlbench_data), ("--clip-weights", args.clip_weights)):
        if value is not None and not grid.rlbench_data:
            raise GridError(f"{flag} applies to grids of RLBench tasks; {grid.name} has none")
    grid.rlbench_data = args.rlbench_data or grid.rlbench_data
    grid.clip_weights = args.clip_weights or grid.clip_weights
    out = args.out or Path("outputs") / "bench" / grid.name
    loader_workers = args.loader_workers if args.loader_workers is not None else (0 if args.device == "cpu" else 4)
    failures = run_grid(
        grid,
        out,
        engine=args.engine,
        workers=args.workers,
        device=args.device,
        address=args.address,
        dry_run=args.dry_run,
        loader_workers=loader_workers,
        threads=args.threads,
        progress_every=args.progress_every,
    )
    if failures:
        print(f"{failures} unit(s) of work failed (see the messages above); rerun the same command to retry them.")
        return 1
    if not args.dry_run:
        print(f"done: results in {out / 'results.jsonl'}; `obsbench report {out / 'results.jsonl'}` makes the tables")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    import json

    from lerobot_obsbench.bench.report import (
        ReportError,
        build_report,
        markdown_table,
        read_published,
        resolve_table,
        summary_json,
        write_report,
    )
    from lerobot_obsbench.bench.results import read_results

    if args.results is None and args.table is None:
        raise UsageError("give a results file (results.jsonl) and/or --table FILE.csv")
    if args.results is not None and not args.results.is_file():
        raise ReportError(f"results file {args.results} not found (`obsbench run` writes OUT/results.jsonl)")
    out = args.out or (args.results.parent / "report" if args.results else Path("report"))
    check_output_folder(out, "--out")
    if args.json:
        check_output_file(args.json, "--json", overwrite=True)  # a summary is regenerated, like the report
    records = read_results(args.results) if args.results else []
    if args.results and not records:
        print(f"warning: no readable records in {args.results}", file=sys.stderr)
    table = resolve_table(args.table) if args.table else None
    published = read_published(table) if table else None
    report = build_report(
        records,
        published,
        published_name=table.stem if table else "published",
        checkpoint=args.checkpoint,
        reference=args.reference,
    )
    paths = write_report(report, out, title=args.title)
    heading, (header, rows) = report["sections"][0]
    print(f"{heading}\n{markdown_table(header, rows)}")
    for warning in report["warnings"]:
        print(f"note: {warning}")
    for source, methods in report["summary"].items():
        for method, s in sorted(methods.items(), key=lambda kv: kv[1]["mean_rank"]):
            print(f"{source:9s} {method:45s} Mean S.R. {s['mean_sr']:.2f}  Mean Rank {s['mean_rank']:.2f}")
    if args.json:
        write_text_atomic(args.json, json.dumps(summary_json(report), indent=2) + "\n")
    print(f"report: {paths['markdown']}, {paths['html']}" + (f"; summary: {args.json}" if args.json else ""))
    return 0


def cmd_convert(args: argparse.Namespace) -> int:
    from lerobot_obsbench.bench.results import convert_v1

    backup = convert_v1(args.results)
    print(f"{args.results}: converted to train + eval records; the original is kept as {backup}")
    return 0


def train_command(items: list[str]) -> list[str]:
    """The brief's spelling -> stock lerobot-train arguments: `policy=act_pcd env=obsbench_pickcube
    [dataset=DIR] [preset=cpu] [key.sub=value ...] [--any.lerobot=flag ...]`. The dataset defaults to
    data/<task> (what `obsbench demos` is told to write there); a missing one is refused naming that command."""
    from lerobot.envs.configs import EnvConfig

    from lerobot_obsbench.envs.configuration import env_type_name
    from lerobot_obsbench.policies.named import NAMED_POLICIES
    from lerobot_obsbench.presets import preset_args

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
    task = values.get("env.task") or getattr(EnvConfig.get_choice_class(env)(), "task", None)
    root = values.pop("dataset", None) or (f"data/{env_type_name(task).removeprefix('obsbench_')}" if task else None)
    if not any(f.startswith("--dataset.root") for f in flags):
        if root is None:
            raise UsageError(f"env={env} names no OBSBench task; give dataset=DIR")
        if not (Path(root) / "meta" / "info.json").is_file():
            raise FileNotFoundError(
                f"no dataset at {root}: record it with `obsbench demos --task {task} --episodes 100 --out {root}` "
                "(or pass dataset=DIR)"
            )
        flags += [f"--dataset.root={root}", f"--dataset.repo_id=local/{Path(root).name}"]
    preset = values.pop("preset", None)
    if preset is not None:
        base, space, _ = NAMED_POLICIES.get(policy, (policy, values.get("policy.obs_space", "pointcloud"), None))
        flags += preset_args(preset, base, space, values.get("policy.encoder"))
    return [f"--policy.type={policy}", f"--env.type={env}", *(f"--{k}={v}" for k, v in values.items()), *flags]


def cmd_train(args: argparse.Namespace) -> int:
    import shlex
    import subprocess

    command = [sys.executable, "-m", "lerobot.scripts.lerobot_train", *train_command(args.items)]
    print("lerobot-train " + shlex.join(command[3:]), flush=True)
    if args.dry_run:
        return 0
    return subprocess.run(command).returncode


def cmd_push(args: argparse.Namespace) -> int:
    from lerobot_obsbench.bench.hub import push_checkpoint

    url = push_checkpoint(args.path, args.repo_id, args.checkpoint, args.private, args.eval)
    print(f"{args.path} -> {url} (load it with --policy.path={args.repo_id}; the model card names the install line)")
    return 0


def cmd_push_dataset(args: argparse.Namespace) -> int:
    from lerobot_obsbench.bench.hub import push_dataset

    push_dataset(args.root, args.repo_id, args.private)
    print(f"{args.root} -> {args.repo_id} (LeRobotDataset({args.repo_id!r}) downloads it)")
    return 0


def cmd_find_cameras(args: argparse.Namespace) -> int:
    from lerobot_obsbench.robots.extrinsics import extrinsics_path
    from lerobot_obsbench.robots.realsense.realsense_rgbd import RealSenseRGBDCamera

    found = RealSenseRGBDCamera.find_cameras()
    if not found:
        print("no RealSense camera found (check the USB 3 cable and that libusb-1.0-0 is installed)")
    for camera in found:
        path = extrinsics_path(camera["id"], args.extrinsics_dir)
        calibrated = f"extrinsics: {path}" if path.is_file() else "not calibrated: obsbench calibrate-cameras"
        print(f"{camera['id']}  {camera['name']}  {camera.get('usb_type', '')}  {calibrated}")
    return 0


def cmd_calibrate_cameras(args: argparse.Namespace) -> int:
    import time

    import cv2
    import numpy as np
    from scipy.spatial.transform import Rotation

    from lerobot_obsbench.robots.extrinsics import BoardSpec, calibrate, save_extrinsics
    from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig
    from lerobot_obsbench.robots.realsense.realsense_rgbd import RealSenseRGBDCamera

    spec = BoardSpec(*args.squares, args.square_length, args.marker_length, args.dictionary)
    if args.print_board:
        check_output_file(args.print_board, "--print-board", overwrite=True)
        unwritable = OutputPathError(
            f"--print-board {args.print_board}: OpenCV could not write it; give an image file name ending in .png"
        )
        if not cv2.haveImageWriter(str(args.print_board)):
            raise unwritable
        args.print_board.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(args.print_board), spec.image()):  # OpenCV returns False instead of raising
            raise unwritable
        print(f"{args.print_board}: print at 100 % and check that a square measures {args.square_length * 1000:g} mm")
        return 0
    if not args.serial and not args.playback:
        raise UsageError("give --serial (see `obsbench find-cameras`) or --playback FILE")
    if args.out:  # before the camera starts
        check_output_folder(Path(args.out), "--out")
    board_to_world = np.eye(4)
    x, y, z, roll, pitch, yaw = args.board_pose
    board_to_world[:3, :3] = Rotation.from_euler("xyz", [roll, pitch, yaw], degrees=True).as_matrix()
    board_to_world[:3, 3] = [x, y, z]
    config = RealSenseRGBDCameraConfig(
        serial_number=args.serial or "",
        playback_file=args.playback,
        width=args.width,
        height=args.height,
        fps=args.fps,
        downsample=1,
        warmup_s=0.0 if args.playback else 1.0,  # a recording needs no auto-exposure to settle
    )
    camera = RealSenseRGBDCamera(config)
    camera.connect()
    try:
        images = []
        for _ in range(args.views):
            images.append(camera.async_read(timeout_ms=2000))
            time.sleep(args.interval)
        K, serial = camera.K, camera.serial_number
    finally:
        camera.disconnect()
    result = calibrate(
        images,
        K,
        serial,
        spec,
        board_to_world,
        min_views=args.min_views,
        min_corners=args.min_corners,
        max_reprojection_px=args.max_reprojection,
    )
    path = save_extrinsics(result, args.out)
    height = result.matrix()[2, 3]
    print(
        f"camera {serial}: {result.views_used}/{args.views} views, reprojection {result.reprojection_px:.2f} px, "
        f"spread {result.spread_mm:.2f} mm; camera {height:.3f} m above the board plane -> {path}"
    )
    return 0


def _view_workspace(args: argparse.Namespace):
    """The crop box of `view` / `refine-cameras`: --workspace, else the --preset's, else the default."""
    from lerobot_obsbench.presets import preset_overrides

    if args.workspace is not None:
        return args.workspace
    if args.preset:
        workspace = preset_overrides(args.preset, POLICY_TYPES[0], "pointcloud").get("workspace")
        if workspace is not None:
            return workspace
    from lerobot_obsbench.spaces import DEFAULT_WORKSPACE

    return DEFAULT_WORKSPACE


def _live_cameras(args: argparse.Namespace) -> dict:
    """RealSense configs of --serial / --playback (camera_0, camera_1, ... in that order)."""
    from lerobot_obsbench.robots.realsense.config_realsense_rgbd import RealSenseRGBDCameraConfig

    if not args.serial and not args.playback:
        raise UsageError("give --serial SERIAL ... or --playback FILE.bag ... for the cameras")
    sources = [("serial_number", s) for s in args.serial] + [("playback_file", f) for f in args.playback]
    return {
        f"camera_{i}": RealSenseRGBDCameraConfig(
            **{field: value},
            width=args.width,
            height=args.height,
            fps=args.fps,
            downsample=args.downsample,
            warmup_s=0.0 if field == "playback_file" else 1.0,
        )
        for i, (field, value) in enumerate(sources)
    }


def cmd_view(args: argparse.Namespace) -> int:
    from lerobot_obsbench.datasets.view import dataset_frame, live_frame, log_frame

    if args.out:  # before the dataset or the cameras are opened
        check_output_file(args.out, "--out", overwrite=True)
    if args.ply:
        check_output_file(args.ply, "--ply", overwrite=True)
    workspace = _view_workspace(args)
    if args.root:
        frame = dataset_frame(args.root, args.frame, args.repo_id)
    elif args.serial or args.playback:
        frame, _ = live_frame(_live_cameras(args), args.extrinsics_dir)
    else:
        raise UsageError("give --root DATASET, or --serial SERIAL ... / --playback FILE.bag ... for cameras")
    shown = log_frame(frame, workspace, args.voxel_size, args.cameras or None, args.out, ply=args.ply)
    where = f"saved to {shown['rrd']} (open with `rerun {shown['rrd']}`)" if shown["rrd"] else "sent to the viewer"
    print(
        f"cameras {', '.join(shown['cameras'])}: {shown['points_all']} points, {shown['points_policy']} after the "
        f"workspace {list(workspace)} and {args.voxel_size * 1000:g} mm voxels; {where}"
        + (f"; cloud written to {shown['ply']}" if shown["ply"] else "")
    )
    return 0


def cmd_refine_cameras(args: argparse.Namespace) -> int:
    from dataclasses import replace

    import numpy as np

    from lerobot_obsbench.datasets.view import camera_cloud, clouds, live_frame
    from lerobot_obsbench.robots.extrinsics import load_extrinsics, save_extrinsics
    from lerobot_obsbench.robots.fusion import align_clouds, write_ply
    from lerobot_obsbench.schema import cam2world_key

    configs = _live_cameras(args)
    if len(configs) < 2:
        raise UsageError("give two or more cameras; the first is the reference")
    if args.ply:
        check_output_file(args.ply, "--ply", overwrite=True)
    workspace = _view_workspace(args)
    frame, serials = live_frame(configs, args.extrinsics_dir)
    names = list(configs)
    reference = camera_cloud(frame, names[0], workspace)
    for name in names[1:]:
        before = np.asarray(frame[cam2world_key(name)], dtype=np.float64)
        alignment = align_clouds(
            reference, camera_cloud(frame, name, workspace), before, args.max_mm, args.max_deg, args.min_overlap
        )
        after = np.asarray(alignment.correction) @ before
        frame[cam2world_key(name)] = after.astype(np.float32)
        saved = load_extrinsics(serials[name], args.extrinsics_dir)
        refinement = {"reference_serial": serials[names[0]], "workspace": list(workspace), **alignment.as_dict()}
        where = "not saved (--dry-run)"
        if not args.dry_run:
            path = save_extrinsics(replace(saved, cam2world=after.tolist(), refinement=refinement), args.extrinsics_dir)
            where = f"saved to {path}"
        print(
            f"camera {serials[name]}: moved {alignment.translation_mm:.2f} mm and {alignment.rotation_deg:.3f} degrees "
            f"onto camera {serials[names[0]]} ({alignment.overlap:.0%} of its points overlap, rmse "
            f"{alignment.rmse_mm:.2f} mm); {where}"
        )
    if args.ply:
        _, xyz, rgb = clouds(frame, names, workspace, args.voxel_size)
        print(f"fused cloud of {len(names)} cameras, {len(xyz)} points: {write_ply(args.ply, xyz, rgb)}")
    return 0


def positive_int(text: str) -> int:
    """argparse type: a whole number >= 1 (checked before anything starts)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def frame_size(text: str) -> int:
    """argparse type: a camera frame size in pixels, at least the smallest every stage handles."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of pixels, got {text!r}") from None
    if value < MIN_IMAGE_SIZE:
        raise argparse.ArgumentTypeError(
            f"must be >= {MIN_IMAGE_SIZE} pixels (LeRobot's video encoder fails on smaller frames), got {value}"
        )
    return value


def build_parser() -> argparse.ArgumentParser:
    from lerobot_obsbench.bench.engines import ENGINES
    from lerobot_obsbench.bench.grid import preset_grids
    from lerobot_obsbench.bench.report import CHECKPOINT_CHOICES, published_tables
    from lerobot_obsbench.envs.maniskill import CONTROL_MODES, DEFAULT_CONTROL_MODE
    from lerobot_obsbench.envs.task import DEMO_SEED_START
    from lerobot_obsbench.presets import PRESETS

    parser = argparse.ArgumentParser(
        prog="obsbench", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"lerobot-obsbench {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (_, summary) in HARDWARE_COMMANDS.items():
        sub.add_parser(name, help=f"{summary} (LeRobot-style options: obsbench {name} --help)", add_help=False)

    p = sub.add_parser("encoders", help="list registered encoders and the observation spaces they accept")
    p.add_argument("--obs-space", choices=OBS_SPACES, help="only encoders accepting this space")
    p.set_defaults(func=cmd_encoders)

    p = sub.add_parser(
        "validate",
        help="check that a LeRobotDataset serves each observation space: keys and shapes, then every frame's "
        "depth, intrinsics and camera pose (README: Dataset schema); exit code 1 when an asked space fails",
    )
    p.add_argument("--root", required=True, help="dataset directory")
    p.add_argument("--repo-id", default="local/dataset")
    p.add_argument("--obs-space", default="all", choices=("all", *OBS_SPACES))
    p.add_argument("--cameras", nargs="*", default=[], help="camera names (default: every camera found)")
    p.add_argument(
        "--quick", action="store_true", help="check the metadata only (default: also scan every frame's sensors)"
    )
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser(
        "attach-calibration",
        help="attach a camera's calibration to a dataset recorded by stock lerobot-record with RealSense depth "
        "(use_depth: true), so that depth, rgbd, pointmap and point-cloud policies train on it",
        epilog="example: obsbench attach-calibration --root data/koch_pick --camera front --serial 123456789 "
        "--cam2world ~/.cache/huggingface/lerobot/calibration/obsbench_extrinsics/123456789.json",
    )
    p.add_argument("--root", required=True, help="dataset directory (its meta/obsbench_cameras.json is written)")
    p.add_argument("--camera", required=True, help="camera name: the <cam> of observation.images.<cam>_depth")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--serial", help="read intrinsics and depth->colour extrinsics from this connected RealSense")
    source.add_argument("--from-recording", help="read them from a RealSense recording (.bag) of the same streams")
    source.add_argument("--from-json", help="read them from a JSON object of CameraCalibration fields")
    p.add_argument("--cam2world", help="the camera pose: obsbench calibrate-cameras' saved file or a 4x4 JSON matrix")
    p.set_defaults(func=cmd_attach_calibration)

    p = sub.add_parser(
        "demos",
        help="record successful scripted-expert demonstrations into a LeRobotDataset "
        "(resumable: rerun the same command after an interruption)",
    )
    p.add_argument("--task", required=True)
    p.add_argument("--episodes", type=positive_int, required=True)
    p.add_argument("--out", type=Path, required=True, help="dataset folder: new, empty, or this recording's (resumed)")
    p.add_argument("--overwrite", action="store_true", help="delete what --out holds first")
    p.add_argument("--image-size", type=frame_size, default=128)
    p.add_argument("--cameras", nargs="+", default=["base_camera"])
    p.add_argument(
        "--seed-start",
        type=int,
        default=DEMO_SEED_START,
        help=f"first demonstration seed (>= "
        f"{DEMO_SEED_START}; lower seeds are reserved for evaluation and checkpoint selection)",
    )
    p.set_defaults(func=cmd_demos)

    p = sub.add_parser(
        "import-h5",
        help="convert official ManiSkill trajectories (.h5 + .json) into the schema by replaying their env states",
    )
    p.add_argument("--h5", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True, help="dataset folder: new, empty, or this import's (resumed)")
    p.add_argument("--overwrite", action="store_true", help="delete what --out holds first")
    p.add_argument("--image-size", type=frame_size, default=128)
    p.add_argument("--cameras", nargs="+", default=["base_camera"])
    p.add_argument("--max-episodes", type=positive_int, default=None)
    p.add_argument("--all", action="store_true", help="also import unsuccessful episodes")
    p.add_argument("--asset-dir", default=None, help="ManiSkill asset directory, for tasks with assets (TurnFaucet)")
    p.set_defaults(func=cmd_import)

    p = sub.add_parser(
        "import-rlbench",
        help="convert PerAct-format RLBench demonstrations (one task folder of a split) into the schema",
    )
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
    p.set_defaults(func=cmd_import_rlbench)

    p = sub.add_parser(
        "eval-rlbench", help="success rate of a checkpoint on an RLBench task's test episodes (needs CoppeliaSim)"
    )
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
    p.add_argument("--policy.device", dest="device", default="cpu")
    p.add_argument("--out", type=Path, default=None, help="write the JSON result here (a file, checked first)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=cmd_eval_rlbench)

    p = sub.add_parser("eval", help="success rate of a checkpoint on the task's fixed held-out seeds 0..N-1")
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
    p.add_argument("--env.episode_length", dest="episode_length", type=int, default=None)
    p.add_argument("--env.asset_dir", dest="asset_dir", default=None)
    p.add_argument(
        "--env.perturbation",
        dest="perturbation",
        default=None,
        help="zero-shot perturbation kind:value, e.g. camera_yaw:10, light:0.03, background:1,0.2,0.2, noise:16",
    )
    p.add_argument("--policy.device", dest="device", default="cpu")
    p.add_argument("--videos", type=Path, default=None, help="write one mp4 per episode here")
    p.add_argument("--out", type=Path, default=None, help="write the JSON result here (a file, checked first)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("doctor", help="check simulator rendering and which tasks can run on this machine")
    p.add_argument("--asset-dir", default=None, help="ManiSkill asset directory (MS_ASSET_DIR)")
    p.set_defaults(func=cmd_doctor)

    p = sub.add_parser(
        "run",
        help="run a benchmark grid (YAML file or preset name: quick, paper-main, ...): "
        "demos -> lerobot-train -> eval -> results.jsonl; resumable",
    )
    p.add_argument("grid", help=f"grid YAML file, or the name of a preset grid: {', '.join(preset_grids())}")
    p.add_argument("--out", type=Path, default=None, help="output directory (default outputs/bench/<grid name>)")
    p.add_argument(
        "--engine",
        default="local",
        choices=ENGINES,
        help="local: a process pool on this machine; "
        "ray: Ray tasks on an existing cluster (--address) or a new local Ray instance",
    )
    p.add_argument("--address", default=None, help="Ray cluster address (e.g. auto, or ray://HEAD:10001)")
    p.add_argument("--workers", type=int, default=1, help="units of work run in parallel by the local engine")
    p.add_argument(
        "--device",
        default="cpu",
        help="torch device for training, evaluation and the simulator's "
        "renderer (cpu, cuda, cuda:N); with cuda each unit asks the engine for one GPU",
    )
    p.add_argument(
        "--threads",
        type=int,
        default=None,
        help="CPU threads per unit (default: the cores shared by the local workers; 1 per CPU under Ray)",
    )
    p.add_argument("--progress-every", type=float, default=30.0, help="seconds between progress lines")
    p.add_argument(
        "--loader-workers",
        type=int,
        default=None,
        help="DataLoader workers per training run (default: 0 on cpu, 4 on a GPU)",
    )
    p.add_argument("--dry-run", action="store_true", help="print the runs still to do and a rough cost; run nothing")
    p.add_argument(
        "--rlbench-data", default=None, help="RLBench grids: PerAct's data (DIR/train|val|test/<task>), for the grid's"
    )
    p.add_argument("--clip-weights", default=None, help="RLBench grids: CLIP ViT-B/16 weights file, for the grid's")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser(
        "report", help="paper-style tables (Markdown + HTML) and plots from results.jsonl and/or a published table"
    )
    p.add_argument("results", type=Path, nargs="?", default=None, help="results.jsonl written by `obsbench run`")
    p.add_argument(
        "--table",
        default=None,
        help="published table: a CSV (rows = tasks, columns = methods, values = success rates in [0, 1]) or the "
        f"name of one of the paper's tables shipped with the plugin: {', '.join(published_tables())}",
    )
    p.add_argument(
        "--checkpoint",
        default="best",
        choices=CHECKPOINT_CHOICES,
        help="which checkpoint's test "
        "evaluations the tables show: best on the validation seeds (where a run has one) or last",
    )
    p.add_argument("--out", type=Path, default=None, help="report directory (default: next to the results)")
    p.add_argument("--json", type=Path, default=None, help="write mean_sr and mean_rank per method here")
    p.add_argument("--title", default="OBSBench report")
    p.add_argument(
        "--reference",
        default=None,
        help="a column label (as the tables print it): every method's probability of improvement over it is added "
        "beside the one over its blind control",
    )
    p.set_defaults(func=cmd_report)

    p = sub.add_parser(
        "convert-results",
        help="convert a results file written by lerobot-obsbench 0.1 (one record "
        "per run) into train + eval records; checkpoints and evaluations are kept",
    )
    p.add_argument("results", type=Path)
    p.set_defaults(func=cmd_convert)

    p = sub.add_parser(
        "train",
        help="train with stock lerobot-train in the brief's spelling: obsbench train policy=act_pcd "
        "env=obsbench_pickcube [dataset=DIR] [preset=cpu] [policy.field=value ...] [--lerobot.flag=value ...]",
    )
    p.add_argument("--dry-run", action="store_true", help="print the lerobot-train command and stop")
    p.add_argument("items", nargs=argparse.REMAINDER, help="key=value items and --flags passed to lerobot-train")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser(
        "push",
        help="upload a grid run (OUT/runs/<run_id>) or a pretrained_model directory to the Hugging Face Hub, with a "
        "model card: space, encoder, policy, task, dataset, budget, evaluation, install line",
    )
    p.add_argument("path", type=Path, help="OUT/runs/<run_id> of `obsbench run`, or a pretrained_model directory")
    p.add_argument("repo_id", help="ORG/NAME on the Hub")
    p.add_argument(
        "--checkpoint", default="best", choices=("best", "last"), help="for a grid run: which evaluated checkpoint"
    )
    p.add_argument("--eval", type=Path, default=None, help="for a checkpoint directory: an `obsbench eval --out` file")
    p.add_argument("--private", action="store_true")
    p.set_defaults(func=cmd_push)

    p = sub.add_parser("push-dataset", help="upload a LeRobotDataset (e.g. from obsbench demos) to the Hub")
    p.add_argument("root", type=Path, help="dataset directory")
    p.add_argument("repo_id", help="ORG/NAME on the Hub")
    p.add_argument("--private", action="store_true")
    p.set_defaults(func=cmd_push_dataset)

    p = sub.add_parser("find-cameras", help="list connected RealSense cameras (serials) and their calibration")
    p.add_argument(
        "--extrinsics-dir", default=None, help="where calibrate-cameras saved extrinsics (default: LeRobot's)"
    )
    p.set_defaults(func=cmd_find_cameras)

    p = sub.add_parser(
        "calibrate-cameras",
        help="camera -> world extrinsics from a ChArUco board on the table, averaged over several views, saved per "
        "camera serial (the robot records cam2world from it)",
    )
    p.add_argument("--serial", default=None, help="camera serial (obsbench find-cameras)")
    p.add_argument("--playback", default=None, help="a recorded .bag instead of a live camera")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--views", type=int, default=10, help="frames to average")
    p.add_argument("--interval", type=float, default=0.1, help="seconds between views")
    p.add_argument("--min-views", type=int, default=5)
    p.add_argument("--min-corners", type=int, default=12, help="refuse a view with fewer ChArUco corners")
    p.add_argument("--max-reprojection", type=float, default=1.0, help="refuse a view above this RMS error (px)")
    p.add_argument("--squares", type=int, nargs=2, default=(5, 7), metavar=("X", "Y"))
    p.add_argument("--square-length", type=float, default=0.035, help="metres, as printed")
    p.add_argument("--marker-length", type=float, default=0.026, help="metres, as printed")
    p.add_argument("--dictionary", default="DICT_4X4_50")
    p.add_argument(
        "--board-pose",
        type=float,
        nargs=6,
        default=(0, 0, 0, 0, 0, 0),
        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
        help="the board frame's pose in the robot-base frame (metres, degrees); default: the board is the world",
    )
    p.add_argument("--out", default=None, help="extrinsics directory (default: LeRobot's calibration dir)")
    p.add_argument("--print-board", type=Path, default=None, help="write the board image to print, and exit")
    p.set_defaults(func=cmd_calibrate_cameras)

    p = sub.add_parser(
        "view",
        help="see what the policy sees: colour, depth, the fused point cloud before and after the crop, the "
        "workspace box and the world axes, in rerun (an .rrd file when there is no display)",
    )
    p.add_argument("--root", default=None, help="a LeRobotDataset (simulated or real)")
    p.add_argument("--repo-id", default="local/dataset")
    p.add_argument("--frame", type=int, default=0, help="global frame index in the dataset")
    p.add_argument("--serial", nargs="*", default=[], help="live RealSense cameras instead of a dataset")
    p.add_argument("--playback", nargs="*", default=[], help="recorded .bag files instead of a dataset")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--downsample", type=int, default=2)
    p.add_argument("--extrinsics-dir", default=None)
    p.add_argument("--cameras", nargs="*", default=[], help="cameras to fuse (default: all with depth)")
    p.add_argument("--workspace", type=float, nargs=6, default=None, help="crop box (default: the preset's)")
    p.add_argument("--preset", default=None, help="take the crop box from this preset (e.g. real-one-arm)")
    p.add_argument("--voxel-size", type=float, default=0.005)
    p.add_argument("--out", type=Path, default=None, help="save an .rrd file (default without a display)")
    p.add_argument("--ply", type=Path, default=None, help="also write the policy's fused cloud as .ply (Open3D)")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser(
        "refine-cameras",
        help="after calibrate-cameras: align each extra camera's cloud to the first's (Open3D coloured ICP on the "
        "shared table and objects) and save the corrected cam2world; refuses an implausibly large correction",
    )
    p.add_argument("--serial", nargs="*", default=[], help="live cameras; the first is the reference")
    p.add_argument("--playback", nargs="*", default=[], help="recorded .bag files instead (the first: reference)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--downsample", type=int, default=2)
    p.add_argument("--extrinsics-dir", default=None, help="where calibrate-cameras saved them (default: LeRobot's)")
    p.add_argument("--workspace", type=float, nargs=6, default=None, help="the region aligned (default: the preset's)")
    p.add_argument("--preset", default=None, help="take the region from this preset (e.g. real-bimanual)")
    p.add_argument("--max-mm", type=float, default=20.0, help="refuse a correction moving a camera further")
    p.add_argument("--max-deg", type=float, default=2.0, help="refuse a correction turning a camera further")
    p.add_argument("--min-overlap", type=float, default=0.3, help="refuse when less of a cloud meets the reference")
    p.add_argument("--voxel-size", type=float, default=0.005, help="of the --ply cloud")
    p.add_argument("--ply", type=Path, default=None, help="write the fused cloud after the refinement as .ply")
    p.add_argument("--dry-run", action="store_true", help="report the corrections; save nothing")
    p.set_defaults(func=cmd_refine_cameras)

    p = sub.add_parser("preset", help="print the --policy.* overrides of a named preset, to paste into lerobot-train")
    p.add_argument("--preset", default="cpu", choices=tuple(PRESETS))
    p.add_argument("--policy", default=POLICY_TYPES[0], choices=POLICY_TYPES)
    p.add_argument("--obs-space", default="pointcloud", choices=OBS_SPACES)
    p.add_argument("--encoder", default=None, help="the encoder you train with (default: the preset's for the space)")
    p.set_defaults(func=cmd_preset)
    return parser


# Commands configured like LeRobot's own (draccus: --robot.type=..., --teleop.*, --dataset.*), run by their modules.
HARDWARE_COMMANDS = {
    "record": ("lerobot_obsbench.datasets.teleop_recording", "teleoperated demonstrations on a real robot"),
    "rollout": ("lerobot_obsbench.robots.rollout", "run a checkpoint on a real robot, the operator judging"),
}


# What a Ctrl-C keeps, per command (the others write nothing until their work is done).
INTERRUPTED = {
    "run": "every finished unit is kept in the results file (a killed training resumes from its last checkpoint); "
    "run the same command to go on",
    "demos": "the recorded episodes are kept in --out; run the same command to go on",
    "import-rlbench": "the converted episodes are kept in --out; run the same command to go on",
    "import-h5": "the replayed episodes are kept in --out; run the same command to go on",
    "eval": "no result was written (--out is written once every episode is done)",
    "record": "every saved episode is kept in --dataset.root; run the same command to go on",
    "rollout": "the episodes' videos are kept in --out; results.json is written once every episode is judged",
}


def interrupted(command: str) -> int:
    """Ctrl-C: one line saying what was kept; the shell's exit code for a SIGINT."""
    kept = INTERRUPTED.get(command, "nothing is left half-written; run the same command again")
    print(f"\nobsbench {command}: interrupted; {kept}", file=sys.stderr)
    return 130


def hardware_command(name: str, argv: list[str]) -> int:
    """`obsbench record` / `rollout`: LeRobot-style (draccus) commands; their set-up errors in one line."""
    import importlib

    from draccus.utils import DraccusException

    import lerobot_obsbench  # noqa: F401  (registers the robots, cameras and policies)

    try:
        return importlib.import_module(HARDWARE_COMMANDS[name][0]).main(argv)
    # ValueError: LeRobot's device factories wrap what stops them (a missing SDK, a bad port) in one
    except (DraccusException, ObsBenchError, ValueError, FileNotFoundError, PermissionError, FileExistsError) as err:
        print(f"obsbench {name}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return interrupted(name)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in HARDWARE_COMMANDS:
        return hardware_command(argv[0], argv[1:])
    args = build_parser().parse_args(argv)
    import httpx
    from huggingface_hub.errors import HfHubHTTPError, OfflineModeIsEnabled

    import lerobot_obsbench  # noqa: F401  (registers policies and encoders)

    try:
        return args.func(args)
    except ObsBenchError as err:  # raised on purpose, its message naming the field and the fix
        print(f"obsbench {args.command}: error: {err}", file=sys.stderr)
        return 2
    except (PermissionError, FileNotFoundError, FileExistsError) as err:  # a path the user gave: one line
        print(f"obsbench {args.command}: error: {err}", file=sys.stderr)
        return 2
    except (HfHubHTTPError, OfflineModeIsEnabled, httpx.HTTPError) as err:  # the Hub refused, or is unreachable
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        print(
            f"obsbench {args.command}: error: the Hugging Face Hub: {first} (check the network, HF_HUB_OFFLINE and "
            "your token: hf auth login)",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:
        return interrupted(args.command)


if __name__ == "__main__":
    sys.exit(main())
