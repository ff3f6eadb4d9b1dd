"""Named hyper-parameter presets, as `--policy.*` overrides for stock `lerobot-train`.

- `paper`: the config defaults themselves (Appendix C of the paper; DESIGN §6). Needs a GPU.
- `cpu`: small models that train in minutes on a 2-core CPU (README main job). Not the paper's setting:
  results from it are smoke tests of the pipeline, never a reproduction.
- `tiny`: the smallest sizes that still exercise every code path (tests).
"""

from __future__ import annotations

PRESETS: dict[str, dict[str, dict[str, object]]] = {
    "paper": {"obs_act": {}, "obs_diffusion": {}},
    "cpu": {
        "obs_act": {
            "dim_model": 128, "n_heads": 4, "dim_feedforward": 256, "n_encoder_layers": 2,
            "n_vae_encoder_layers": 2, "chunk_size": 20, "num_tokens": 128, "knn": 16,
        },
        "obs_diffusion": {
            "down_dims": [64, 128, 256], "diffusion_step_embed_dim": 64, "num_tokens": 128, "knn": 16,
            "num_inference_steps": 20,
        },
    },
    "tiny": {
        "obs_act": {
            "dim_model": 32, "n_heads": 2, "dim_feedforward": 32, "n_encoder_layers": 1,
            "n_vae_encoder_layers": 1, "chunk_size": 5, "num_tokens": 16, "knn": 4,
        },
        "obs_diffusion": {
            "down_dims": [16, 32], "diffusion_step_embed_dim": 16, "horizon": 8, "n_action_steps": 4,
            "num_tokens": 16, "knn": 4, "num_inference_steps": 4,
        },
    },
}
# Image encoders on CPU presets: ResNet-18 instead of the paper's ResNet-50.
CPU_IMAGE_ENCODER = "resnet18"


def default_encoder(preset: str, obs_space: str) -> str:
    """The encoder a preset uses for `obs_space` when none is named."""
    from lerobot_obsbench.policies.common import DEFAULT_ENCODER

    if preset != "paper" and obs_space != "pointcloud":
        return CPU_IMAGE_ENCODER
    return DEFAULT_ENCODER[obs_space]


def preset_overrides(preset: str, policy_type: str, obs_space: str) -> dict[str, object]:
    if preset not in PRESETS:
        raise ValueError(f"Unknown preset {preset!r}; choose one of {', '.join(PRESETS)}.")
    if policy_type not in PRESETS[preset]:
        raise ValueError(f"Unknown policy type {policy_type!r}; choose one of {', '.join(PRESETS[preset])}.")
    overrides = dict(PRESETS[preset][policy_type])
    if preset != "paper":
        overrides["encoder"] = default_encoder(preset, obs_space)
    return overrides


def preset_args(preset: str, policy_type: str, obs_space: str) -> list[str]:
    """`--policy.<field>=<value>` arguments for stock lerobot-train."""
    args = []
    for name, value in preset_overrides(preset, policy_type, obs_space).items():
        text = "[" + ",".join(str(v) for v in value) + "]" if isinstance(value, list) else str(value)
        args.append(f"--policy.{name}={text}")
    return args
