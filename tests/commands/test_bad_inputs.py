"""Bad inputs a tired researcher gives the CLI, one row each: the command exits 2 with one line that names the
flag or field and the way out, no traceback, before any long work, and every file that was there before is
byte-identical after (nothing lost, nothing half-written).

Each row builds its own inputs in a fresh folder (`setup(root) -> argv`) and names a fragment the error line
must hold."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lerobot_obsbench.cli import main
from tests.commands import bad_inputs_grid, bad_inputs_outputs, bad_inputs_validate
from tests.support import rlbench_fixtures


def _finished_demos(root: Path, **settings) -> Path:
    """What `obsbench demos` leaves in a finished dataset folder (sidecar + LeRobot's meta), with `settings`."""
    out = root / "demos"
    (out / "meta").mkdir(parents=True)
    (out / "meta" / "info.json").write_text('{"codebase_version": "v3.0"}\n')
    info = {"task": "PushCube-v1", "seeds": [100000, 100001], "image_size": 128, "cameras": ["base_camera"]}
    (out / "obsbench_demos.json").write_text(json.dumps({**info, "seed_start": 100000, **settings}) + "\n")
    return out


def demos_over_another_dataset(root: Path) -> list[str]:
    out = root / "recording"
    (out / "meta").mkdir(parents=True)
    (out / "meta" / "info.json").write_text('{"robot_type": "koch"}\n')  # a real recording, say
    (out / "data").mkdir()
    (out / "data" / "episode_0.parquet").write_bytes(b"PAR1 frames")
    return ["demos", "--task", "PushCube-v1", "--episodes", "2", "--out", str(out)]


def demos_with_another_image_size(root: Path) -> list[str]:
    out = _finished_demos(root, image_size=64)
    return ["demos", "--task", "PushCube-v1", "--episodes", "2", "--out", str(out), "--image-size", "128"]


def demos_resuming_another_task(root: Path) -> list[str]:
    out = root / "demos"
    (out / ".episodes").mkdir(parents=True)
    settings = {"task": "PickCube-v1", "image_size": 128, "cameras": ["base_camera"], "seed_start": 100000}
    (out / ".episodes" / "settings.json").write_text(json.dumps(settings) + "\n")
    (out / ".episodes" / "seed_100000.npz").write_bytes(b"an episode")
    return ["demos", "--task", "PushCube-v1", "--episodes", "2", "--out", str(out)]


def demos_below_the_smallest_frame(root: Path) -> list[str]:
    return ["demos", "--task", "PushCube-v1", "--episodes", "2", "--out", str(root / "d"), "--image-size", "16"]


def import_rlbench_over_another_dataset(root: Path) -> list[str]:
    from scripts import make_synthetic_dataset as synthetic

    rlbench_fixtures.write_task(root / "open_drawer", synthetic, "variations", episodes=1, frames=2)
    out = root / "dataset"
    out.mkdir()
    (out / "notes.txt").write_text("my own dataset\n")
    return ["import-rlbench", "--data", str(root / "open_drawer"), "--out", str(out)]


def _rlbench_with_gray_depth(root: Path) -> Path:
    """An RLBench task folder whose first depth PNG is 16-bit grayscale (as other exporters write depth)."""
    import numpy as np
    from PIL import Image

    from scripts import make_synthetic_dataset as synthetic

    rlbench_fixtures.write_task(root / "open_drawer", synthetic, "variations", episodes=1, frames=2)
    (png,) = root.glob("open_drawer/**/front_depth/0.png")
    Image.fromarray(np.full((32, 32), 1200, dtype=np.uint16)).save(png)
    return root / "open_drawer"


def import_rlbench_gray_depth(root: Path) -> list[str]:
    return ["import-rlbench", "--data", str(_rlbench_with_gray_depth(root)), "--out", str(root / "dataset")]


def import_rlbench_gray_depth_strict(root: Path) -> list[str]:
    return [*import_rlbench_gray_depth(root), "--strict"]


def convert_results_twice(root: Path) -> list[str]:
    results = root / "results.jsonl"
    results.write_text(json.dumps({"kind": "train", "run_id": "a"}) + "\n")  # already in the current format
    (root / "results.jsonl.v1").write_text('{"run_id": "a", "evaluations": {}}\n')  # the only copy of the original
    return ["convert-results", str(results)]


def _eval(out: Path) -> list[str]:
    # the policy path is never read: the output is checked first
    return ["eval", "--policy.path", "/nonexistent/pretrained_model", "--env.task", "PushCube-v1", "--out", str(out)]


def eval_out_is_a_directory(root: Path) -> list[str]:
    (root / "results").mkdir()
    return _eval(root / "results")


def eval_out_exists(root: Path) -> list[str]:
    (root / "eval.json").write_text('{"successes": 40}\n')
    return _eval(root / "eval.json")


def eval_out_under_a_file(root: Path) -> list[str]:
    (root / "notes").write_text("a file, not a folder\n")
    return _eval(root / "notes" / "eval.json")


def print_board_unwritable_name(root: Path) -> list[str]:
    return ["calibrate-cameras", "--print-board", str(root / "boards" / "board.unknown")]


def calibrate_out_is_a_file(root: Path) -> list[str]:
    """Refused before the camera (a recording that does not exist here) is opened."""
    (root / "extrinsics").write_text("a file, not a folder\n")
    return ["calibrate-cameras", "--playback", str(root / "board.bag"), "--out", str(root / "extrinsics")]


def view_out_is_a_directory(root: Path) -> list[str]:
    """Refused before the dataset (which does not exist here) is read."""
    (root / "views").mkdir()
    return ["view", "--root", str(root / "dataset"), "--out", str(root / "views")]


def report_out_is_a_file(root: Path) -> list[str]:
    (root / "report").write_text("my notes\n")
    return _results(root, TRAIN, _eval_line(episodes=50, successes=3))


def report_json_over_its_results(root: Path) -> list[str]:
    """Used to replace the results store with the summary (exit 0)."""
    argv = _results(root, TRAIN, _eval_line(episodes=50, successes=3))
    return [*argv, "--json", str(root / "results.jsonl")]


def view_out_over_the_datasets_metadata(root: Path) -> list[str]:
    """Used to overwrite the dataset's own meta/info.json with the viewer's recording (exit 0)."""
    dataset = _finished_demos(root)
    return ["view", "--root", str(dataset), "--out", str(dataset / "meta" / "info.json"), "--overwrite"]


def report_into_a_dataset(root: Path) -> list[str]:
    argv = _results(root, TRAIN, _eval_line(episodes=50, successes=3))
    return [*argv[:-1], str(_finished_demos(root) / "report")]


def view_ply_over_an_existing_file(root: Path) -> list[str]:
    """Used to replace any existing file without being asked."""
    (root / "cloud.ply").write_text("last week's cloud\n")
    return ["view", "--root", str(root / "dataset"), "--ply", str(root / "cloud.ply")]


def _grid(root: Path, text: str) -> list[str]:
    (root / "g.yaml").write_text(text)
    return ["run", str(root / "g.yaml"), "--out", str(root / "out"), "--dry-run"]


def grid_override_against_its_encoder_axis(root: Path) -> list[str]:
    """Used to train PointNet while the results and report said dp3."""
    text = "tasks: [PushCube-v1]\nobs_spaces: [pointcloud]\nencoders: {pointcloud: [dp3]}\nsteps: 5\n"
    return _grid(root, text + "policy_overrides: {encoder: pointnet}\n")


def grid_variant_against_its_learning_rates(root: Path) -> list[str]:
    """Used to be dropped (the learning-rate axis comes later on the command line) while the run id carried it."""
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\nvariants: [{}, {optimizer_lr: 0.5}]\n")


def grid_with_held_out_demos_in_words(root: Path) -> list[str]:
    """Used to pass the checks and fail after the demonstrations were recorded."""
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\nheld_out_demos: ten\n")


def grid_with_negative_held_out_demos(root: Path) -> list[str]:
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\nheld_out_demos: -5\n")


def _view(root: Path, *options: str) -> list[str]:
    return ["view", "--root", str(root / "dataset"), *options]


def view_negative_frame(root: Path) -> list[str]:
    return _view(root, "--frame", "-1")


def _small_dataset(root: Path) -> Path:
    from scripts import make_synthetic_dataset as synthetic

    return synthetic.write_dataset(root / "dataset", episodes=1, frames=3, size=32, seed=0, use_video=False)


def view_a_frame_past_the_end(root: Path) -> list[str]:
    """Used to end in an IndexError traceback."""
    _small_dataset(root)
    return _view(root, "--frame", "3", "--out", str(root / "v.rrd"))


def view_a_camera_typo(root: Path) -> list[str]:
    """Used to end in a KeyError deep in the point-cloud adapter."""
    _small_dataset(root)
    return _view(root, "--cameras", "base_camerra", "--out", str(root / "v.rrd"))


def view_zero_voxel(root: Path) -> list[str]:
    return _view(root, "--voxel-size", "0")


def view_zero_downsample(root: Path) -> list[str]:
    return ["view", "--playback", str(root / "a.bag"), "--downsample", "0"]


def view_inverted_workspace(root: Path) -> list[str]:
    """Used to reach the dataset and end in a traceback."""
    return _view(root, "--workspace", "0.5", "-0.5", "-0.3", "0.3", "0", "0.3")


def refine_cameras_inverted_workspace(root: Path) -> list[str]:
    return ["refine-cameras", "--playback", "a.bag", "b.bag", "--workspace", "0", "0", "-1", "1", "0", "1"]


def eval_videos_into_a_file(root: Path) -> list[str]:
    """Used to be found after every episode had run, when the first video was written."""
    (root / "videos").write_text("a file, not a folder\n")
    return [*_eval(root / "e.json"), "--videos", str(root / "videos")]


def view_a_recording_that_is_not_there(root: Path) -> list[str]:
    """Used to end in librealsense's RuntimeError traceback."""
    return ["view", "--playback", str(root / "missing.bag"), "--out", str(root / "v.rrd")]


def view_a_camera_that_is_not_connected(root: Path) -> list[str]:
    """Used to end in a ConnectionError traceback."""
    return ["view", "--serial", "123456789", "--out", str(root / "v.rrd")]


def eval_on_a_gpu_this_machine_lacks(root: Path) -> list[str]:
    """Used to fail after the policy loaded, in torch."""
    return [*_eval(root / "e.json"), "--policy.device", "cuda:99"]


def eval_on_a_device_that_does_not_exist(root: Path) -> list[str]:
    return [*_eval(root / "e.json"), "--policy.device", "gpu"]


def eval_with_a_negative_episode_length(root: Path) -> list[str]:
    """Used to be found only after the policy and the simulator loaded."""
    return [*_eval(root / "e.json"), "--env.episode_length", "-5"]


def eval_a_checkpoint_with_a_truncated_config(root: Path) -> list[str]:
    """Used to end in a JSONDecodeError traceback."""
    checkpoint = root / "pretrained_model"
    checkpoint.mkdir()
    (checkpoint / "config.json").write_text('{"type": "obs_act", "chunk_si')
    return ["eval", "--policy.path", str(checkpoint), "--env.task", "PushCube-v1"]


def eval_an_oracle_on_another_tasks_objects(root: Path) -> list[str]:
    """Used to be refused for the state size only, never for the objects: the synthetic cube's pose (7 values)
    passed as LiftPegUpright's peg pose."""
    from scripts import make_synthetic_dataset as synthetic
    from tests.support.helpers import training_setup

    dataset = synthetic.write_dataset(
        root / "ds", episodes=2, frames=6, size=32, seed=3, with_goal=False, privileged=True, use_video=False
    )
    policy, pre, post, _ = training_setup("obs_act", "state", dataset)
    for part in (policy, pre, post):
        part.save_pretrained(root / "pretrained_model")
    return ["eval", "--policy.path", str(root / "pretrained_model"), "--env.task", "LiftPegUpright-v1"]


def demos_below_the_first_demonstration_seed(root: Path) -> list[str]:
    """Used to end in a bare ValueError traceback."""
    return ["demos", "--task", "PushCube-v1", "--episodes", "2", "--out", str(root / "d"), "--seed-start", "5"]


def demos_of_a_camera_typo(root: Path) -> list[str]:
    """Used to start the simulator and end in a worker's traceback naming --env.cameras, which demos has not."""
    return ["demos", "--task", "PushCube-v1", "--episodes", "2", "--out", str(root / "d"), "--cameras", "base_camra"]


def grid_override_lerobot_train_cannot_parse(root: Path) -> list[str]:
    """Used to pass the checks (Python takes 0 for a bool) and fail in lerobot-train after the demos."""
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\npolicy_overrides: {use_vae: 0}\n")


def grid_with_a_camera_typo(root: Path) -> list[str]:
    """Used to be found only when the demonstrations started recording."""
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\ncameras: [base_camra]\n")


def grid_of_a_named_policy_type(root: Path) -> list[str]:
    """README's act_pcd in a grid used to be refused as an unknown policy, with no word of what it stands for."""
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [pointcloud]\nsteps: 5\npolicies: [act_pcd]\n")


def run_with_no_workers(root: Path) -> list[str]:
    return ["run", "quick", "--workers", "0", "--dry-run", "--out", str(root / "out")]


def calibrate_cameras_with_no_views(root: Path) -> list[str]:
    return ["calibrate-cameras", "--playback", str(root / "board.bag"), "--views", "0"]


def refine_cameras_with_an_overlap_above_one(root: Path) -> list[str]:
    return ["refine-cameras", "--playback", "a.bag", "b.bag", "--min-overlap", "30"]


def grid_with_a_duplicated_key(root: Path) -> list[str]:
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\nsteps: 50\n")


def grid_with_a_duplicated_seed(root: Path) -> list[str]:
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\nseeds: [1, 1]\n")


def grid_below_the_smallest_frame(root: Path) -> list[str]:
    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\nimage_size: 16\n")


def grid_with_a_task_it_cannot_record(root: Path) -> list[str]:
    return _grid(root, "tasks: [TurnFaucet-v1]\nobs_spaces: [rgb]\nsteps: 5\n")


def _results(root: Path, *lines: str) -> list[str]:
    (root / "results.jsonl").write_text("".join(line + "\n" for line in lines))
    return ["report", str(root / "results.jsonl"), "--out", str(root / "report")]


RUN_CONFIG = {"task": "T", "policy": "act", "obs_space": "rgb", "encoder": "resnet18", "seed": 1, "demos": 10}
TRAIN = json.dumps({"kind": "train", "run_id": "r", "config": {}, "method": "m", "task": "T", "checkpoint": "c"})


def _eval_line(**counts) -> str:
    fields = {"eval_id": "e", "run_id": "r", "checkpoint": "last", "split": "test", "perturbation": "none"}
    return json.dumps({"kind": "eval", **fields, **counts})


def report_with_an_impossible_count(root: Path) -> list[str]:
    return _results(root, TRAIN, _eval_line(episodes=50, successes=1e308))


def report_with_a_negative_rate(root: Path) -> list[str]:
    return _results(root, TRAIN, _eval_line(episodes=50, successes=3, success_rate=-3))


def report_with_a_config_that_is_not_a_mapping(root: Path) -> list[str]:
    """Used to end in an AttributeError traceback."""
    train = json.loads(TRAIN) | {"config": "act/rgb seed 1"}
    return _results(root, json.dumps(train), _eval_line(episodes=50, successes=3))


def report_with_a_training_seed_in_words(root: Path) -> list[str]:
    """Used to end in a KeyError traceback (the run config has no usable seed)."""
    train = json.loads(TRAIN) | {"config": {**RUN_CONFIG, "seed": "one"}}
    return _results(root, json.dumps(train), _eval_line(episodes=50, successes=3))


def report_with_per_seed_outcomes_against_the_count(root: Path) -> list[str]:
    """Used to count 3 successes in the tables and 5 in the camera-moved agreement."""
    per_seed = {"seeds": list(range(5)), "success": "11111", "length": [9] * 5}
    train = json.loads(TRAIN) | {"config": RUN_CONFIG}
    return _results(root, json.dumps(train), _eval_line(episodes=5, successes=3, per_seed=per_seed))


def report_with_lines_that_are_not_records(root: Path) -> list[str]:
    return _results(root, "null", "42")


def rollout_with_a_missing_checkpoint(root: Path) -> list[str]:
    """The port does not exist either: the checkpoint must be refused before the robot is made."""
    return [
        "rollout",
        "--robot.type=obsbench_koch_follower",
        f"--robot.port={root / 'ttyACM0'}",
        f"--policy_path={root / 'outputs' / 'train' / 'pretrained_model'}",
        f"--out={root / 'rollouts'}",
    ]


def rollout_with_a_bad_value(root: Path) -> list[str]:
    return [
        "rollout",
        "--robot.type=obsbench_koch_follower",
        "--robot.port=/dev/ttyACM0",
        "--policy_path=x",
        "--episodes=many",
    ]


def record_one_arm_as_readme_writes_it(root: Path) -> list[str]:
    """README's one-arm pair (obsbench_koch_follower + LeRobot's koch_leader) is accepted; it then stops, in one
    line, at what this machine lacks (the Dynamixel SDK, or the port)."""
    return [
        "record",
        "--robot.type=obsbench_koch_follower",
        f"--robot.port={root / 'ttyACM0'}",
        "--teleop.type=koch_leader",
        f"--teleop.port={root / 'ttyACM1'}",
        f"--dataset.root={root / 'demos'}",
        "--dataset.task=pick up the cube",
    ]


def push_dataset_without_the_hub(root: Path) -> list[str]:
    """Offline (CI), unreachable (here) or refused (no token): one line either way."""
    from scripts import make_synthetic_dataset as synthetic

    dataset = synthetic.write_dataset(root / "ds", episodes=1, frames=4, size=32, seed=0, use_video=False)
    return ["push-dataset", str(dataset), "someone/demos"]


# (row, setup, fragments of the error output)
def attach_calibration_to_a_missing_dataset(root: Path) -> list[str]:
    (root / "front.json").write_text("{}\n")
    return [
        "attach-calibration",
        "--root",
        str(root / "dataset"),
        "--camera",
        "front",
        "--from-json",
        str(root / "front.json"),
    ]


def validate_a_folder_that_is_no_dataset(root: Path) -> list[str]:
    (root / "videos").mkdir()
    return ["validate", "--root", str(root)]


def import_h5_without_its_json(root: Path) -> list[str]:
    (root / "trajectory.h5").write_bytes(b"\x89HDF\r\n")
    return ["import-h5", "--h5", str(root / "trajectory.h5"), "--out", str(root / "out")]


def eval_rlbench_without_the_simulator(root: Path) -> list[str]:
    return ["eval-rlbench", "--policy.path", str(root / "p"), "--task", "open_drawer", "--data", str(root / "d")]


def train_without_a_policy(root: Path) -> list[str]:
    return ["train", "env=obsbench_pickcube", "--dry-run"]


def push_a_folder_that_is_no_run(root: Path) -> list[str]:
    (root / "run").mkdir()
    return ["push", str(root / "run"), "org/name"]


def view_without_a_dataset_or_camera(root: Path) -> list[str]:
    return ["view", "--out", str(root / "frame.rrd")]


def refine_one_camera(root: Path) -> list[str]:
    return ["refine-cameras", "--playback", str(root / "camera0.bag")]


def replay_a_dataset_not_recorded_by_demos(root: Path) -> list[str]:
    out = root / "recording"
    (out / "meta").mkdir(parents=True)
    (out / "meta" / "info.json").write_text('{"robot_type": "koch"}\n')
    return ["replay", "--root", str(out)]


def _demos_with_actions(root: Path, seeds: int = 2, parquet: bytes | None = None) -> Path:
    """A demonstrations folder: the sidecar naming `seeds` seeds, and one data file of two one-step episodes."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = _finished_demos(root, seeds=list(range(100000, 100000 + seeds)))
    (out / "data" / "chunk-000").mkdir(parents=True)
    data = out / "data" / "chunk-000" / "file-000.parquet"
    table = {"action": [[0.0] * 7, [0.0] * 7], "episode_index": [0, 1], "frame_index": [0, 0]}
    pq.write_table(pa.table(table), data)
    if parquet is not None:
        data.write_bytes(data.read_bytes()[: len(parquet)])
    return out


def replay_a_cut_sidecar(root: Path) -> list[str]:
    """Used to end in json's traceback."""
    out = _demos_with_actions(root)
    (out / "obsbench_demos.json").write_text('{"task": "PushCube-v1", "seeds": [1000')
    return ["replay", "--root", str(out)]


def replay_a_cut_data_file(root: Path) -> list[str]:
    """Used to end in pyarrow's traceback."""
    return ["replay", "--root", str(_demos_with_actions(root, parquet=b"PAR1" * 8))]


def replay_more_episodes_than_seeds(root: Path) -> list[str]:
    """Used to end in an IndexError after the simulator started."""
    return ["replay", "--root", str(_demos_with_actions(root, seeds=1))]


def encoders_of_a_typo(root: Path) -> list[str]:
    return ["encoders", "--obs-space", "pointclould"]


def preset_of_a_typo(root: Path) -> list[str]:
    return ["preset", "--preset", "papper"]


def preset_of_another_policys_protocol(root: Path) -> list[str]:
    """Used to print an empty line (pointcloud) or image flags for ACT without saying dp3 is Diffusion Policy's."""
    return ["preset", "--preset", "dp3", "--policy", "obs_act", "--obs-space", "pointcloud"]


def train_with_another_policys_protocol(root: Path) -> list[str]:
    return ["train", "policy=act_pcd", "env=obsbench_pickcube", "preset=dp3", f"dataset.root={root}", "--dry-run"]


def demos_of_a_metaworld_typo(root: Path) -> list[str]:
    return ["demos", "--task", "drawer-opn-v3", "--episodes", "2", "--out", str(root / "drawer")]


def demos_of_a_metaworld_camera_typo(root: Path) -> list[str]:
    return ["demos", "--task", "drawer-open-v3", "--episodes", "2", "--out", str(root / "d"), "--cameras", "wrist"]


ROWS = [
    (demos_of_a_metaworld_typo, ["unknown Meta-World task 'drawer-opn-v3'; did you mean drawer-open-v3"]),
    (demos_of_a_metaworld_camera_typo, ["cameras ['wrist']: drawer-open-v3 has no such camera", "'corner2'"]),
    (demos_over_another_dataset, ["--out", "is not empty (data, meta)", "--overwrite"]),
    (demos_with_another_image_size, ["other settings (image_size 64 there, 128 asked)", "--overwrite"]),
    (demos_resuming_another_task, ["interrupted run", "task 'PickCube-v1' there, 'PushCube-v1' asked"]),
    (demos_below_the_smallest_frame, ["argument --image-size: must be >= 32 pixels"]),
    (import_rlbench_over_another_dataset, ["--out", "is not empty (notes.txt)", "--overwrite"]),
    (import_rlbench_gray_depth, ["none of its 1 episodes could be read"]),
    (import_rlbench_gray_depth_strict, ["front_depth/0.png: a I;16 PNG", "RLBench's depth PNGs are 8-bit RGB"]),
    (convert_results_twice, ["holds no lerobot-obsbench 0.1 records: nothing to convert"]),
    (eval_out_is_a_directory, ["--out", "is a directory; give a file path"]),
    (eval_out_exists, ["--out", "already exists; add --overwrite"]),
    (eval_out_under_a_file, ["notes is a file, so the folder cannot be created"]),
    (print_board_unwritable_name, ["--print-board", "OpenCV could not write it", ".png"]),
    (calibrate_out_is_a_file, ["--out", "extrinsics is a file; give a folder"]),
    (view_out_is_a_directory, ["--out", "views is a directory; give a file path"]),
    (report_out_is_a_file, ["--out", "report is a file; give a folder"]),
    (report_json_over_its_results, ["--json", "would write over this command's input"]),
    (view_out_over_the_datasets_metadata, ["--out", "info.json would write over this command's input"]),
    (report_into_a_dataset, ["--out", "is inside the LeRobot dataset", "write outputs outside datasets"]),
    (view_ply_over_an_existing_file, ["--ply", "cloud.ply already exists; add --overwrite"]),
    (eval_videos_into_a_file, ["--videos", "videos is a file; give a folder"]),
    (view_a_recording_that_is_not_there, ["RealSense recording", "missing.bag not found"]),
    (view_a_camera_that_is_not_connected, ["No RealSense camera with serial '123456789'", "obsbench find-cameras"]),
    (eval_on_a_gpu_this_machine_lacks, ["argument --policy.device: cuda:99:", "give cpu"]),
    (eval_on_a_device_that_does_not_exist, ["argument --policy.device: 'gpu' is not a torch device"]),
    (eval_with_a_negative_episode_length, ["argument --env.episode_length: must be a whole number >= 1, got -5"]),
    (eval_a_checkpoint_with_a_truncated_config, ["config.json cannot be read", "the checkpoint is damaged"]),
    (eval_an_oracle_on_another_tasks_objects, ["trained on the poses of ['cube'] but this task gives the poses of"]),
    (demos_below_the_first_demonstration_seed, ["argument --seed-start: must be a whole number >= 100000, got 5"]),
    (demos_of_a_camera_typo, ["cameras ['base_camra']: PushCube-v1 has no such camera", "['base_camera']"]),
    (grid_override_lerobot_train_cannot_parse, ["{'use_vae': 0}", "Couldn't parse '0' into a bool"]),
    (grid_with_a_camera_typo, ["cameras ['base_camra']: PushCube-v1 has no such camera"]),
    (
        grid_of_a_named_policy_type,
        ["policies: [obs_act], obs_spaces: [pointcloud], encoders: {pointcloud: [pointnet]}"],
    ),
    (run_with_no_workers, ["argument --workers: must be a whole number >= 1, got 0"]),
    (calibrate_cameras_with_no_views, ["argument --views: must be a whole number >= 1, got 0"]),
    (
        refine_cameras_with_an_overlap_above_one,
        ["argument --min-overlap: must be a finite number > 0 and <= 1, got 30"],
    ),
    (grid_with_a_duplicated_key, ["'steps' is given twice (lines 3 and 4)"]),
    (grid_with_held_out_demos_in_words, ["held_out_demos", "whole number"]),
    (grid_with_negative_held_out_demos, ["held_out_demos", ">= 0"]),
    (view_negative_frame, ["--frame", "must be a whole number >= 0, got -1"]),
    (view_a_frame_past_the_end, ["--frame 3 is outside the dataset's 3 frames (0..2)"]),
    (view_a_camera_typo, ["--cameras base_camerra: not a camera with depth here", "['base_camera']"]),
    (view_zero_voxel, ["--voxel-size", "must be a finite number > 0, got 0"]),
    (view_zero_downsample, ["--downsample", "must be a whole number >= 1, got 0"]),
    (view_inverted_workspace, ["--workspace 0.5 -0.5 -0.3 0.3 0 0.3", "each min below its max"]),
    (refine_cameras_inverted_workspace, ["--workspace 0 0 -1 1 0 1", "each min below its max"]),
    (grid_override_against_its_encoder_axis, ["policy_overrides sets --policy.encoder", "through encoders"]),
    (grid_variant_against_its_learning_rates, ["variants sets --policy.optimizer_lr", "through learning_rates"]),
    (grid_with_a_duplicated_seed, ["seeds lists 1 more than once"]),
    (grid_below_the_smallest_frame, ["image_size must be a whole number >= 32; got 16"]),
    (grid_with_a_task_it_cannot_record, ["TurnFaucet-v1 has no scripted expert", "obsbench import-h5", "assets"]),
    (report_with_an_impossible_count, ["results.jsonl:2", "successes = 1e+308 is not a whole number in 0..50"]),
    (report_with_a_negative_rate, ["results.jsonl:2", "success_rate = -3 is not a finite number in [0, 1]"]),
    (report_with_a_config_that_is_not_a_mapping, ["results.jsonl:1", 'config = "act/rgb seed 1" is not a mapping']),
    (report_with_a_training_seed_in_words, ["results.jsonl:1", 'config.seed = "one" is not a whole number']),
    (
        report_with_per_seed_outcomes_against_the_count,
        ["results.jsonl:2", "per_seed holds 5 successes where successes = 3"],
    ),
    (report_with_lines_that_are_not_records, ["results.jsonl:1", "null, not a record", "results.jsonl:2"]),
    (rollout_with_a_missing_checkpoint, ["obsbench rollout: error:", "pretrained_model"]),
    (rollout_with_a_bad_value, ["obsbench rollout: error:", "episodes"]),
    (push_dataset_without_the_hub, ["obsbench push-dataset: error: the Hugging Face Hub:", "HF_HUB_OFFLINE"]),
    (record_one_arm_as_readme_writes_it, ["obsbench record: error:", "KochRGBDFollowerConfig"]),
    (attach_calibration_to_a_missing_dataset, ["obsbench attach-calibration: error:", "dataset"]),
    (validate_a_folder_that_is_no_dataset, ["obsbench validate: error:", "is not a LeRobot dataset"]),
    (import_h5_without_its_json, ["obsbench import-h5: error:", "trajectory.json not found"]),
    (eval_rlbench_without_the_simulator, ["obsbench eval-rlbench: error:", "COPPELIASIM_ROOT"]),
    (train_without_a_policy, ["obsbench train: error: give policy=TYPE and env=TYPE"]),
    (push_a_folder_that_is_no_run, ["obsbench push: error:", "is neither a grid run"]),
    (view_without_a_dataset_or_camera, ["obsbench view: error: give --root DATASET, or --serial SERIAL"]),
    (refine_one_camera, ["obsbench refine-cameras: error: give two or more cameras"]),
    (replay_a_dataset_not_recorded_by_demos, ["obsbench replay: error:", "no obsbench_demos.json", "obsbench demos"]),
    (replay_a_cut_sidecar, ["obsbench_demos.json: cannot be read as JSON", "record the demonstrations again"]),
    (replay_a_cut_data_file, ["file-000.parquet: cannot be read as a LeRobot data file", "obsbench demos"]),
    (replay_more_episodes_than_seeds, ["names 1 seeds for 2 recorded episodes", "record the demonstrations again"]),
    (encoders_of_a_typo, ["argument --obs-space: invalid choice: 'pointclould'"]),
    (preset_of_a_typo, ["argument --preset: invalid choice: 'papper'"]),
    (
        preset_of_another_policys_protocol,
        ["preset dp3 is 3D Diffusion Policy's protocol", "use --policy obs_diffusion"],
    ),
    (train_with_another_policys_protocol, ["preset dp3 is 3D Diffusion Policy's protocol", "describes no obs_act"]),
    *bad_inputs_validate.ROWS,
    *bad_inputs_outputs.ROWS,
    *bad_inputs_grid.ROWS,
]
# Commands whose failure is not one error line: `doctor` reports every check it ran (exit 2 when one fails),
# `find-cameras` lists what it finds (none is an answer, not an error); both are covered below.
REPORTING_COMMANDS = {"doctor", "find-cameras"}


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("setup, fragments", ROWS, ids=[row.__name__ for row, _ in ROWS])
def test_bad_input_is_refused_in_one_line_and_keeps_every_file(tmp_path, capsys, setup, fragments):
    argv = setup(tmp_path)
    before = _snapshot(tmp_path)
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse's own refusals (a flag's type)
        code = stop.code
    assert code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    errors = [line for line in err.splitlines() if "error:" in line]
    assert len(errors) == 1, err  # one line says what is wrong
    for fragment in fragments:
        assert fragment in err, err
    after = _snapshot(tmp_path)
    assert {name: after.get(name) for name in before} == before  # nothing there before was changed or removed


def test_overwrite_replaces_what_was_refused(tmp_path, capsys):
    """The choice the refusal names works: --overwrite on an existing eval result is let through (the run then
    fails later on the missing policy, not on the output)."""
    argv = eval_out_exists(tmp_path)
    assert main([*argv, "--overwrite"]) != 0
    assert "already exists" not in capsys.readouterr().err


def test_import_rlbench_skips_unreadable_episodes_and_lists_them(tmp_path, capsys):
    """One unreadable episode (its pickle missing, another's depth PNG garbage) does not stop the import: the
    others are imported and the skipped ones listed; --strict stops at the first."""
    from scripts import make_synthetic_dataset as synthetic

    rlbench_fixtures.write_task(tmp_path / "open_drawer", synthetic, "variations", episodes=3, frames=2)
    first, second, third = sorted(tmp_path.glob("open_drawer/**/episodes/episode*"))
    (first / "low_dim_obs.pkl").unlink()
    (second / "front_depth" / "0.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    args = ["import-rlbench", "--data", str(tmp_path / "open_drawer")]
    assert main([*args, "--out", str(tmp_path / "strict"), "--strict"]) == 2
    assert "low_dim_obs.pkl missing" in capsys.readouterr().err
    assert main([*args, "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "1 open_drawer episodes imported" in out and "2 unreadable episodes skipped" in out
    info = json.loads((tmp_path / "out" / "obsbench_import.json").read_text())
    assert [e["path"] for e in info["episodes"]] == [str(third)]
    assert {s["path"] for s in info["skipped"]} == {str(first), str(second)}


def test_print_board_into_a_new_folder_writes_the_board(tmp_path, capsys):
    """`--print-board missing/dir/board.png` used to report success and write nothing."""
    import cv2

    board = tmp_path / "missing" / "dir" / "board.png"
    assert main(["calibrate-cameras", "--print-board", str(board)]) == 0
    image = cv2.imread(str(board))
    assert image is not None and image.shape[0] > 100 and "print at 100 %" in capsys.readouterr().out


def test_every_command_has_an_error_path_here(tmp_path):
    """A new command without a row above fails this test: each is run with a bad input at least once."""
    import argparse

    from lerobot_obsbench.cli import build_parser

    subparsers = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    folders = {setup: tmp_path / setup.__name__ for setup, _ in ROWS}
    for folder in folders.values():
        folder.mkdir()
    covered = {setup(folder)[0] for setup, folder in folders.items()}
    assert set(subparsers.choices) == covered | REPORTING_COMMANDS


def test_doctor_and_find_cameras_report_without_a_traceback(tmp_path, capsys):
    import subprocess
    import sys

    # its own process: the asset folder is read when ManiSkill is first imported
    doctor = subprocess.run(
        [str(Path(sys.executable).parent / "obsbench"), "doctor", "--asset-dir", str(tmp_path / "no-assets")],
        capture_output=True,
        text=True,
        timeout=600,
        stdin=subprocess.DEVNULL,
    )
    assert doctor.returncode == 2  # TurnFaucet's assets are missing
    assert "TurnFaucet-v1 needs ManiSkill assets" in doctor.stdout and "Traceback" not in doctor.stdout + doctor.stderr
    assert main(["find-cameras"]) == 0
    out = capsys.readouterr()
    assert "no RealSense camera found" in out.out and "Traceback" not in out.out + out.err


def _hints() -> list[tuple[str, str]]:
    """Every `obsbench COMMAND ...` the package's strings hold (messages, help, docstrings), as (file, text): f-string
    fields become X, a `(A | B)` choice its first alternative, and the command ends where the prose does."""
    import ast
    import re

    import lerobot_obsbench

    package = Path(lerobot_obsbench.__file__).parent
    hints = []
    for path in sorted(package.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.JoinedStr):
                text = "".join(v.value if isinstance(v, ast.Constant) else "X" for v in node.values)
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                text = node.value
            else:
                continue
            text = re.sub(r"\(([^()|]*?)\s*\|[^()]*\)", r"\1", text.replace("\\\n", " "))
            for match in re.finditer(r"(?<![\w.])obsbench ([a-z][a-z0-9-]*)((?: +[^\s;,`()'\"]+)*)", text):
                words = match.group(2).split()
                while words and (words[-1].endswith(".") and not words[-1].startswith("-") or not words[-1]):
                    words.pop()  # the sentence's full stop
                hints.append((path.name, " ".join([match.group(1), *words])))
    return sorted(set(hints))


def test_every_command_the_package_prints_parses_as_printed():
    """A hint such as `obsbench attach-calibration DATASET --camera front` (the command takes --root DATASET) used to
    fail when run as printed: every command the package's messages and help name is parsed by its own parser, with
    each placeholder as a value. Options it does not have and stray positionals fail; a missing required option
    does not (a hint may name one option of several)."""
    import contextlib
    import io
    import re

    from lerobot_obsbench.cli import build_parser
    from lerobot_obsbench.commands import common

    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    for command in commands.values():  # a hint may name one option of several required ones
        for action in command._actions:
            action.required = False
        for group in command._mutually_exclusive_groups:
            group.required = False
    hints = _hints()
    assert any(text.startswith("attach-calibration --root") for _, text in hints)  # the scan finds the hints
    wrong = []
    for where, text in hints:
        words = [word.split("|")[0] for word in text.split()]  # a|b: a choice of values
        if words[0] not in commands:
            if words[0] not in ("import", "with"):  # Python's `from lerobot_obsbench import`, prose
                wrong.append(f"{where}: obsbench {text}: no such command")
            continue
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.suppress(SystemExit):
            common.parse(parser, words)
        refused = [line for line in err.getvalue().splitlines() if "error:" in line]
        mention = refused and refused[0].endswith(f"argument {words[-1]}: expected one argument")  # names an option
        placeholder = refused and re.search(r"got '[A-Z_]+'$", refused[0])  # a typed option's placeholder value
        if refused and not mention and not placeholder:
            wrong.append(f"{where}: obsbench {text}: {refused[0]}")
    assert not wrong, "\n".join(wrong)
