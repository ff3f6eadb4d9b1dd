"""Time per training step (forward, backward and the preset's optimizer step) for every (observation space,
encoder) pair of obs_act and obs_diffusion, side by side with LeRobot's stock ACT-ResNet18 / Diffusion-ResNet18 at
the same batch and the same transformer / UNet sizes, on ray-cast cluttered 128² frames.

    .venv/bin/python -m benchmarks.bench_train_step [--batch 8] [--device cpu] [--preset cpu] [--out FILE]

`--preset paper` times the paper grid's encoders (ResNet-50, ViT-B, MultiViT-B, PointNet, SpUNet-34) at the
paper's batches (ACT 16, DP 64) and also reports each row against rgb/ResNet-50; it is meant for a GPU
(`--device cuda`). SpUNet-34 rows need spconv's CUDA wheel (`pip install '.[cuda]'`) and are left out, with the
reason in the JSON, where spconv cannot run on the device.
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


def features(size: int) -> tuple[dict, dict]:
    inputs = {
        f"observation.images.{CAM}": PolicyFeature(FeatureType.VISUAL, (3, size, size)),
        f"observation.depth.{CAM}": PolicyFeature(FeatureType.STATE, (size, size, 1)),
        f"observation.intrinsics.{CAM}": PolicyFeature(FeatureType.STATE, (3, 3)),
        f"observation.cam2world.{CAM}": PolicyFeature(FeatureType.STATE, (4, 4)),
        "observation.state": PolicyFeature(FeatureType.STATE, (15,)),
        "observation.environment_state": PolicyFeature(FeatureType.ENV, (3,)),
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
    }
    out = {k: steps(v).to(device) for k, v in out.items()}
    out["action"] = torch.randn(batch, horizon, 7, device=device)
    out["action_is_pad"] = torch.zeros(batch, horizon, dtype=torch.bool, device=device)
    return out


def step_time(policy, batch: dict, repeats: int) -> dict:
    """One optimizer step as lerobot-train takes it (the policy's own optimizer preset), timed."""
    policy.train()
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())

    def step():
        optimizer.zero_grad(set_to_none=True)
        loss, _ = policy.forward(batch)
        loss.backward()
        optimizer.step()
        if batch["action"].is_cuda:
            torch.cuda.synchronize()

    result = timed(step, repeats=repeats, warmup=2)
    return {**result, "steps_per_s": round(1000 / result["median_ms"], 2)}


def spconv_problem(device: torch.device) -> str | None:
    """Why SpUNet-34 cannot be timed on `device`, or None when it can."""
    try:
        import spconv.pytorch  # noqa: F401
    except ImportError as error:
        return f"spconv is not installed ({error})"
    if device.type == "cuda" and not torch.cuda.is_available():
        return "CUDA is not available"
    return None


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--batch", type=int, help="default: 8 (cpu preset), the paper's batches (paper preset)")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--preset", default="cpu", choices=["cpu", "paper"])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    torch.manual_seed(0)
    device = torch.device(args.device)
    if device.type == "cuda":  # as lerobot-train sets them
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True
    batches = {kind: args.batch or (PAPER_BATCH[kind] if args.preset == "paper" else 8) for kind in PAPER_BATCH}
    frames = cluttered_frames(load_synthetic(), max(batches.values()), args.size)
    inputs, outputs = features(args.size)
    rows, skipped = [], []
    for kind, stock_cls, stock_policy, ours_cls, ours_policy in (
        ("act", ACTConfig, ACTPolicy, ObsACTConfig, ObsACTPolicy),
        ("diffusion", DiffusionConfig, DiffusionPolicy, ObsDiffusionConfig, ObsDiffusionPolicy),
    ):
        # model sizes, shared by stock and plugin policies (the stock config's fields only)
        common = {
            k: v for k, v in model_sizes(args.preset, f"obs_{kind}").items() if k in stock_cls.__dataclass_fields__
        }
        stock_extra = {"pretrained_backbone_weights": None}
        if kind == "diffusion":
            stock_extra["crop_shape"] = None
        else:
            stock_extra["n_action_steps"] = 1
        stock_cfg = stock_cls(
            device=args.device,
            input_features={k: v for k, v in inputs.items() if "images" in k or k.endswith("state")},
            output_features=outputs,
            **common,
            **stock_extra,
        )
        stock = stock_policy(stock_cfg).to(device)
        horizon = stock_cfg.chunk_size if kind == "act" else stock_cfg.horizon
        n_obs = None if kind == "act" else stock_cfg.n_obs_steps
        batch = make_batch(frames, batches[kind], horizon, n_obs, device)
        if kind == "diffusion":
            batch["observation.images"] = batch[f"observation.images.{CAM}"].unsqueeze(2)
        base = step_time(stock, batch, args.repeats)
        rows.append(
            {
                "policy": f"stock {kind}",
                "obs_space": "rgb",
                "encoder": "resnet18 (LeRobot)",
                "params_M": round(sum(p.numel() for p in stock.parameters()) / 1e6, 2),
                **base,
                "ratio": 1.0,
            }
        )
        print(f"stock {kind}-resnet18: {base['median_ms']:.0f} ms")
        pairs = PAIRS[args.preset] + ([("pointcloud", "pointnet@2048")] if kind == "act" else [])
        reference = None
        for space, encoder in pairs:
            if encoder == "spunet34" and (problem := spconv_problem(device)):
                skipped.append({"policy": f"obs_{kind}", "obs_space": space, "encoder": encoder, "why": problem})
                print(f"obs_{kind} {space:10s} {encoder:14s}: skipped, {problem}")
                continue
            extra = dict(
                preset_overrides(args.preset, f"obs_{kind}", space, encoder.split("@")[0]),
                encoder=encoder.split("@")[0],
                workspace=list(WORKSPACE),
            )
            if "@" in encoder:
                extra["num_tokens"] = int(encoder.split("@")[1])
            cfg = ours_cls(
                device=args.device,
                obs_space=space,
                input_features=dict(inputs),
                output_features=outputs,
                **{k: v for k, v in extra.items()},
            )
            policy = ours_policy(cfg).to(device)
            t = step_time(policy, batch, args.repeats)
            reference = reference or t
            ratio = round(t["median_ms"] / base["median_ms"], 2)
            rows.append(
                {
                    "policy": f"obs_{kind}",
                    "obs_space": space,
                    "encoder": encoder,
                    "batch": batches[kind],
                    "params_M": round(sum(p.numel() for p in policy.parameters()) / 1e6, 2),
                    **t,
                    "ratio": ratio,
                    f"vs_{pairs[0][0]}_{pairs[0][1]}": round(t["median_ms"] / reference["median_ms"], 2),
                }
            )
            print(
                f"obs_{kind} {space:10s} {encoder:14s}: {t['median_ms']:.0f} ms, {t['steps_per_s']} steps/s "
                f"({ratio}x stock)"
            )
            del policy
            if device.type == "cuda":
                torch.cuda.empty_cache()
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
