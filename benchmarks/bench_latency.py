"""Per-step latency of a trained policy: sensor frame(s) -> action, at the paper's model sizes.

obs_act at the config defaults (the paper's: hidden 512, 4 encoder layers, chunk 100, temporal ensembling, so the
policy runs every control step) for each space with the paper's encoder (ResNet-50 for image spaces, PointNet for
point clouds, at 2,048 tokens as the paper and at 512), on ray-cast cluttered scenes in two set-ups:

- `sim128`: one 128x128 RGB-D camera (the simulated benchmark);
- `real640`: two 640x480 RGB-D cameras around the paper's one-arm crop box (the real robot, preset
  `real-one-arm`).

Each step is broken down into preprocessing (the observation adapter: normalisation, or unproject -> crop -> voxel;
for point clouds also FPS -> kNN), the encoder (the rest of the observation encoder), the transformer (ACT's
encoder + decoder) and the rest (state / latent projections, action head, temporal ensembling). obs_diffusion
(the paper's DP sizes, 100 denoising steps) is timed per action chunk: observation encoding + the denoiser.
LeRobot's normalising processor (microseconds) is not included.

`--baseline REF` times the same rows with the package as of git revision REF (the code before a change),
interleaved with the working tree's, in this one run, and reports each ratio.

    .venv/bin/python -m benchmarks.bench_latency [--setups sim128 real640] [--baseline REF] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from benchmarks.common import ROOT, load_synthetic, write

SETUPS = {
    # cameras (name, eye), image (H, W), crop box (world frame, table at z = 0), where the clutter lies (x, y ranges)
    "sim128": {
        "cameras": [("base_camera", (0.45, 0.0, 0.55))],
        "size": (128, 128),
        "workspace": (-0.6, 0.6, -0.6, 0.6, 0.005, 0.8),
        "clutter": ((-0.25, 0.25), (-0.25, 0.25)),
    },
    "real640": {
        "cameras": [("left", (0.55, -0.2, 0.5)), ("right", (-0.45, -0.2, 0.5))],
        "size": (480, 640),
        "workspace": (-0.15, 0.27, -0.5, 0.1, 0.005, 0.3),
        "clutter": ((-0.12, 0.24), (-0.45, 0.05)),
    },
}
ROWS = [
    ("rgb", "resnet50", None),
    ("depth", "resnet50", None),
    ("rgbd", "resnet50", None),
    ("pointmap", "resnet50", None),
    ("pointcloud", "pointnet", 2048),
    ("pointcloud", "pointnet", 512),
]
STATE_DIM, ACTION_DIM = 15, 7


def scene(setup: dict, seed: int = 0) -> dict:
    """One frame per camera of 12 random boxes (3-9 cm) on the table, in the dataset schema's layout."""
    synthetic = load_synthetic()
    rng = np.random.default_rng(seed)
    (x0, x1), (y0, y1) = setup["clutter"]
    boxes = []
    for _ in range(12):
        half = rng.uniform(0.015, 0.045)
        centre = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1), half])
        boxes.append((centre, half, tuple(int(c) for c in rng.integers(0, 255, 3))))
    target = ((x0 + x1) / 2, (y0 + y1) / 2, 0.0)
    h, w = setup["size"]
    batch = {}
    for name, eye in setup["cameras"]:
        K = synthetic.intrinsics(w)
        K[1, 2] = h / 2
        cam2world = synthetic.look_at(eye=eye, target=target)
        rgb, depth, _ = synthetic.render(K, cam2world, (h, w), boxes)
        batch[f"observation.images.{name}"] = torch.tensor(rgb).permute(2, 0, 1)[None].float() / 255
        batch[f"observation.depth.{name}"] = torch.tensor(depth.astype(np.int64))[None]
        batch[f"observation.intrinsics.{name}"] = torch.tensor(K, dtype=torch.float32)[None]
        batch[f"observation.cam2world.{name}"] = torch.tensor(cam2world, dtype=torch.float32)[None]
    batch["observation.state"] = torch.zeros(1, STATE_DIM)
    return batch


def make_policy(kind: str, setup: dict, space: str, encoder: str, tokens: int | None, device):
    from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig
    from lerobot_obsbench.policies.obs_act.modeling_obs_act import ObsACTPolicy
    from lerobot_obsbench.policies.obs_diffusion.modeling_obs_diffusion import ObsDiffusionPolicy

    h, w = setup["size"]
    inputs = {"observation.state": PolicyFeature(FeatureType.STATE, (STATE_DIM,))}
    for name, _ in setup["cameras"]:
        inputs[f"observation.images.{name}"] = PolicyFeature(FeatureType.VISUAL, (3, h, w))
        inputs[f"observation.depth.{name}"] = PolicyFeature(FeatureType.STATE, (h, w, 1))
        inputs[f"observation.intrinsics.{name}"] = PolicyFeature(FeatureType.STATE, (3, 3))
        inputs[f"observation.cam2world.{name}"] = PolicyFeature(FeatureType.STATE, (4, 4))
    extra = {"num_tokens": tokens} if tokens else {}
    if space == "pointcloud":
        extra["workspace"] = list(setup["workspace"])
    config_cls, policy_cls = (ObsACTConfig, ObsACTPolicy) if kind == "act" else (ObsDiffusionConfig, ObsDiffusionPolicy)
    config = config_cls(
        device=str(device),
        obs_space=space,
        encoder=encoder,
        cameras=[name for name, _ in setup["cameras"]],
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))},
        **extra,
    )
    return policy_cls(config).to(device).eval()


class Stopwatch:
    """Wall time spent inside chosen modules and functions, summed per label (nested labels are separate)."""

    def __init__(self, device):
        self.device, self.totals = device, {}

    def _sync(self):
        if self.device.type == "cuda":
            torch.cuda.synchronize()

    @contextmanager
    def span(self, label: str):
        self._sync()
        start = time.perf_counter()
        try:
            yield
        finally:
            self._sync()
            self.totals[label] = self.totals.get(label, 0.0) + (time.perf_counter() - start) * 1000

    def module(self, module: torch.nn.Module, label: str) -> None:
        spans = {}

        def before(*_):
            spans[id(module)] = self.span(label)
            spans[id(module)].__enter__()

        def after(*_):
            spans.pop(id(module)).__exit__(None, None, None)

        module.register_forward_pre_hook(before)
        module.register_forward_hook(after)

    def function(self, owner, name: str, label: str) -> None:
        original = getattr(owner, name)

        def wrapped(*args, **kwargs):
            with self.span(label):
                return original(*args, **kwargs)

        setattr(owner, name, wrapped)


def median(values: list[float]) -> float:
    return round(float(np.median(values)), 2)


def time_act(policy, batch: dict, repeats: int, device) -> dict:
    from lerobot_obsbench.encoders import point_tokenizer

    watch = Stopwatch(device)
    model = policy.model
    watch.module(model.observation.adapter, "adapter")
    watch.module(model.observation, "observation")
    watch.module(model.encoder, "transformer")
    watch.module(model.decoder, "transformer")
    watch.function(point_tokenizer, "group", "fps_knn")
    steps = {"total": [], "preprocess": [], "encoder": [], "transformer": [], "rest": []}
    policy.reset()
    with torch.inference_mode():
        for i in range(repeats + 2):
            watch.totals = {}
            with watch.span("total"):
                policy.select_action(batch)
            if i < 2:  # warm-up
                continue
            t = watch.totals
            preprocess = t["adapter"] + t.get("fps_knn", 0.0)
            encoder = t["observation"] - preprocess
            for key, value in (
                ("total", t["total"]),
                ("preprocess", preprocess),
                ("encoder", encoder),
                ("transformer", t["transformer"]),
                ("rest", t["total"] - t["observation"] - t["transformer"]),
            ):
                steps[key].append(value)
    return {f"{key}_ms": median(values) for key, values in steps.items()}


def time_diffusion(policy, batch: dict, repeats: int, device) -> dict:
    watch = Stopwatch(device)
    watch.module(policy.diffusion.observation, "observation")
    watch.module(policy.diffusion.unet, "denoiser")
    chunks = {"chunk": [], "observation": [], "denoiser": []}
    with torch.inference_mode():
        for i in range(repeats + 1):
            policy.reset()  # empty queues: this select_action generates a chunk
            watch.totals = {}
            with watch.span("chunk"):
                policy.select_action(batch)
            if i:
                for key in chunks:
                    chunks[key].append(watch.totals[key])
    out = {f"{key}_ms": median(values) for key, values in chunks.items()}
    return {
        **out,
        "inference_steps": policy.diffusion.num_inference_steps,
        "action_steps_per_chunk": policy.config.n_action_steps,
    }


def measure(setups: list[str], device_name: str, repeats: int, diffusion: bool, spaces: list[str]) -> list[dict]:
    import lerobot_obsbench

    torch.manual_seed(0)
    device = torch.device(device_name)
    rows = []
    for setup_name in setups:
        setup = SETUPS[setup_name]
        batch = {k: v.to(device) for k, v in scene(setup).items()}
        rows_here = [row for row in ROWS if row[0] in spaces]
        for space, encoder, tokens in rows_here:
            policy = make_policy("act", setup, space, encoder, tokens, device)
            label = f"{encoder}@{tokens}" if tokens else encoder
            row = {"setup": setup_name, "policy": "obs_act", "obs_space": space, "encoder": label}
            row["code"] = str(Path(lerobot_obsbench.__file__).parent)
            row.update(time_act(policy, batch, repeats, device))
            print(json.dumps(row), flush=True)
            rows.append(row)
        if diffusion:
            for space, encoder, tokens in rows_here:
                if tokens == 512:  # DP's point-cloud feature is one global vector: no token count to vary
                    continue
                policy = make_policy("diffusion", setup, space, encoder, tokens, device)
                row = {"setup": setup_name, "policy": "obs_diffusion", "obs_space": space, "encoder": encoder}
                row.update(time_diffusion(policy, batch, max(repeats // 5, 1), device))
                print(json.dumps(row), flush=True)
                rows.append(row)
    return rows


def measure_revision(ref: str, args) -> list[dict]:
    """`measure` in a subprocess whose `lerobot_obsbench` is the package as of git revision `ref`."""
    with tempfile.TemporaryDirectory() as tmp:
        archive = Path(tmp) / "code.tar"
        subprocess.run(["git", "archive", "-o", str(archive), ref, "lerobot_obsbench"], cwd=ROOT, check=True)
        with tarfile.open(archive) as tar:
            tar.extractall(tmp, filter="data")
        command = [sys.executable, "-m", "benchmarks.bench_latency", "--worker", *worker_args(args)]
        # `-m` puts the working directory first on sys.path: run from the extracted revision, the benchmark
        # itself coming from this checkout through PYTHONPATH
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([tmp, str(ROOT)])}
        done = subprocess.run(command, cwd=tmp, env=env, check=True, capture_output=True, text=True)
        return json.loads(done.stdout.strip().splitlines()[-1])


def worker_args(args) -> list[str]:
    return [
        "--setups",
        *args.setups,
        "--device",
        args.device,
        "--repeats",
        str(args.repeats),
        *(["--no-diffusion"] if args.no_diffusion else []),
        "--spaces",
        *args.spaces,
    ]


def summarise(rows: list[dict]) -> dict:
    """Per set-up: each row's step against rgb / ResNet-50, and the point-cloud preprocessing figure."""
    out = {}
    for setup in SETUPS:
        act = {r["obs_space"] + "/" + r["encoder"]: r for r in rows if r["setup"] == setup and r["policy"] == "obs_act"}
        if "rgb/resnet50" not in act:
            continue
        rgb = act["rgb/resnet50"]["total_ms"]
        out[setup] = {name: round(r["total_ms"] / rgb, 2) for name, r in act.items()}
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--setups", nargs="+", default=list(SETUPS), choices=list(SETUPS))
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--no-diffusion", action="store_true", help="leave out the Diffusion Policy rows")
    spaces = list(dict.fromkeys(space for space, _, _ in ROWS))
    parser.add_argument("--spaces", nargs="+", default=spaces, choices=spaces)
    parser.add_argument("--baseline", help="git revision to time side by side (the code before a change)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    if args.worker:  # one revision's rows, as JSON on the last line
        print(json.dumps(measure(args.setups, args.device, args.repeats, not args.no_diffusion, args.spaces)))
        return
    result = {"device": args.device, "repeats": args.repeats, "setups": {k: SETUPS[k] for k in args.setups}}
    if args.baseline:
        # both revisions in subprocesses, one after the other per set-up, so each pair shares the machine's state
        current, before = [], []
        for setup in args.setups:
            one = argparse.Namespace(**{**vars(args), "setups": [setup]})
            before += measure_revision(args.baseline, one)
            current += measure_local(one)
        result["baseline"] = {"revision": args.baseline, "rows": before, "vs_rgb": summarise(before)}
        result["speedup_vs_baseline"] = [
            {
                **{k: now[k] for k in ("setup", "policy", "obs_space", "encoder")},
                "baseline_code": old.get("code"),
                **{
                    key: round(old[key] / now[key], 2)
                    for key in now
                    if key.endswith("_ms") and old.get(key) and now[key] > 0.05
                },
            }
            for now, old in zip(current, before, strict=True)
        ]
    else:
        current = measure(args.setups, args.device, args.repeats, not args.no_diffusion, args.spaces)
    result["rows"], result["vs_rgb"] = current, summarise(current)
    write(f"latency_{args.device}", result, args.out)


def measure_local(args) -> list[dict]:
    """`measure` for the working tree, in a subprocess like the baseline's."""
    command = [sys.executable, "-m", "benchmarks.bench_latency", "--worker", *worker_args(args)]
    done = subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    main()
