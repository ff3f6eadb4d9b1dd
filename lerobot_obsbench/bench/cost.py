"""The cost model: what a grid's units of work take, in seconds, from measured rates (docs/performance.md,
"The cost model"). `obsbench run --dry-run` prices a plan with it on a 2-core CPU and on one H200 GPU; the
driver's progress line estimates a grid's ETA with it until a run reports its own rate."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from lerobot_obsbench.bench.grid import Grid
from lerobot_obsbench.bench.specs import EvalSpec, RunSpec
from lerobot_obsbench.bench.units import demo_dir, demo_frames, demos_recorded
from lerobot_obsbench.envs.catalog import task_record
from lerobot_obsbench.envs.metaworld.env import rendered_sensors
from lerobot_obsbench.envs.metaworld.tasks import is_metaworld_name
from lerobot_obsbench.schema import DEFAULT_POINT_FEATURES, DEPTH_PREFIX, IMAGE_PREFIX, is_control, reads_points

DEMO_FRAMES_PER_EPISODE = 30  # for estimates before the demonstrations exist, for a task whose expert is not measured

# The measured rates, each with the machine and benchmark behind it in docs/performance.md#the-cost-model; a
# benchmark's new measurement reaches them through `python -m benchmarks.refresh_rates`.
RATES = json.loads(Path(__file__).with_name("rates.json").read_text())
# Training samples per second by (device kind, preset) and space kind, for `--dry-run` estimates and a grid's ETA
# until a run reports its own rate.
TRAIN_SAMPLES_PER_SECOND = {
    (device, preset): by_space
    for device, presets in RATES["train_samples_per_second"].items()
    for preset, by_space in presets.items()
}
# Evaluation env steps per second with the policy at `EVAL_RATE_IMAGE_SIZE`, by lockstep batch size, env start-up
# included (an unmeasured batch size counts as the largest measured one below it).
EVAL_STEPS_PER_SECOND = {
    device: {int(batch): rate for batch, rate in by_batch.items()}
    for device, by_batch in RATES["eval_steps_per_second"].items()
}
EVAL_RATE_IMAGE_SIZE = RATES["eval_rate_image_size"]
# A task's evaluation seconds over what the rates above price, summed over the evaluations of a real grid
# (benchmarks/bench_grid_cost.py): a task's physics (a peg pushed into a hole) and policies that fail, running out
# each episode's budget, make it larger. A task not listed, and every task on a device not listed, counts as 1.
EVAL_TASK_FACTOR = RATES["eval_task_factor"]
# Meta-World evaluation env steps per second with the policy, by what the env renders for it (`rendered_for`),
# env start-up included. Not scaled with the image size: MuJoCo's colour pass costs its lighting passes, not its
# pixels (docs/metaworld.md, "Cost"). A GPU plan is priced at them too (not measured there: an upper bound).
METAWORLD_EVAL_STEPS_PER_SECOND = RATES["metaworld_eval_steps_per_second"]["cpu"]
# The scripted experts' mean episode length on demonstration seeds, by task (benchmarks/bench_experts.py): the steps a
# recording takes and, before the demonstrations exist, the frames a frame_epochs budget passes over.
EXPERT_MEAN_STEPS = RATES["expert_mean_steps"]
# The cores of the machine the cpu rates were measured on: more local workers than this share no more of its time.
CPU_RATE_CORES = RATES["cpu_rate_cores"]
# RLBench env steps per second, on either device: a guess.
RLBENCH_STEPS_PER_SECOND = RATES["rlbench_steps_per_second"]
# One line of the dry run: the machines behind the rates.
RATES_MEASURED_ON = (
    f"rates: cpu measured on {RATES['measured_on']['cpu']}; cuda on {RATES['measured_on']['cuda']}; per-task "
    f"evaluation factors on {', '.join(EVAL_TASK_FACTOR)} only; Meta-World's evaluation on cpu only, which prices "
    "it on either; docs/performance.md"
)
# The device kinds a plan is priced on, each as one worker: the whole 2-core CPU machine, or one GPU.
DEVICE_KINDS = ("cpu", "cuda")


def device_kind(device: str) -> str:
    return "cuda" if device.startswith("cuda") else "cpu"


def space_kind(obs_space: str) -> str:
    return "point" if reads_points(obs_space) else "none" if is_control(obs_space) else "image"


def rendered_for(obs_space: str, point_features: str = DEFAULT_POINT_FEATURES) -> str:
    """What a Meta-World env renders for a policy on `obs_space` whose points carry `point_features`
    (`rendered_sensors`), as the rates name it: "none", "depth", "colour" or "colour+depth"."""
    names = {IMAGE_PREFIX: "colour", DEPTH_PREFIX: "depth"}
    return "+".join(names[prefix] for prefix in rendered_sensors(obs_space, point_features)) or "none"


def train_seconds(run: RunSpec, steps: int, device: str) -> float:
    rate = TRAIN_SAMPLES_PER_SECOND[(device_kind(device), run.preset)][space_kind(run.obs_space)]
    # larger images cost more; smaller ones barely less (loading and the fixed per-step work dominate)
    return steps * run.batch_size / rate * max(run.image_size / 128, 1.0) ** 2 + 20


def episode_seconds(
    episodes: float,
    max_steps: int,
    device: str,
    rlbench: bool = False,
    batch_size: int = 1,
    image_size: int = 128,
    used: float = 0.6,
    task: str | None = None,
    rendered: str | None = None,
) -> float:
    """Running `episodes` simulated episodes of up to `max_steps` steps, `batch_size` in lockstep, each using
    `used` of its budget (a successful episode ends early; a failed one runs it out); `task`: evaluations of that
    task, priced with its measured factor (None: the rates alone); `rendered`: a Meta-World env's, rendering that
    (`rendered_for`; None: ManiSkill's)."""
    if rlbench:
        rate = RLBENCH_STEPS_PER_SECOND[device_kind(device)]
    elif rendered is not None:
        rate = METAWORLD_EVAL_STEPS_PER_SECOND[rendered]
    else:
        measured = EVAL_STEPS_PER_SECOND[device_kind(device)]
        rate = measured[max(n for n in measured if n <= batch_size)]
        if device_kind(device) == "cpu":  # the CPU renderer slows with the frame; the GPU's did not from 64² to 128²
            rate *= min(1.0, EVAL_RATE_IMAGE_SIZE / image_size)
    factor = EVAL_TASK_FACTOR.get(device_kind(device), {}).get(task, 1.0)
    return episodes * max_steps * used / rate * factor + 10


def eval_seconds(spec: EvalSpec, run: RunSpec, device: str, batch_size: int = 1) -> float:
    """`spec`, an evaluation of `run`, with `batch_size` episodes in lockstep."""
    rlbench = run.rlbench_task is not None
    rendered = rendered_for(run.obs_space, run.point_features) if is_metaworld_name(run.task) else None
    return episode_seconds(
        spec.episodes, spec.max_steps, device, rlbench, batch_size, run.image_size, task=run.task, rendered=rendered
    )


def demo_seconds(grid: Grid, run: RunSpec, episodes: int, device: str) -> float:
    """Recording `episodes` scripted demonstrations of `run`'s task, one env: an expert's step costs what a
    policy's does in evaluation (the simulator and renderer dominate), and each success comes with the failed
    attempts its expert's success rate implies, each running out the episode's budget."""
    record = task_record(run.task)
    failed = episodes * (1 / record.expert_success_rate - 1)
    steps = grid.max_steps(run)
    used = min(1.0, EXPERT_MEAN_STEPS[run.task] / steps) if run.task in EXPERT_MEAN_STEPS else 0.6
    # a Meta-World recording renders colour and depth of the grid's cameras, priced as a policy that reads what is
    # rendered (its expert costs less)
    rendered = ("colour+depth" if grid.cameras else "none") if is_metaworld_name(run.task) else None
    size = run.image_size
    return episode_seconds(episodes, steps, device, image_size=size, used=used, rendered=rendered) + episode_seconds(
        failed, steps, device, image_size=size, used=1.0, rendered=rendered
    )


def unmeasured(runs: list[RunSpec]) -> dict[str, list[str]]:
    """Task -> the rates a CPU plan of `runs` prices it without, at their defaults: a ManiSkill task with no
    measured evaluation factor (counts as 1), a task whose scripted expert's episode length is not measured (counts
    as 0.6 of the budget). RLBench tasks are priced by a guess for every task (the rates' own line says so)."""
    missing: dict[str, list[str]] = {}
    for task in dict.fromkeys(r.task for r in runs if r.rlbench_task is None):
        names = []
        if not is_metaworld_name(task) and task not in EVAL_TASK_FACTOR["cpu"]:
            names.append("evaluation factor")
        if task not in EXPERT_MEAN_STEPS:
            names.append("expert's episode length")
        if names:
            missing[task] = names
    return missing


def planned_steps(run: RunSpec, out: Path) -> tuple[int, bool]:
    """(optimizer steps, exact): frame_epochs budgets are estimated until the demonstrations exist."""
    if run.budget_unit != "frame_epochs":
        return run.steps(), True
    path = demo_dir(out, run, run.demos)
    if demos_recorded(path):
        return run.steps(demo_frames(path, run.demos)), True
    return run.steps(round(run.demos * EXPERT_MEAN_STEPS.get(run.task, DEMO_FRAMES_PER_EPISODE))), False


@dataclass
class PlanCost:
    """What a plan adds up to: optimizer steps, training samples and evaluation episodes, and its seconds with one
    worker on each of `DEVICE_KINDS`."""

    steps: int = 0
    samples: int = 0
    episodes: int = 0
    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(DEVICE_KINDS, 0.0))

    def add_demos(self, grid: Grid, run: RunSpec, episodes: int) -> None:
        """Recording `episodes` demonstrations of the dataset `run` trains on."""
        for kind in DEVICE_KINDS:
            self.seconds[kind] += demo_seconds(grid, run, episodes, kind)

    def add_run(
        self, run: RunSpec, steps: int, train: bool, evals: list[EvalSpec], batch_sizes: dict[str, int]
    ) -> None:
        """`run`'s `evals`, and its training of `steps` when `train`; `batch_sizes`: each device kind's lockstep
        evaluation episodes."""
        if train:
            self.steps += steps
            self.samples += steps * run.batch_size
        self.episodes += sum(s.episodes for s in evals)
        for kind in DEVICE_KINDS:
            self.seconds[kind] += (train_seconds(run, steps, kind) if train else 0) + sum(
                eval_seconds(s, run, kind, batch_sizes[kind]) for s in evals
            )

    def lines(self, device: str, workers: int = 1) -> list[str]:
        """The dry run's cost lines for a plan on `device` with `workers` local workers."""
        cpu, cuda = self.seconds["cpu"], self.seconds["cuda"]
        lines = [
            f"  rough cost with one worker: {cpu / 3600:.1f} h on a 2-core CPU, {cuda / 3600:.1f} h "
            f"on one H200 GPU (planning on {device}; demonstrations to record included)"
        ]
        if workers > 1 and device_kind(device) == "cpu":
            shared = min(workers, CPU_RATE_CORES)
            lines.append(
                f"  with {workers} local workers: ~{cpu / 3600 / shared:.1f} h of wall time on a 2-core CPU "
                f"(the one-worker cost shared evenly by {shared}; measured against real grids in docs/performance.md)"
            )
        return [*lines, f"  {RATES_MEASURED_ON}"]
