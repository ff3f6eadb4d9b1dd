"""Named hyper-parameter presets, as `--policy.*` overrides for stock `lerobot-train`.

- `paper`: the paper's protocol as its official code runs it (docs/paper-differences.md
  lists what stays different and why): the config defaults' model sizes, plus
  ACT's MSE loss and raw-metre point positions, 224 px image inputs (49 ResNet tokens), zero-started extra stem
  channels, the official depth / xyz scaling and point-sampling details, Diffusion Policy's official point-cloud
  head and weight-decay exemptions, gradient clipping at 0.5 and the per-policy OneCycle warm-up. Needs a GPU.
- `cpu`: small models that train in minutes on a 2-core CPU (the main job, `make main`): ResNet-18 instead of ResNet-50
  for images, 128 point tokens, DP3 on xyz scaled to the crop box (DP3's own setting). Not the paper's setting:
  results from it are never a reproduction.
- `dp3`: 3D Diffusion Policy's protocol as its code runs it (`dp3.yaml` and its Meta-World task files; DP3, Ze et
  al., RSS 2024): Diffusion Policy executing 3 of the steps it predicts from 2 observations, DDIM with 10 inference
  steps predicting the sample, DP3's point encoder on 512 xyz points scaled to the crop box; images through
  ResNet-18 (Diffusion Policy's own image baseline). For Diffusion Policy; docs/metaworld.md lists what differs.
  Needs a GPU at DP3's budget (`dp3-metaworld` grid).
- `tiny`: the smallest sizes that still exercise every code path (tests).
- `real-one-arm` / `real-two-arms`: the paper's real-robot tasks (Reach / Pick Cube, Fold Cloth; see
  `lerobot_obsbench.robots.real_tasks`): ACT at lr 5e-5 with chunk 20 / 40, the crop box in the ChArUco world frame.

A preset sets only fields that the run's space and encoder use (the policies refuse values they would ignore):
overrides are keyed by policy type ("*": both) and by the kind of space — "all", "image" (rgb, depth, rgbd,
pointmap), "depth" (image spaces with a depth or xyz channel), "point" — or an encoder's name.

A value the user gives explicitly wins over the preset's: `preset_args(..., user_fields=...)` leaves out the fields
the command already sets, so lerobot-train gets each field once, with the user's value.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

from lerobot_obsbench.encoders import default_encoder
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.schema import POLICY_TYPES, check_choice, space_info

ACT, DP = POLICY_TYPES
# The paper's point-cloud encoders: FPS + kNN tokenizer, its pipeline and heads.
PAPER_POINT_ENCODERS = ("pointnet", "spunet34")

PRESETS: dict[str, dict[tuple[str, str], dict[str, object]]] = {
    "paper": {
        ("*", "all"): {"optimizer_grad_clip_norm": 0.5},
        (ACT, "all"): {"action_loss": "mse", "scheduler_pct_start": 0.1},
        (DP, "all"): {"optimizer_weight_decay": 1e-4, "optimizer_decay_exempt_1d": True, "scheduler_pct_start": 0.15},
        ("*", "image"): {"image_input_size": 224},
        **{("*", stem): {"zero_init_extra_channels": True} for stem in ("resnet18", "resnet50", "vit_b")},
        ("*", "depth"): {"depth_normalization": "official"},
        # the paper's point encoders' tokenizer and heads (DP3 has neither)
        **{("*", enc): {"point_pipeline": "official"} for enc in PAPER_POINT_ENCODERS},
        **{(ACT, enc): {"position_scale": 1.0} for enc in PAPER_POINT_ENCODERS},
        **{(DP, enc): {"dp_point_head": "official"} for enc in PAPER_POINT_ENCODERS},
    },
    # The paper's real-robot set-up (ACT, lr 5e-5, ResNet-50 / PointNet, two RealSense cameras; docs/real-robot.md):
    # crop boxes in the ChArUco board's world frame (z up), jittered by ±1 cm in training.
    "real-one-arm": {
        (ACT, "all"): {"chunk_size": 20, "optimizer_lr": 5e-5},
        ("*", "image"): {"encoder": "resnet50"},
        ("*", "point"): {
            "encoder": "pointnet",
            "workspace": [-0.15, 0.27, -0.5, 0.1, 0.005, 0.3],
            "workspace_jitter": 0.01,
        },
    },
    "real-two-arms": {
        (ACT, "all"): {"chunk_size": 40, "optimizer_lr": 5e-5},
        ("*", "image"): {"encoder": "resnet50"},
        ("*", "point"): {
            "encoder": "pointnet",
            "workspace": [-0.15, 0.35, -0.5, 0.3, 0.005, 0.3],
            "workspace_jitter": 0.01,
        },
    },
    "cpu": {
        (ACT, "all"): {
            "dim_model": 128,
            "n_heads": 4,
            "dim_feedforward": 256,
            "n_encoder_layers": 2,
            "n_vae_encoder_layers": 2,
            "chunk_size": 20,
        },
        (DP, "all"): {"down_dims": [64, 128, 256], "diffusion_step_embed_dim": 64, "num_inference_steps": 20},
        ("*", "image"): {"encoder": "resnet18"},
        ("*", "point"): {"num_tokens": 128},
        # DP3 as its code runs: xyz points scaled to [-1, 1] (here over the crop box)
        ("*", "dp3"): {"point_features": "xyz", "point_normalization": "box"},
    },
    "dp3": {
        (DP, "all"): {
            # DP3 predicts 4 steps; LeRobot's config refuses a horizon that is not a multiple of 2 ** len(down_dims)
            "horizon": 8,
            "n_action_steps": 3,
            "drop_n_last_frames": 4,  # horizon - n_action_steps - n_obs_steps + 1
            "noise_scheduler_type": "DDIM",
            "prediction_type": "sample",
            "num_inference_steps": 10,
            "optimizer_betas": [0.95, 0.999],
            "optimizer_weight_decay": 1e-6,
        },
        ("*", "image"): {"encoder": "resnet18"},
        ("*", "point"): {"encoder": "dp3", "num_tokens": 512},
        ("*", "dp3"): {"point_features": "xyz", "point_normalization": "box"},
    },
    "tiny": {
        (ACT, "all"): {
            "dim_model": 32,
            "n_heads": 2,
            "dim_feedforward": 32,
            "n_encoder_layers": 1,
            "n_vae_encoder_layers": 1,
            "chunk_size": 5,
        },
        (DP, "all"): {
            "down_dims": [16, 32],
            "diffusion_step_embed_dim": 16,
            "horizon": 8,
            "n_action_steps": 4,
            "num_inference_steps": 4,
        },
        ("*", "image"): {"encoder": "resnet18"},
        ("*", "point"): {"num_tokens": 16},
        **{("*", enc): {"knn": 4} for enc in PAPER_POINT_ENCODERS},
    },
}


# Presets that are one policy's protocol, and what they are: the other policy type is refused, not given a part of it.
PROTOCOL_OF = {"dp3": DP}
PRESET_PROTOCOLS = {"dp3": "3D Diffusion Policy's protocol (DP3)"}


def space_kinds(obs_space: str) -> tuple[str, ...]:
    """The preset keys a space takes: `all`, and `image`, `depth`, `point` where it (or a part of it) is one."""
    space = space_info(obs_space)
    return (
        "all",
        *(
            kind
            for kind, applies in (("image", space.image), ("depth", space.depth), ("point", space.points))
            if applies
        ),
    )


def _merged(preset: str, policy_type: str, kinds) -> dict[str, object]:
    overrides: dict[str, object] = {}
    for kind in kinds:
        for policy in ("*", policy_type):
            overrides.update(PRESETS[preset].get((policy, kind), {}))
    return overrides


def preset_encoder(preset: str, obs_space: str) -> str:
    """The encoder a preset uses for `obs_space` when none is named (for a fused space, its parts' joined)."""
    if space_info(obs_space).fused:
        return "+".join(preset_encoder(preset, part) for part in space_info(obs_space).parts)
    return str(_merged(preset, ACT, space_kinds(obs_space)).get("encoder") or default_encoder(obs_space))


def check_preset_policy(preset: str, policy_type: str) -> None:
    """Refuse a preset for a policy type it does not describe (a protocol of one policy: `PROTOCOL_OF`)."""
    check_choice("preset", preset, PRESETS)
    check_choice("policy type", policy_type, POLICY_TYPES)
    protocol = PROTOCOL_OF.get(preset)
    if protocol is not None and policy_type != protocol:
        others = ", ".join(p for p in PRESETS if p not in PROTOCOL_OF)
        raise ConfigError(
            f"preset {preset} is {PRESET_PROTOCOLS[preset]}, a {protocol} protocol; it describes no {policy_type}: "
            f"use --policy {protocol}, or for {policy_type} one of the presets {others}"
        )


def preset_overrides(preset: str, policy_type: str, obs_space: str, encoder: str | None = None) -> dict[str, object]:
    """The preset's `--policy.*` fields for a run with `encoder` (None: the preset's encoder for the space); a fused
    space's encoder is the pair of its parts' encoders the preset names."""
    check_preset_policy(preset, policy_type)
    encoders = (encoder or preset_encoder(preset, obs_space)).split("+")  # a fused space's: each part's fields
    fields = _merged(preset, policy_type, (*space_kinds(obs_space), *encoders))
    if space_info(obs_space).fused:
        fields["encoder"] = preset_encoder(preset, obs_space)  # a part's choice stands for the pair
    return fields


def model_sizes(preset: str, policy_type: str) -> dict[str, object]:
    """The preset's overrides that every space shares (model sizes and training recipe)."""
    check_choice("preset", preset, PRESETS)
    return _merged(preset, policy_type, ("all",))


def cli_value(value) -> str:
    """A field's value as lerobot-train's command line takes it (a list as `[a,b]`)."""
    return "[" + ",".join(str(v) for v in value) + "]" if isinstance(value, (list, tuple)) else str(value)


def policy_flags(fields: Mapping[str, object]) -> list[str]:
    """`--policy.<field>=<value>` arguments for stock lerobot-train."""
    return [f"--policy.{name}={cli_value(value)}" for name, value in fields.items()]


def preset_args(
    preset: str, policy_type: str, obs_space: str, encoder: str | None = None, user_fields: Collection[str] = ()
) -> list[str]:
    """The preset's `--policy.*` arguments for stock lerobot-train, but for `user_fields`: the command sets those to
    the user's own values, which win, and lerobot-train gets each field once."""
    fields = preset_overrides(preset, policy_type, obs_space, encoder)
    return policy_flags({name: value for name, value in fields.items() if name not in user_fields})
