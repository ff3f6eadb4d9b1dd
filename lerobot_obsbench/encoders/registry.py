"""String-keyed encoder registry (in the spirit of timm's `create_model`).

Each encoder declares the observation spaces it accepts; `make_encoder` refuses any other pair with a message
listing the valid ones. An encoder built with `output="tokens"` returns `(tokens (B, S, D), pos (B|1, S, D))`
for ACT's transformer; with `output="global"` it returns one feature vector (B, F) for Diffusion Policy's
conditioning. `encoder.out_dim` is D or F.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from torch import nn

from lerobot_obsbench.datasets.schema import OBS_SPACES, check_obs_space

OUTPUTS = ("tokens", "global")


@dataclass(frozen=True)
class EncoderInfo:
    name: str
    spaces: tuple[str, ...]
    summary: str
    build: Callable[..., nn.Module]
    pretrained: str = ""  # which pretrained weights `pretrained=` accepts; empty: trained from scratch only


_REGISTRY: dict[str, EncoderInfo] = {}


def register_encoder(name: str, spaces: tuple[str, ...], summary: str, pretrained: str = ""):
    """Decorator registering `build(obs_space, output, **kwargs) -> nn.Module` under `name`; `pretrained` names
    the weights its `pretrained=` argument loads (empty: none)."""
    unknown = set(spaces) - set(OBS_SPACES)
    if unknown:
        raise ValueError(f"encoder {name!r} declares unknown spaces {sorted(unknown)}")

    def decorator(build: Callable[..., nn.Module]) -> Callable[..., nn.Module]:
        _REGISTRY[name] = EncoderInfo(name, tuple(spaces), summary, build, pretrained)
        return build

    return decorator


def available_encoders(obs_space: str | None = None) -> list[str]:
    """Registered encoder names, optionally only those accepting `obs_space`."""
    if obs_space is None:
        return sorted(_REGISTRY)
    check_obs_space(obs_space)
    return sorted(name for name, info in _REGISTRY.items() if obs_space in info.spaces)


def encoder_info(name: str) -> EncoderInfo:
    if name not in _REGISTRY:
        raise ValueError(f"Unknown encoder {name!r}; registered encoders: {', '.join(sorted(_REGISTRY))}.")
    return _REGISTRY[name]


def valid_pairs() -> str:
    return "; ".join(f"{n}: {', '.join(i.spaces)}" for n, i in sorted(_REGISTRY.items()))


def check_encoder(name: str, obs_space: str) -> None:
    """Raise a ValueError naming the valid (encoder, space) pairs when `name` cannot encode `obs_space`."""
    info = encoder_info(name)
    check_obs_space(obs_space)
    if obs_space not in info.spaces:
        raise ValueError(
            f"Encoder {name!r} does not accept obs_space={obs_space!r}. Encoders for {obs_space!r}: "
            f"{', '.join(available_encoders(obs_space))}. Valid pairs: {valid_pairs()}."
        )


def make_encoder(name: str, obs_space: str, output: str = "tokens", **kwargs) -> nn.Module:
    """Build encoder `name` for `obs_space`; kwargs are encoder-specific (see each builder)."""
    check_encoder(name, obs_space)
    if output not in OUTPUTS:
        raise ValueError(f"output must be one of {OUTPUTS}; got {output!r}")
    return encoder_info(name).build(obs_space=obs_space, output=output, **kwargs)
