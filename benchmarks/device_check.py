"""The device check: what a GPU machine runs of this project, in one command that writes one JSON.

    python -m benchmarks.device_check --device cuda --checkpoint DIR --out DIR [--budget-s 420] [--overwrite]
    .venv/bin/python -m benchmarks.device_check --device cpu --tiny --checkpoint DIR --out DIR   # the same, tiny

Stages, in this order (the most wanted first), each timed and recorded on its own: a stage that fails is recorded
with its error and traceback and the next one runs; `device_check.json` is rewritten whole after every stage, so a
run stopped by its time limit keeps what it finished; a stage other than `machine` and `imports` (which always run)
that would start after `--budget-s` is skipped, saying so. The options and `--out` are checked before any stage:
`--out` is a folder, and a `device_check.json` already in it is replaced only when the check wrote it for the same
device, task and checkpoint, or with `--overwrite` (lerobot_obsbench/outputs.py's rule); `device_check.log` is
appended to.

- `machine`: the card, its driver, torch, the Vulkan driver SAPIEN finds, the versions of what the bundle carries;
- `imports`: every module the check uses (`MODULES`; scripts/device_bundle.py carries what they need);
- `device_tensors`: one ManiSkill frame of the task through the schema conversion (depth as uint16), LeRobot's
  observation preprocessing and the checkpoint's policy, on the device and on the CPU: the devices and dtypes it
  passed through, the action difference and the time per action;
- `gpu_simulation`: ManiSkill's GPU simulation (physx_cuda) of the task at N = 1, 16, 64, 256 envs with the task
  camera at 64² and 128², colour + depth rendered: env steps/s with random actions, and with the checkpoint in the
  loop (one wave of N episodes, env start included);
- `success`: the checkpoint's success on the first 64 test seeds under each simulation backend that runs (the GPU
  simulation in one wave; the CPU simulation in lockstep over worker processes, rendering on the device), with
  95% intervals and per-seed outcomes (the backends differ seed for seed: docs/simulation.md);
- `cpu_simulation`: ManiSkill's CPU simulation, one env per worker process rendering on the device, at N workers:
  env steps/s with random actions;
- `train_step`: the training step (forward, backward, optimizer) of the paper preset's space × encoder pairs
  (paper-main's encoders at the paper's batches) and of every run of the quick and recipes grids (the latter with
  its augmentations), steps/s and peak memory
  (benchmarks/bench_train_step.py);
- `preprocess`: unproject → crop → voxel → FPS → kNN per frame (benchmarks/bench_preprocess.py).

`--tiny` runs every stage at the smallest sizes (what the CPU test runs, so that what breaks on the GPU is the GPU,
not this script). docs/performance.md#the-device-check says how the GPU machine gets what it lacks and what the
last run measured.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import math
import os
import subprocess
import sys
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

from benchmarks.portable import portable

TASK = "PushCubeWide-v1"  # the quick grid's task
# Everything the stages import: the bundle builder (scripts/device_bundle.py) carries the distributions these need
# that the GPU machine's image lacks.
MODULES = (
    "lerobot_obsbench.policies",
    "lerobot_obsbench.policies.loading",
    "lerobot_obsbench.envs.evaluate",
    "lerobot_obsbench.envs.maniskill",
    "lerobot_obsbench.envs.vector",
    "lerobot_obsbench.bench.grid",
    "benchmarks.bench_train_step",
    "benchmarks.bench_preprocess",
    "benchmarks.bench_eval",
)
# The stages, in the order they run (the most wanted first).
STAGES = (
    "machine",
    "imports",
    "device_tensors",
    "gpu_simulation",
    "success",
    "cpu_simulation",
    "train_step",
    "preprocess",
)
NEED_CHECKPOINT = ("device_tensors", "success")
# The stages that run whatever --stages and --budget-s say: what the machine is and whether the check imports.
ALWAYS_RUN = ("machine", "imports")
RESULT = "device_check.json"
# lerobot_obsbench/outputs.py's record of which command wrote which file of a folder, read and written here in its
# format: the check's options are checked before the plugin is imported, which its imports stage reports on.
OUTPUTS_RECORD = ".obsbench_outputs.json"
# Where the NVIDIA driver of container GPU nodes (NVIDIA's container toolkit) keeps its Vulkan ICD when
# /usr/share/vulkan has none.
NVIDIA_VULKAN_ICD = Path("/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json")


@dataclass(frozen=True)
class Sizes:
    """How much each stage runs."""

    image_sizes: tuple[int, ...]  # task camera sizes of the simulation stages
    gpu_envs: tuple[int, ...]  # N of the GPU simulation
    cpu_workers: tuple[int, ...]  # N of the CPU simulation (worker processes)
    sim_steps: int  # random-action steps per env and measurement
    success_episodes: int  # test seeds of the success stage
    success_cpu_workers: int  # lockstep workers of its CPU simulation
    train_preset: str  # bench_train_step's preset
    train_pairs: tuple | None  # its (space, encoder) pairs; None: all of the preset's
    train_batch: int | None  # None: the paper's batches
    train_image_size: int
    train_repeats: int
    preprocess_batch: int
    preprocess_size: int


FULL = Sizes((64, 128), (1, 16, 64, 256), (1, 16), 50, 64, 16, "paper", None, None, 128, 5, 32, 128)
# one image and one point encoder; 64²: the smallest image LeRobot's stock Diffusion ResNet-18 builds at (its batch-1
# shape probe needs 2x2 maps)
TINY = Sizes((64,), (1, 2), (1,), 3, 2, 2, "cpu", (("rgb", "resnet18"), ("pointcloud", "pointnet")), 2, 64, 1, 2, 32)


def use_nvidia_vulkan_icd() -> str | None:
    """Point the Vulkan loader at the NVIDIA driver's ICD where the system's ICD folder has none (before SAPIEN is
    imported, so worker processes inherit it); the ICD file used, if any."""
    for name in ("VK_ICD_FILENAMES", "VK_DRIVER_FILES"):
        if os.environ.get(name):
            return os.environ[name]
    if Path("/usr/share/vulkan/icd.d/nvidia_icd.json").is_file():
        return "/usr/share/vulkan/icd.d/nvidia_icd.json"
    if NVIDIA_VULKAN_ICD.is_file():
        os.environ["VK_ICD_FILENAMES"] = os.environ["VK_DRIVER_FILES"] = str(NVIDIA_VULKAN_ICD)
        return str(NVIDIA_VULKAN_ICD)
    return None


def budget_seconds(text: str) -> float:
    """--budget-s read as lerobot_obsbench.numeric.number_argument(above=0) reads it (a finite number > 0), written
    out here because the check must start, and report, where the plugin does not import."""
    wanted = "a finite number > 0"
    try:
        value = float(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be {wanted}, got {text}")
    return value


def made_by(device: str, task: str, checkpoint: Path | None) -> dict:
    """What a device_check.json holds, as the folder's output record keeps it: a check of the same device, task and
    checkpoint may replace it, any other needs --overwrite."""
    return {
        "writer": "benchmarks.device_check",
        "device": device,
        "task": task,
        "checkpoint": str(checkpoint.expanduser().resolve()) if checkpoint else None,
    }


def out_folder_problem(out: Path, checkpoint: Path | None, writer: dict, overwrite: bool) -> str | None:
    """Why the check may not write into `out` (None when it may), decided as lerobot_obsbench/outputs.py's
    `check_output_folder` decides for a command's output folder holding `RESULT`."""
    if out.exists() and not out.is_dir():
        return f"--out {out} is a file; give a folder"
    if checkpoint is not None:
        resolved, source = out.expanduser().resolve(), checkpoint.expanduser().resolve()
        if resolved == source or source in resolved.parents:
            return f"--out {out} would write over this command's input {checkpoint}; give a path outside it"
    folder = out
    while not folder.exists():  # the nearest existing folder decides whether the rest can be created
        folder = folder.parent
    if not folder.is_dir():
        return f"--out {out}: {folder} is a file, so the folder cannot be created"
    if not os.access(folder, os.W_OK):
        return f"--out {out}: the folder {folder} is not writable; give another path"
    if (out / RESULT).exists() and not overwrite and not is_own_output(out / RESULT, writer):
        return (
            f"--out {out} already holds {RESULT}, not this command's own output of the same inputs; add "
            "--overwrite to replace what is there, or give another folder"
        )
    return None


def _recorded(folder: Path) -> dict:
    """The folder's output record ({} when there is none or it cannot be read: nothing is then the check's own)."""
    try:
        record = json.loads((folder / OUTPUTS_RECORD).read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    files = record.get("files") if isinstance(record, dict) else None
    return files if isinstance(files, dict) else {}


def _sha256(path: Path) -> str:
    with open(path, "rb") as stream:
        return hashlib.file_digest(stream, "sha256").hexdigest()


def is_own_output(path: Path, writer: dict) -> bool:
    """Whether `path` is a file that `writer` wrote and that still holds what it wrote."""
    return path.is_file() and _recorded(path.parent).get(path.name) == {**writer, "sha256": _sha256(path)}


def _write_text_atomic(path: Path, text: str) -> None:
    """`text` written through a temporary file renamed into place: a check stopped mid-write leaves a whole file."""
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


def write_result(out: Path, result: dict, writer: dict) -> None:
    """The check's JSON written whole into `out`, and noted in the folder's output record as `writer`'s."""
    _write_text_atomic(out / RESULT, json.dumps(portable(result), indent=2) + "\n")
    record = {**_recorded(out), RESULT: {**writer, "sha256": _sha256(out / RESULT)}}
    _write_text_atomic(out / OUTPUTS_RECORD, json.dumps({"files": record}, indent=1, sort_keys=True) + "\n")


def import_modules() -> None:
    from lerobot_obsbench.envs.maniskill import import_maniskill

    for module in MODULES:
        importlib.import_module(module)
    import_maniskill()


def describe(value) -> str:
    """dtype and device of a tensor, or the type of anything else."""
    import torch

    return f"{value.dtype} on {value.device}" if torch.is_tensor(value) else type(value).__name__


class DeviceCheck:
    def __init__(self, device: str, task: str, checkpoint: Path | None, out: Path, sizes: Sizes, budget_s: float):
        self.device, self.task, self.checkpoint, self.out, self.sizes = device, task, checkpoint, out, sizes
        self.started, self.budget_s = time.time(), budget_s
        self.writer = made_by(device, task, checkpoint)
        self.result = {
            "benchmark": "device_check",
            "device": device,
            "task": task,
            "checkpoint": str(checkpoint) if checkpoint else None,
            "sizes": asdict(sizes),
            "budget_s": budget_s,
            "stages": {},
        }

    def run(self, name: str, stage, needs_checkpoint: bool = False) -> None:
        elapsed = time.time() - self.started
        if name not in ALWAYS_RUN and elapsed > self.budget_s:
            record = {"ok": False, "skipped": f"the budget of {self.budget_s:g} s was spent ({elapsed:.0f} s)"}
        elif needs_checkpoint and self.checkpoint is None:
            record = {"ok": False, "skipped": "no --checkpoint given"}
        else:
            print(f"== {name} ({elapsed:.0f} s)", flush=True)
            begin = time.time()
            try:
                record = {"ok": True, **stage()}
            except Exception as err:  # recorded, and the next stage runs: the check is a report, not a test
                record = {"ok": False, "error": f"{type(err).__name__}: {err}", "traceback": traceback.format_exc()}
                print(record["traceback"], flush=True)
            record["seconds"] = round(time.time() - begin, 1)
        self.result["stages"][name] = record
        self.result["seconds"] = round(time.time() - self.started, 1)
        write_result(self.out, self.result, self.writer)

    # ---- stages ------------------------------------------------------------------------------------------------

    def machine(self) -> dict:
        import importlib.metadata as metadata

        import torch

        from benchmarks.common import machine

        smi = (
            subprocess.run(
                ["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
                capture_output=True,
                text=True,
            )
            if self.device.startswith("cuda")
            else None
        )
        versions = {}
        for name in ("torch", "numpy", "lerobot", "mani_skill", "sapien", "gymnasium", "diffusers", "spconv-cu126"):
            try:
                versions[name] = metadata.version(name)
            except metadata.PackageNotFoundError:
                versions[name] = None
        return {
            **machine(),
            "nvidia_smi": smi.stdout.strip() if smi else None,
            "cuda_available": torch.cuda.is_available(),
            "vulkan_icd": use_nvidia_vulkan_icd(),
            "versions": versions,
        }

    def imports(self) -> dict:
        begin = time.time()
        import_modules()
        return {"modules": list(MODULES), "import_s": round(time.time() - begin, 1)}

    def env_kwargs(self, image_size: int) -> dict:
        return dict(task=self.task, cameras=["base_camera"], image_size=image_size, device=self.device)

    def device_tensors(self) -> dict:
        import torch

        from lerobot_obsbench.envs.evaluate import policy_observation
        from lerobot_obsbench.envs.maniskill import ObsBenchEnv
        from lerobot_obsbench.policies.loading import load_policy
        from lerobot_obsbench.schema import depth_key

        env = ObsBenchEnv(**self.env_kwargs(self.checkpoint_size()))
        try:
            env.reset(seed=0)
            raw = env.raw_observation()
            out = {"simulator_depth": describe(raw["sensor_data"]["base_camera"]["depth"])}
            actions = {}
            for device in dict.fromkeys(["cpu", self.device]):
                frames = env.schema_frames(_to(raw, device))
                policy, pre, post = load_policy(self.checkpoint, device)
                batch = pre(policy_observation(env.to_env_observation(frames)))
                policy.reset()
                with torch.inference_mode():
                    post(policy.select_action(batch))  # warm-up (CUDA kernels, cudnn choices)
                    policy.reset()
                    begin = time.perf_counter()
                    actions[device] = post(policy.select_action(batch)).float().cpu()
                    if device.startswith("cuda"):
                        torch.cuda.synchronize()
                out[device] = {
                    "schema_depth": describe(frames[depth_key("base_camera")]),
                    "policy_batch_depth": describe(batch["observation.robot_state"]["depth.base_camera"]),
                    "action_ms": round((time.perf_counter() - begin) * 1000, 2),
                }
            out["max_abs_action_difference"] = float((actions[self.device] - actions["cpu"]).abs().max())
        finally:
            env.close()
        return out

    def gpu_simulation(self) -> dict:
        from lerobot_obsbench.envs.maniskill import physx_gpu_library

        if not self.device.startswith("cuda"):
            return {"ran": False, "why": "ManiSkill's GPU simulation needs a CUDA device"}
        library = physx_gpu_library()
        if not library.is_file():
            return {
                "ran": False,
                "why": (
                    f"SAPIEN's GPU PhysX library is not at {library}: SAPIEN downloads it from GitHub "
                    "(sapien-sim/physx-precompiled) at the first GPU simulation, and this machine reaches no network. "
                    "scripts/device_bundle.py carries it where the machine that builds the bundle has it."
                ),
                "download_attempt": _enable_gpu_attempt(),
            }
        rows = []
        for image_size in self.sizes.image_sizes:
            for n in self.sizes.gpu_envs:
                rows.append(self.sim_rate(image_size, n, "physx_cuda"))
                if self.checkpoint is not None and image_size == self.checkpoint_size():
                    rows[-1]["with_policy"] = self.with_policy(n, n, "physx_cuda")
        return {"ran": True, "rows": rows}

    def cpu_simulation(self) -> dict:
        rows = []
        for image_size in self.sizes.image_sizes:
            for n in self.sizes.cpu_workers:
                rows.append(self.sim_rate(image_size, n, "physx_cpu"))
        out = {"rows": rows}
        if self.checkpoint is not None:  # one env at a time with the policy (the success stage has it at its N)
            out["with_policy_one_env"] = self.with_policy(self.sizes.success_cpu_workers // 2, 1, "physx_cpu")
        return out

    def success(self) -> dict:
        from lerobot_obsbench.envs.maniskill import physx_gpu_library

        episodes = self.sizes.success_episodes
        runs = {"physx_cpu": self.with_policy(episodes, self.sizes.success_cpu_workers, "physx_cpu")}
        if self.device.startswith("cuda") and physx_gpu_library().is_file():
            runs["physx_cuda"] = self.with_policy(episodes, episodes, "physx_cuda")
        return runs

    def train_step(self) -> dict:
        import torch

        from benchmarks.bench_train_step import PAPER_BATCH, grid_rows, prepare, preset_rows

        device = torch.device(self.device)
        prepare(device)
        sizes = self.sizes
        batches = {kind: sizes.train_batch or batch for kind, batch in PAPER_BATCH.items()}
        pairs = list(sizes.train_pairs) if sizes.train_pairs else None
        rows, skipped = preset_rows(
            sizes.train_preset, device, sizes.train_image_size, batches, sizes.train_repeats, pairs
        )
        return {
            "preset": sizes.train_preset,
            "batch": batches,
            "image_size": sizes.train_image_size,
            "rows": rows,
            "skipped": skipped,
            "quick_grid": grid_rows("quick", device, sizes.train_repeats),
            "recipes_grid": grid_rows("recipes", device, sizes.train_repeats),
        }

    def preprocess(self) -> dict:
        import torch

        from benchmarks.bench_preprocess import measure

        return measure(torch.device(self.device), self.sizes.preprocess_batch, self.sizes.preprocess_size, 1)

    # ---- measurements ------------------------------------------------------------------------------------------

    def checkpoint_size(self) -> int:
        """The checkpoint's camera size (one that reads no camera: the first simulated size)."""
        resolution = json.loads((self.checkpoint / "config.json").read_text()).get("camera_resolution")
        return resolution[0] if resolution else self.sizes.image_sizes[0]

    def sim_rate(self, image_size: int, n: int, sim_backend: str) -> dict:
        from benchmarks.bench_eval import env_steps_per_second

        row = env_steps_per_second(self.env_kwargs(image_size), n, self.sizes.sim_steps, sim_backend)
        row["image_size"] = image_size
        print(f"{sim_backend} {image_size}² N={n}: {row}", flush=True)
        return row

    def with_policy(self, episodes: int, batch_size: int, sim_backend: str) -> dict:
        """The checkpoint on the first `episodes` test seeds, `batch_size` at a time, on `sim_backend`."""
        from lerobot_obsbench.envs.evaluate import evaluate

        result = evaluate(
            self.checkpoint,
            self.task,
            episodes,
            device=self.device,
            progress=False,
            batch_size=batch_size,
            sim_backend=sim_backend,
        )
        steps = int(sum(result["per_seed"]["length"]))
        row = {
            key: result[key]
            for key in ("episodes", "successes", "success_rate", "ci95", "batch_size", "sim_backend", "wall_s")
        }
        row.update(
            env_steps=steps,
            env_steps_per_s=round(steps / max(result["wall_s"], 1e-9), 1),
            episodes_per_min=round(60 * episodes / max(result["wall_s"], 1e-9), 1),
            per_seed=result["per_seed"]["success"],
            lengths=result["per_seed"]["length"],
        )
        print(
            f"{sim_backend} N={batch_size}: {row['successes']}/{episodes}, {row['env_steps_per_s']} env steps/s",
            flush=True,
        )
        return row


def _to(tree, device: str):
    """A ManiSkill observation (nested dicts of tensors) with every tensor moved to `device`."""
    import torch

    if isinstance(tree, dict):
        return {key: _to(value, device) for key, value in tree.items()}
    return tree.to(device) if torch.is_tensor(tree) else tree


def _enable_gpu_attempt(timeout_s: float = 30.0) -> dict:
    """SAPIEN's own GPU PhysX start-up in a child process (its download has no time limit of its own): how it
    ended."""
    code = "import sapien.physx; sapien.physx.enable_gpu(); print('enabled')"
    try:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return {"returncode": None, "output": f"no answer within {timeout_s:.0f} s"}
    return {"returncode": done.returncode, "output": (done.stdout + done.stderr).strip()[-1500:]}


class _Tee:
    """Everything printed goes to the terminal and to the log file."""

    def __init__(self, stream, log):
        self.stream, self.log = stream, log

    def write(self, text):
        self.log.write(text)
        self.log.flush()
        return self.stream.write(text)

    def flush(self):
        self.stream.flush()

    def __getattr__(self, name):
        return getattr(self.stream, name)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda", help="cuda (the check's purpose) or cpu")
    parser.add_argument("--task", default=TASK, help="the simulated task (default: the quick grid's)")
    parser.add_argument("--checkpoint", type=Path, help="a pretrained_model directory trained on --task")
    parser.add_argument(
        "--out",
        type=Path,
        required=True,
        help=f"folder for {RESULT} (replaced only when a check of the same device, task and checkpoint wrote it, or "
        "with --overwrite) and device_check.log (appended to)",
    )
    parser.add_argument("--overwrite", action="store_true", help=f"replace a {RESULT} in --out that another wrote")
    parser.add_argument(
        "--budget-s",
        type=budget_seconds,
        default=420.0,
        help="start no stage but machine and imports after this many seconds (a finite number > 0)",
    )
    parser.add_argument("--tiny", action="store_true", help="the smallest sizes (the CPU test)")
    parser.add_argument("--stages", nargs="+", help="run only these stages (machine and imports always run)")
    args = parser.parse_args(argv)
    if args.checkpoint is not None and not (args.checkpoint / "config.json").is_file():
        parser.error(f"--checkpoint {args.checkpoint}: no config.json there (give a pretrained_model directory)")
    unknown = sorted(set(args.stages or ()) - set(STAGES))
    if unknown:
        parser.error(f"--stages: unknown {unknown}; choose from {', '.join(STAGES)}")
    problem = out_folder_problem(
        args.out, args.checkpoint, made_by(args.device, args.task, args.checkpoint), args.overwrite
    )
    if problem:
        parser.error(problem)
    if args.device.startswith("cuda"):
        use_nvidia_vulkan_icd()
    args.out.mkdir(parents=True, exist_ok=True)
    check = DeviceCheck(args.device, args.task, args.checkpoint, args.out, TINY if args.tiny else FULL, args.budget_s)
    with open(args.out / "device_check.log", "a") as log:
        sys.stdout, sys.stderr = _Tee(sys.stdout, log), _Tee(sys.stderr, log)
        try:
            for name in STAGES:
                if not args.stages or name in (*ALWAYS_RUN, *args.stages):
                    check.run(name, getattr(check, name), needs_checkpoint=name in NEED_CHECKPOINT)
        finally:
            sys.stdout, sys.stderr = sys.stdout.stream, sys.stderr.stream
    failed = [name for name, record in check.result["stages"].items() if not record["ok"]]
    print(f"wrote {args.out / RESULT} ({check.result['seconds']} s); not ok: {failed or 'none'}")


if __name__ == "__main__":
    main()
