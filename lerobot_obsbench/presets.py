"""Named hyper-parameter presets, as `--policy.*` overrides for stock `lerobot-train`.

- `paper`: the config defaults themselves (Appendix C of the paper; DESIGN §6). Needs a GPU.
- `cpu`: small models that train in minutes on a 2-core CPU (README main job): ResNet-18 instead of ResNet-50
  for images, 128 point tokens. Not the paper's setting: results from it are smoke tests, never a reproduction.
- `tiny`: the smallest sizes that still exercise every code path (tests).

A preset only sets fields that the run's space uses: point-cloud fields for point clouds, the image encoder
for image spaces (the policies refuse values they would ignore).
"""

from __future__ import annotations

from lerobot_obsbench.encoders import default_encoder
from lerobot_obsbench.schema import IMAGE_SPACES, POINT_SPACES, POLICY_TYPES, check_choice

# Model sizes per preset and policy.
PRESETS: dict[str, dict[str, dict[str, object]]] = {
    "paper": {"obs_act": {}, "obs_diffusion": {}},
    "cpu": {
        "obs_act": {
            "dim_model": 128,
            "n_heads": 4,
            "dim_feedforward": 256,
            "n_encoder_layers": 2,
            "n_vae_encoder_layers": 2,
            "chunk_size": 20,
        },
        "obs_diffusion": {"down_dims": [64, 128, 256], "diffusion_step_embed_dim": 64, "num_inference_steps": 20},
    },
    "tiny": {
        "obs_act": {
            "dim_model": 32,
            "n_heads": 2,
            "dim_feedforward": 32,
            "n_encoder_layers": 1,
            "n_vae_encoder_layers": 1,
            "chunk_size": 5,
        },
        "obs_diffusion": {
            "down_dims": [16, 32],
            "diffusion_step_embed_dim": 16,
            "horizon": 8,
            "n_action_steps": 4,
            "num_inference_steps": 4,
        },
    },
}
# Point tokenizer sizes per preset (point-cloud spaces only).
POINT_OVERRIDES: dict[str, dict[str, object]] = {
    "paper": {},
    "cpu": {"num_tokens": 128},
    "tiny": {"num_tokens": 16, "knn": 4},
}
# Image encoder per preset (image spaces only); None: the registry's default (the paper's ResNet-50).
IMAGE_ENCODER: dict[str, str | None] = {"paper": None, "cpu": "resnet18", "tiny": "resnet18"}


def preset_overrides(preset: str, policy_type: str, obs_space: str) -> dict[str, object]:
    check_choice("preset", preset, PRESETS)
    check_choice("policy type", policy_type, POLICY_TYPES)
    overrides = dict(PRESETS[preset][policy_type])
    if obs_space in POINT_SPACES:
        overrides.update(POINT_OVERRIDES[preset])
    if obs_space in IMAGE_SPACES and IMAGE_ENCODER[preset]:
        overrides["encoder"] = IMAGE_ENCODER[preset]
    return overrides


def preset_encoder(preset: str, obs_space: str) -> str:
    """The encoder a preset uses for `obs_space` when none is named."""
    return str(preset_overrides(preset, POLICY_TYPES[0], obs_space).get("encoder") or default_encoder(obs_space))


def preset_args(preset: str, policy_type: str, obs_space: str) -> list[str]:
    """`--policy.<field>=<value>` arguments for stock lerobot-train."""
    args = []
    for name, value in preset_overrides(preset, policy_type, obs_space).items():
        text = "[" + ",".join(str(v) for v in value) + "]" if isinstance(value, list) else str(value)
        args.append(f"--policy.{name}={text}")
    return args
