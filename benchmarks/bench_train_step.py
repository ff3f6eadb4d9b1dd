"""Time per training step (forward, backward and the preset's optimizer step) for every (observation space,
encoder) pair of obs_act and obs_diffusion, side by side with LeRobot's stock ACT-ResNet18 / Diffusion-ResNet18 at
the same batch and the same transformer / UNet sizes, on ray-cast cluttered 128² frames; or for every run of a
benchmark grid, each at its own preset, encoder, overrides, batch and image size (`--grid quick`: the main job's).

    .venv/bin/python -m benchmarks.bench_train_step [--batch 8] [--device cpu] [--preset cpu] [--out FILE]
    .venv/bin/python -m benchmarks.bench_train_step --grid quick [--device cpu]

`--preset paper` times the paper grid's encoders (ResNet-50, ViT-B, MultiViT-B, PointNet, SpUNet-34) at the
paper's batches (ACT 16, DP 64) and also reports each row against rgb/ResNet-50; it is meant for a GPU
(`--device cuda`). SpUNet-34 rows need spconv's CUDA wheel (`pip install '.[cuda]'`) and are left out, with the
reason in the JSON, where spconv cannot run on the device. On a CUDA device each row also has its peak memory.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.act.configuration_act import ACTConfig
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

from benchmarks.bench_preprocess import WORKSPACE, cluttered_frames
from benchmarks.common import load_synthetic, timed, write
from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig
from lerobot_obsbench.policies.obs_act.modeling_obs_act import ObsACTPolicy
from lerobot_obsbench.policies.obs_diffusion.modeling_obs_diffusion import ObsDiffusionPolicy
from lerobot_obsbench.presets import model_sizes, preset_overrides
from lerobot_obsbench.schema import POSE_SIZE, PRIVILEGED_STATE_KEY

CAM = "base_camera"
PAIRS = {
    "cpu": [
        ("rgb", "resnet18"),
        ("depth", "resnet18"),
        ("rgbd", "resnet18"),
        ("pointmap", "resnet18"),
        ("pointcloud", "pointnet"),
    ],
    # paper-main's encoders for every space (the first row is the reference of `vs_rgb_resnet50`)
    "paper": [
        ("rgb", "resnet50"),
        ("rgb", "vit_b"),
        ("depth", "resnet50"),
        ("rgbd", "resnet50"),
        ("rgbd", "multivit_b"),
        ("pointmap", "resnet50"),
        ("pointcloud", "pointnet"),
        ("pointcloud", "spunet34"),
    ],
}
# paper-main's batches (configs/grids/paper-main.yaml)
PAPER_BATCH = {"act": 16, "diffusion": 64}
# what stock ACT / Diffusion read besides the images
STOCK_STATE = ("observation.state", "observation.environment_state")
POLICIES = {
    "act": (ACTConfig, ACTPolicy, ObsACTConfig, ObsACTPolicy),
    "diffusion": (DiffusionConfig, DiffusionPolicy, ObsDiffusionConfig, ObsDiffusionPolicy),
}


def features(size: int) -> tuple[dict, dict]:
    inputs = {
        f"observation.images.{CAM}": PolicyFeature(FeatureType.VISUAL, (3, size, size)),
        f"observation.depth.{CAM}": PolicyFeature(FeatureType.STATE, (size, size, 1)),
        f"observation.intrinsics.{CAM}": PolicyFeature(FeatureType.STATE, (3, 3)),
        f"observation.cam2world.{CAM}": PolicyFeature(FeatureType.STATE, (4, 4)),
        "observation.state": PolicyFeature(FeatureType.STATE, (15,)),
        "observation.environment_state": PolicyFeature(FeatureType.ENV, (3,)),
        # one object's pose, for the oracle control (every other space leaves it out)
        PRIVILEGED_STATE_KEY: PolicyFeature(FeatureType.STATE, (POSE_SIZE,)),
    }
    return inputs, {"action": PolicyFeature(FeatureType.ACTION, (7,))}


def make_batch(frames: dict, batch: int, horizon: int, n_obs: int | None, device) -> dict:
    def steps(x):  # diffusion batches carry an observation-history axis
        return x if n_obs is None else x.unsqueeze(1).expand(x.shape[0], n_obs, *x.shape[1:]).contiguous()

    out = {
        f"observation.images.{CAM}": torch.tensor(frames["rgb"][:batch]).permute(0, 3, 1, 2).float() / 255,
        f"observation.depth.{CAM}": torch.tensor(frames["depth"][:batch].astype(np.int64)),
        f"observation.intrinsics.{CAM}": torch.tensor(frames["K"], dtype=torch.float32).expand(batch, 3, 3),
        f"observation.cam2world.{CAM}": torch.tensor(frames["cam2world"], dtype=torch.float32).expand(batch, 4, 4),
        "observation.state": torch.randn(batch, 15),
        "observation.environment_state": torch.randn(batch, 3),
        PRIVILEGED_STATE_KEY: torch.randn(batch, POSE_SIZE),
    }
    out = {k: steps(v).to(device) for k, v in out.items()}
    out["action"] = torch.randn(batch, horizon, 7, device=device)
    out["action_is_pad"] = torch.zeros(batch, horizon, dtype=torch.bool, device=device)
    return out


def train_step(policy, batch: dict):
    """A function taking one optimizer step of `policy` on `batch` as lerobot-train takes it (the policy's own
    optimizer preset), returning when a CUDA device has finished it."""
    policy.train()
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())
    cuda = batch["action"].is_cuda

    def step():
        optimizer.zero_grad(set_to_none=True)
        loss, _ = policy.forward(batch)
        loss.backward()
        optimizer.step()
        if cuda:
            torch.cuda.synchronize()

    return step


def step_time(policy, batch: dict, repeats: int) -> dict:
    """One optimizer step (`train_step`), timed; on a CUDA device with the peak memory the steps allocated."""
    cuda = batch["action"].is_cuda
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    result = timed(train_step(policy, batch), repeats=repeats, warmup=2)
    result["steps_per_s"] = round(1000 / result["median_ms"], 2)
    if cuda:
        result["peak_memory_MiB"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
    return result


def spconv_problem(device: torch.device) -> str | None:
    """Why SpUNet-34 cannot be timed on `device`, or None when it can."""
    try:
        import spconv.pytorch  # noqa: F401
    except ImportError as error:
        return f"spconv is not installed ({error})"
    if device.type == "cuda" and not torch.cuda.is_available():
        return "CUDA is not available"
    return None


def params_millions(policy) -> float:
    return round(sum(p.numel() for p in policy.parameters()) / 1e6, 2)


def release(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.empty_cache()


def preset_rows(
    preset: str, device: torch.device, size: int, batches: dict, repeats: int, pairs: list | None = None
) -> tuple[list, list]:
    """Rows (and skipped pairs, with why) of `--preset`: stock ACT / Diffusion, then every (space, encoder) of
    `pairs` (default: PAIRS[preset], and for ACT the point cloud at the paper's 2048 tokens)."""
    frames = cluttered_frames(load_synthetic(), max(batches.values()), size)
    inputs, outputs = features(size)
    rows, skipped = [], []
    for kind, (stock_cls, stock_policy, ours_cls, ours_policy) in POLICIES.items():
        # model sizes, shared by stock and plugin policies (the stock config's fields only)
        common = {k: v for k, v in model_sizes(preset, f"obs_{kind}").items() if k in stock_cls.__dataclass_fields__}
        stock_extra = {"pretrained_backbone_weights": None}
        if kind == "diffusion":
            stock_extra["crop_shape"] = None
            # the plugin pins the paper's horizon and action steps (LeRobot 0.6's stock defaults are 64 and 32)
            for name in ("horizon", "n_action_steps"):
                stock_extra[name] = common.get(name, ours_cls.__dataclass_fields__[name].default)
        else:
            stock_extra["n_action_steps"] = 1
        stock_cfg = stock_cls(
            device=device.type,
            input_features={k: v for k, v in inputs.items() if "images" in k or k in STOCK_STATE},
            output_features=outputs,
            **{**common, **stock_extra},
        )
        stock = stock_policy(stock_cfg).to(device)
        horizon = stock_cfg.chunk_size if kind == "act" else stock_cfg.horizon
        n_obs = None if kind == "act" else stock_cfg.n_obs_steps
        batch = make_batch(frames, batches[kind], horizon, n_obs, device)
        if kind == "diffusion":
            batch["observation.images"] = batch[f"observation.images.{CAM}"].unsqueeze(2)
        base = step_time(stock, batch, repeats)
        rows.append(
            {
                "policy": f"stock {kind}",
                "obs_space": "rgb",
                "encoder": "resnet18 (LeRobot)",
                "params_M": params_millions(stock),
                **base,
                "ratio": 1.0,
            }
        )
        print(f"stock {kind}-resnet18: {base['median_ms']:.0f} ms")
        del stock
        release(device)
        timed_pairs = pairs or PAIRS[preset] + ([("pointcloud", "pointnet@2048")] if kind == "act" else [])
        reference = None
        for space, encoder in timed_pairs:
            if encoder == "spunet34" and (problem := spconv_problem(device)):
                skipped.append({"policy": f"obs_{kind}", "obs_space": space, "encoder": encoder, "why": problem})
                print(f"obs_{kind} {space:10s} {encoder:14s}: skipped, {problem}")
                continue
            name = encoder.split("@")[0]
            extra = dict(preset_overrides(preset, f"obs_{kind}", space, name), encoder=name, workspace=list(WORKSPACE))
            if "@" in encoder:
                extra["num_tokens"] = int(encoder.split("@")[1])
            cfg = ours_cls(
                device=device.type, obs_space=space, input_features=dict(inputs), output_features=outputs, **extra
            )
            policy = ours_policy(cfg).to(device)
            t = step_time(policy, batch, repeats)
            reference = reference or t
            ratio = round(t["median_ms"] / base["median_ms"], 2)
            rows.append(
                {
                    "policy": f"obs_{kind}",
                    "obs_space": space,
                    "encoder": encoder,
                    "batch": batches[kind],
                    "params_M": params_millions(policy),
                    **t,
                    "ratio": ratio,
                    f"vs_{timed_pairs[0][0]}_{timed_pairs[0][1]}": round(t["median_ms"] / reference["median_ms"], 2),
                }
            )
            print(
                f"obs_{kind} {space:10s} {encoder:14s}: {t['median_ms']:.0f} ms, {t['steps_per_s']} steps/s "
                f"({ratio}x stock)"
            )
            del policy
            release(device)
    return rows, skipped


def grid_run_policy(run, device: torch.device, synthetic, **fields) -> tuple:
    """(policy, batch) of one grid run: the policy built as the grid's lerobot-train call builds it (preset, task
    crop box, overrides; `fields` set more `--policy.*` fields) from torch's current seed, and a batch of
    cluttered frames at the run's batch and image size."""
    from lerobot_obsbench.bench.grid import task_overrides

    kind = run.policy.removeprefix("obs_")
    _, _, ours_cls, ours_policy = POLICIES[kind]
    inputs, outputs = features(run.image_size)
    fields = {
        **preset_overrides(run.preset, run.policy, run.obs_space, run.encoder),
        **task_overrides(run.task, run.obs_space),
        **dict(run.policy_overrides),
        "encoder": run.encoder,
        "augment": run.augment,
        "optimizer_lr": run.lr,
        **fields,
    }
    cfg = ours_cls(
        device=device.type, obs_space=run.obs_space, input_features=inputs, output_features=outputs, **fields
    )
    policy = ours_policy(cfg).to(device)
    horizon = cfg.chunk_size if kind == "act" else cfg.horizon
    n_obs = None if kind == "act" else cfg.n_obs_steps
    frames = cluttered_frames(synthetic, run.batch_size, run.image_size)
    return policy, make_batch(frames, run.batch_size, horizon, n_obs, device)


def grid_rows(grid_name: str, device: torch.device, repeats: int, threads: list[int] | None = None) -> list[dict]:
    """One row per training run of a grid (the first seed and learning rate of each method): its policy built as
    the grid's lerobot-train call builds it (preset, task crop box, overrides), timed at the run's batch and image
    size; with `threads`, one row per CPU thread count, the counts of one policy timed one after the other."""
    from lerobot_obsbench.bench.grid import load_grid

    runs = {run.method: run for run in reversed(load_grid(grid_name).expand())}
    synthetic, rows = load_synthetic(), []
    for run in runs.values():
        policy, batch = grid_run_policy(run, device, synthetic)
        for count in threads or [torch.get_num_threads()]:
            torch.set_num_threads(count)
            t = step_time(policy, batch, repeats)
            rows.append(
                {
                    "grid": grid_name,
                    "policy": run.policy,
                    "obs_space": run.obs_space,
                    "encoder": run.encoder,
                    "augment": run.augment,
                    "batch": run.batch_size,
                    "image_size": run.image_size,
                    "threads": count,
                    "params_M": params_millions(policy),
                    **t,
                    "samples_per_s": round(t["steps_per_s"] * run.batch_size, 1),
                }
            )
            print(
                f"{grid_name} {run.method:32s} {count} thread(s): {t['median_ms']:.1f} ms, {t['steps_per_s']} steps/s"
            )
        del policy
        release(device)
    return rows


def prepare(device: torch.device) -> None:
    torch.manual_seed(0)
    if device.type == "cuda":  # as lerobot-train sets them
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--batch", type=int, help="default: 8 (cpu preset), the paper's batches (paper preset)")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--preset", default="cpu", choices=["cpu", "paper"])
    parser.add_argument("--grid", help="time every run of this grid (preset name or file) instead of --preset")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, nargs="+", help="--grid: time each run at these CPU thread counts")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    device = torch.device(args.device)
    prepare(device)
    if args.threads and not args.grid:
        parser.error("--threads goes with --grid")
    if args.grid:
        rows = grid_rows(args.grid, device, args.repeats, args.threads)
        name = Path(args.grid).name.removesuffix(".yaml")
        write(f"train_step_{device.type}_grid_{name}", {"grid": args.grid, "rows": rows}, args.out)
        return
    batches = {kind: args.batch or (PAPER_BATCH[kind] if args.preset == "paper" else 8) for kind in PAPER_BATCH}
    rows, skipped = preset_rows(args.preset, device, args.size, batches, args.repeats)
    write(
        f"train_step_{args.device}_{args.preset}",
        {
            "batch": batches,
            "image_size": args.size,
            "preset": args.preset,
            "target_ratio": 2.0,
            "rows": rows,
            "skipped": skipped,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
