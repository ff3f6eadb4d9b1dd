"""The units of work of a grid — recording demonstrations, training a run, evaluating a checkpoint — as top-level
functions of picklable arguments that return results records, so any engine (a local process pool, Ray on a
cluster) can run them (the driver hands them over as `jobs.py`'s jobs). Only the grid's driver writes the results
file.

Layout of a grid's output directory (`run_dir`, `demo_dir`; shared by every worker; on a cluster it must be a
shared filesystem):

    OUT/results.jsonl                       train and eval records (see `results.py`)
    OUT/demos/<task>-<px>-<cams>-<ctrl>-<N>ep/  scripted demonstrations shared by every run of that task
    OUT/runs/<run_id>/train/                lerobot-train's output_dir: checkpoints/<step>/, checkpoints/last
    OUT/runs/<run_id>/train.log             lerobot-train's console output (live progress is read from it)
    OUT/runs/<run_id>/eval/<eval_id>.json   per-episode results of one evaluation (+ .log; .progress while it runs)

Nothing is lost to a kill: training saves evenly spaced checkpoints and a restarted run resumes from its last
one with LeRobot's own `--resume`; a checkpoint is never deleted; each evaluation is one record, so a kill
during evaluation loses only the evaluation in flight.
"""

from __future__ import annotations

import ctypes
import json
import math
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

from lerobot_obsbench.bench.machine import facts_of_process, machine_facts
from lerobot_obsbench.bench.specs import EvalSpec, RunSpec
from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.rlbench.paper_tasks import grid_task_name
from lerobot_obsbench.schema import LOCAL_REPO_ID

PACKAGES = ("lerobot", "torch", "mani-skill", "sapien", "lerobot_policy_obsbench")
CHECKPOINTS = "checkpoints"
# LeRobot's checkpoint layout (lerobot.utils.constants): checkpoints/<step>/{pretrained_model, training_state}
PRETRAINED, TRAINING_STATE, TRAINING_STEP = "pretrained_model", "training_state", "training_step.json"


class RunError(ObsBenchError, RuntimeError):
    """A unit of work failed; its log says why."""


def die_with_parent() -> None:
    """Children (training subprocesses, pool workers) get SIGKILL when their parent dies, so a killed grid
    leaves no orphan writing into a run directory."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def versions() -> dict[str, str]:
    found = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def thread_env(threads: int | None) -> dict[str, str]:
    """Environment pinning a process's CPU threads (torch, OpenMP, MKL): results then do not depend on which
    machine or engine ran the unit."""
    if not threads:
        return {}
    return {name: str(threads) for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}


# ---- the output directory's layout -------------------------------------------------------------------------


def run_dir(out_dir: str | Path, run_id: str) -> Path:
    """OUT/runs/<run_id>: what one run writes (its training, logs and evaluations)."""
    return Path(out_dir) / "runs" / run_id


def demo_dir(out_dir: str | Path, run: RunSpec, episodes: int) -> Path:
    """OUT/demos/<demo_key>-<N>ep: the first `episodes` demonstrations of the dataset `run` trains on."""
    return Path(out_dir) / "demos" / f"{run.demo_key}-{episodes}ep"


def demos_recorded(path: Path) -> bool:
    """Whether `path` holds a finished recording (its LeRobotDataset is assembled only once every episode is in)."""
    return (path / "meta" / "info.json").is_file()


# ---- demonstrations ----------------------------------------------------------------------------------------


def demos_unit(
    task: str, episodes: int, path: str, image_size: int, cameras: list[str], rlbench: dict | None = None
) -> dict:
    """Record (or finish recording) `episodes` scripted demonstrations of `task` into `path` (resumable); an
    RLBench task's are imported from the first `episodes` of `rlbench["data"]`/train/<task> instead."""
    name = grid_task_name(task)
    if name is not None:
        from lerobot_obsbench.datasets.rlbench_import import import_rlbench
        from lerobot_obsbench.rlbench.text import load_clip_text_encoder

        weights = rlbench.get("clip_weights")
        return import_rlbench(
            Path(rlbench["data"]) / "train" / name,
            Path(path),
            task=name,
            cameras=tuple(cameras),
            text_encoder=load_clip_text_encoder(weights) if weights else None,
            max_episodes=episodes,
        )
    from lerobot_obsbench.datasets.sim_demos import record_demos

    return record_demos(task, episodes, Path(path), image_size=image_size, cameras=tuple(cameras))


def demo_count(dataset: Path) -> int:
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    return int(LeRobotDatasetMetadata(LOCAL_REPO_ID, root=dataset).total_episodes)


def demo_frames(dataset: Path, episodes: int) -> int:
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    return int(sum(LeRobotDatasetMetadata(LOCAL_REPO_ID, root=dataset).episodes["length"][:episodes]))


# ---- training ----------------------------------------------------------------------------------------------


def log_every(steps: int) -> int:
    """lerobot-train's `--log_freq` for a run of `steps`: about 50 loss lines, at most every 200 steps."""
    return max(min(steps // 50, 200), 1)


def train_command(
    run: RunSpec, dataset: Path, output_dir: Path, steps: int, device: str, save_every: int, loader_workers: int = 0
) -> list[str]:
    """Stock lerobot-train for one run (a fresh start; `resume_command` continues one)."""
    return [
        str(Path(sys.executable).parent / "lerobot-train"),
        f"--policy.type={run.policy}",
        *run.policy_args(),
        f"--policy.device={device}",
        f"--dataset.repo_id={LOCAL_REPO_ID}",
        f"--dataset.root={dataset}",
        f"--dataset.episodes=[{','.join(str(i) for i in range(run.demos))}]",
        f"--seed={run.seed}",
        f"--batch_size={run.batch_size}",
        f"--steps={steps}",
        f"--save_freq={save_every}",
        f"--log_freq={log_every(steps)}",
        f"--num_workers={loader_workers}",
        "--wandb.enable=false",
        f"--output_dir={output_dir}",
        f"--job_name=obsbench_{run.run_id}",
    ]


def resume_command(output_dir: Path) -> list[str]:
    """LeRobot's own resume of a run from its last checkpoint (same config, optimizer, scheduler and RNG)."""
    config = output_dir / CHECKPOINTS / "last" / PRETRAINED / "train_config.json"
    return [str(Path(sys.executable).parent / "lerobot-train"), f"--config_path={config}", "--resume=true"]


def resumes_exactly() -> bool:
    """Whether lerobot-train here resumes a run as the uninterrupted run goes on: the plugin's fix is in place
    (it is applied on the LeRobot version it was written for)."""
    from lerobot.scripts import lerobot_train

    from lerobot_obsbench import patches

    return lerobot_train.cycle is patches.cycle_keeping_restored_rng


def saved_checkpoints(output_dir: Path) -> dict[int, Path]:
    """step -> pretrained_model directory of every complete checkpoint lerobot-train saved."""
    found = {}
    for entry in (output_dir / CHECKPOINTS).glob("[0-9]*"):
        model = entry / PRETRAINED
        if entry.is_dir() and (model / "model.safetensors").is_file() and (model / "config.json").is_file():
            found[int(entry.name)] = model
    return dict(sorted(found.items()))


def resumable_step(output_dir: Path) -> int | None:
    """The step LeRobot would resume from (its `last` checkpoint's training state), or None."""
    state = output_dir / CHECKPOINTS / "last" / TRAINING_STATE / TRAINING_STEP
    if not state.is_file():
        return None
    try:
        return int(json.loads(state.read_text())["step"])
    except (ValueError, KeyError):
        return None


def save_every(steps: int, checkpoints: int) -> int:
    """The spacing of `checkpoints` evenly spaced checkpoints (the last at `steps`)."""
    return max(1, -(-steps // max(checkpoints, 1)))


def kept_checkpoints(steps: int, checkpoints: int, curve: tuple[int, ...] = ()) -> list[int]:
    """The steps whose checkpoints a run keeps: `checkpoints` evenly spaced ones (the last at `steps`) and the
    learning curve's `curve` steps."""
    every = save_every(steps, checkpoints)
    return sorted({*range(every, steps, every), steps, *curve})


def save_freq(kept: list[int]) -> int:
    """lerobot-train's `--save_freq` (one spacing for every checkpoint) that saves each of the `kept` steps: the
    greatest common divisor of those before the last, which lerobot-train always saves; the others it saves are
    deleted once training ends."""
    return math.gcd(*kept[:-1]) if len(kept) > 1 else kept[0]


def train_unit(
    run_config: dict,
    dataset: str,
    out_dir: str,
    device: str = "cpu",
    checkpoints: int = 4,
    held_out: int = 0,
    loader_workers: int = 0,
    threads: int | None = None,
    curve: tuple[int, ...] = (),
    retrain: bool = False,
) -> dict:
    """Train one run with stock lerobot-train (resuming from its last checkpoint after a kill), keeping its
    `checkpoints` evenly spaced checkpoints and those of its learning curve's `curve` steps, then compute its
    diagnostics on the dataset's last `held_out` demonstrations; returns its train record (`retrain`: one that
    replaces the record of an earlier training whose checkpoints are gone)."""
    run = RunSpec.from_config(run_config)
    root = run_dir(out_dir, run.run_id)
    root.mkdir(parents=True, exist_ok=True)
    (root / "run.json").write_text(json.dumps(run.config(), indent=2) + "\n")
    output_dir = root / "train"
    steps = run.steps(demo_frames(Path(dataset), run.demos) if run.budget_unit == "frame_epochs" else None)
    kept = kept_checkpoints(steps, checkpoints, curve)
    resumed_from = resumable_step(output_dir)
    if resumed_from is None:
        shutil.rmtree(output_dir, ignore_errors=True)  # lerobot-train refuses an existing output_dir
        command = train_command(run, Path(dataset), output_dir, steps, device, save_freq(kept), loader_workers)
    else:
        command = resume_command(output_dir)
    start = time.time()
    progress = {"steps": steps, "resumed_from": resumed_from or 0, "started": start}
    (root / "progress.json").write_text(json.dumps(progress) + "\n")
    env = {**os.environ, "HF_HUB_OFFLINE": "1", **thread_env(threads)}
    with open(root / "train.log", "a") as log:
        log.write(f"\n=== {now()} {'resuming at step ' + str(resumed_from) if resumed_from else 'starting'} ===\n")
        log.flush()
        done = subprocess.run(
            command,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            preexec_fn=die_with_parent,
            env=env,
        )
    saved = saved_checkpoints(output_dir)
    if done.returncode != 0 or not set(kept) <= set(saved):
        tail = "".join((root / "train.log").read_text().splitlines(keepends=True)[-15:])
        raise RunError(
            f"training of run {run.run_id} ({run.method} on {run.task}) failed with exit code "
            f"{done.returncode}; log {root / 'train.log'}:\n{tail}"
        )
    train_s = round(time.time() - start, 1)
    for step, model in saved.items():
        if step not in kept:  # saved only because lerobot-train saves at one spacing
            shutil.rmtree(model.parent)
    saved = {step: saved[step] for step in kept}
    return {
        "kind": "train",
        "run_id": run.run_id,
        "config": run.config(),
        "method": run.method,
        "task": run.task,
        "train_steps": steps,
        "samples": steps * run.batch_size,
        "budget": {run.budget_unit: run.budget},
        "checkpoint": str(saved[steps]),
        "checkpoints": {str(s): str(p) for s, p in saved.items()},
        "resumed_from": resumed_from,
        # whether the resume continued the uninterrupted run's data order and random stream (patches.py, fix 5)
        **({"resumed_exactly": resumes_exactly()} if resumed_from else {}),
        **({"retrained": True} if retrain else {}),
        "device": device,
        "timings": {"train_s": train_s},
        "diagnostics": run_diagnostics(run, root, steps, Path(saved[steps]), Path(dataset), held_out, device, threads),
        "versions": versions(),
        "machine": facts_of_process(env),  # those of the lerobot-train it ran: same machine, same environment
        "finished_at": now(),
    }


def run_diagnostics(
    run: RunSpec,
    root: Path,
    steps: int,
    checkpoint: Path,
    dataset: Path,
    held_out: int,
    device: str,
    threads: int | None = None,
) -> dict:
    """The run's loss curve (a run of `steps`), and its held-out diagnostics on the dataset's last `held_out`
    episodes (which no run trains on), on the unit's `threads` as its training (so any engine computes the same
    figures). A failure is recorded in place of the held-out figures, not raised: the trained run is kept."""
    from lerobot_obsbench.bench.diagnostics import held_out_diagnostics, loss_curve
    from lerobot_obsbench.envs.catalog import task_record

    out: dict = {"loss_curve": loss_curve((root / "train.log").read_text(), log_every(steps))}
    if held_out and threads:
        import torch

        torch.set_num_threads(threads)
    if held_out:
        total = demo_count(dataset)
        episodes = list(range(total - held_out, total))
        if episodes[0] < run.demos:
            raise RunError(f"run {run.run_id} trains on {run.demos} demos; the held-out {episodes} overlap them")
        try:
            out.update(held_out_diagnostics(checkpoint, dataset, episodes, task_record(run.task), device))
        except Exception as err:  # a diagnostic must not lose a trained run
            out["error"] = f"{type(err).__name__}: {err}"
    return out


def training_progress(out_dir: Path, run_id: str) -> dict | None:
    """The live state of a run's training read from its log: {"step", "steps", "loss", "started"} (None before
    it starts). lerobot-train's progress bar counts from the step it resumed at."""
    root = run_dir(out_dir, run_id)
    try:
        info = json.loads((root / "progress.json").read_text())
        with open(root / "train.log", "rb") as log:
            log.seek(max(0, log.seek(0, os.SEEK_END) - 8192))
            tail = log.read().decode(errors="replace")
    except (OSError, ValueError):
        return None
    counts = re.findall(r"\| *(\d+)/(\d+) \[", tail)
    losses = re.findall(r"(?<!\w)loss:([0-9.eE+-]+)", tail)  # the total, not l1_loss / kld_loss after it
    step = info["resumed_from"] + (int(counts[-1][0]) if counts else 0)
    return {
        "step": step,
        "steps": info["steps"],
        "loss": float(losses[-1]) if losses else None,
        "started": info["started"],
    }


# ---- evaluation --------------------------------------------------------------------------------------------


def eval_unit(
    eval_config: dict,
    run_config: dict,
    checkpoint: str,
    checkpoint_step: int,
    out_dir: str,
    device: str = "cpu",
    threads: int | None = None,
    rlbench: dict | None = None,
    batch_size: int = 1,
) -> dict:
    """Evaluate one checkpoint (seed split, episodes, perturbation, episode budget of `eval_config`), ManiSkill
    episodes `batch_size` at a time in lockstep; returns its eval record. Per-episode results go to
    runs/<run_id>/eval/<eval_id>.json. An RLBench run is evaluated by RLBench's protocol on the split's episodes in
    `rlbench["data"]`."""
    import torch

    if threads:
        torch.set_num_threads(threads)
    spec, run = EvalSpec(**eval_config), RunSpec.from_config(run_config)
    folder = run_dir(out_dir, run.run_id) / "eval"
    folder.mkdir(parents=True, exist_ok=True)
    # the evaluation's own console output (LeRobot's loading messages) goes to its log, not the grid's console
    with open(folder / f"{spec.eval_id}.log", "w") as log, redirect_stdout(log), redirect_stderr(log):
        if run.rlbench_task is not None:
            result = _evaluate_rlbench(spec, run, checkpoint, device, rlbench, folder / f"{spec.eval_id}.progress")
        else:
            from lerobot_obsbench.envs.evaluate import evaluate

            result = evaluate(
                checkpoint,
                run.task,
                spec.episodes,
                image_size=run.image_size,
                control_mode=run.control_mode,
                episode_length=spec.max_steps,
                device=device,
                perturbation=spec.perturbation,
                split=spec.split,
                progress=False,
                progress_file=folder / f"{spec.eval_id}.progress",
                batch_size=batch_size,
            )
    (folder / f"{spec.eval_id}.json").write_text(json.dumps({**spec.config(), **result}, indent=2) + "\n")
    keys = ("episodes", "successes", "success_rate", "ci95", "sub_success", "episode_length_mean", "per_seed", "wall_s")
    return {
        "kind": "eval",
        "eval_id": spec.eval_id,
        **spec.config(),
        "task": run.task,
        "method": run.method,
        "checkpoint_step": checkpoint_step,
        "device": device,
        **{k: result[k] for k in ("batch_size", "sim_backend") if k in result},  # (RLBench has neither)
        **{k: result[k] for k in keys},
        "machine": machine_facts(),
        "finished_at": now(),
    }


# RLBench's PerAct data names its splits train / val / test
RLBENCH_SPLITS = {"test": "test", "validation": "val"}


def _evaluate_rlbench(spec: EvalSpec, run: RunSpec, checkpoint: str, device: str, rlbench: dict, progress) -> dict:
    from lerobot_obsbench.rlbench.evaluate import camera_view_for, evaluate_checkpoint
    from lerobot_obsbench.rlbench.paper_tasks import rlbench_task

    return evaluate_checkpoint(
        checkpoint,
        rlbench_task(run.rlbench_task),
        Path(rlbench["data"]) / RLBENCH_SPLITS[spec.split],
        spec.episodes,
        spec.max_steps,
        camera_view=camera_view_for(spec.perturbation),
        clip_weights=rlbench.get("clip_weights") if run.language_goal else None,
        device=device,
        progress_file=progress,
    )


def evaluation_progress(out_dir: Path, run_id: str, eval_id: str) -> dict | None:
    """{"done", "episodes", "successes"} of a running evaluation (None before it starts)."""
    try:
        return json.loads((run_dir(out_dir, run_id) / "eval" / f"{eval_id}.progress").read_text())
    except (OSError, ValueError):
        return None
