"""String-keyed encoder registry (in the spirit of timm's `create_model` and robomimic's encoder core).

Each registered encoder states its contract:
- the observation spaces it accepts (`make_encoder` refuses any other pair, listing the valid ones);
- the keyword options its builder takes, read from the builder's signature (an unknown keyword is refused,
  naming the accepted ones: a typo never passes silently); a parameter whose default is a dataclass instance
  is an option set shared by several encoders (the point tokenizer's): its fields are options of the encoder,
  gathered back into one instance when it is built;
- what it outputs, before anything is built (`encoder_output`): with `output="tokens"`, `(tokens (B, S, D),
  pos (B|1, S, D))` for ACT's transformer; with `output="global"`, one feature vector (B, F) for Diffusion
  Policy's conditioning;
- the spaces it is the default encoder of (one default per space; declared here only);
- the values an option may take where they are a fixed set (`choices`, e.g. the normalisation layers `norm`
  offers), checked before anything is built; None always means the builder's own default.

Names are unique: registering a name twice is an error.

A fused space (a `schema.Space` with parts, e.g. rgb+pointcloud) is encoded by one registered encoder per part,
named by their names joined the same way (`spatial_softmax+dp3`): `FusedEncoder` runs each on its part's input and
puts their tokens side by side (ACT) or concatenates their features (Diffusion Policy). Its options are its parts'
options, each passed to every part that takes it (one `norm` value sets both parts' normalisation).
"""

from __future__ import annotations

import dataclasses
import inspect
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import nn

from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.schema import available_spaces, check_obs_space, space_info

OUTPUTS = ("tokens", "global")
# Builder parameters every encoder has; the rest of a builder's signature are its options.
BUILD_ARGS = ("obs_space", "output", "dim")


class EncoderError(ObsBenchError, ValueError):
    """An encoder name, option or space pairing that cannot be built, or an encoder registered wrongly."""


class EncoderOptionError(EncoderError, TypeError):
    """An option the encoder's builder does not take (a TypeError, as a wrong keyword argument is)."""


@dataclass(frozen=True)
class EncoderOutput:
    """What an encoder produces per sample: `tokens` tokens of width `width` (ACT), or one feature vector of
    size `width` (Diffusion Policy; `tokens` is None)."""

    tokens: int | None
    width: int


@dataclass(frozen=True)
class EncoderContext:
    """What an encoder's declared output depends on besides its options: the camera count and frame size."""

    cameras: int = 1
    image_size: tuple[int, int] | None = None  # (height, width); None for point clouds


@dataclass(frozen=True)
class EncoderInfo:
    name: str
    spaces: tuple[str, ...]
    summary: str
    build: Callable[..., nn.Module]
    # describe(obs_space, output, dim, context, options) -> EncoderOutput, with `options` the builder's
    # keyword options as they will be passed (defaults filled in).
    describe: Callable[..., EncoderOutput]
    options: tuple[str, ...]
    defaults: dict
    pretrained: str = ""  # which pretrained weights `pretrained=` accepts; empty: trained from scratch only
    default_for: tuple[str, ...] = ()
    # builder parameter -> the dataclass of the option set it takes (its fields are in `options`)
    option_sets: dict[str, type] = field(default_factory=dict)
    # option -> the values it accepts (None, the builder's default, always)
    choices: dict[str, tuple] = field(default_factory=dict)


_REGISTRY: dict[str, EncoderInfo] = {}


def register_encoder(
    name: str,
    spaces: tuple[str, ...],
    summary: str,
    describe: Callable[..., EncoderOutput],
    pretrained: str = "",
    default_for: tuple[str, ...] = (),
    choices: dict[str, tuple] | None = None,
):
    """Decorator registering `build(obs_space, output, dim, *, <options>) -> nn.Module` under `name`.

    `describe` states the output for a configuration before building; `pretrained` names the weights the
    `pretrained=` option loads (empty: none); `default_for` lists the spaces this encoder is the default of;
    `choices` the values of options that take one of a fixed set.
    """
    unknown = set(spaces) - set(available_spaces())
    if unknown:
        raise EncoderError(f"encoder {name!r} declares unknown spaces {sorted(unknown)}")
    if not set(default_for) <= set(spaces):
        raise EncoderError(f"encoder {name!r} cannot be the default of spaces it does not accept: {default_for}")

    def decorator(build: Callable[..., nn.Module]) -> Callable[..., nn.Module]:
        if name in _REGISTRY:
            raise EncoderError(f"an encoder named {name!r} is already registered ({_REGISTRY[name].summary})")
        params = inspect.signature(build).parameters
        if any(p.kind in (p.VAR_KEYWORD, p.VAR_POSITIONAL) for p in params.values()):
            raise EncoderError(f"encoder {name!r}: the builder must name its options (no *args / **kwargs)")
        if tuple(params)[: len(BUILD_ARGS)] != BUILD_ARGS:
            raise EncoderError(f"encoder {name!r}: the builder's first parameters must be {BUILD_ARGS}")
        for space in default_for:
            taken = [i.name for i in _REGISTRY.values() if space in i.default_for]
            if taken:
                raise EncoderError(f"encoder {name!r}: {taken[0]!r} is already the default encoder of {space!r}")
        options, defaults, option_sets = [], {}, {}
        for key in tuple(params)[len(BUILD_ARGS) :]:
            default = params[key].default
            if dataclasses.is_dataclass(default):  # an option set: its fields are the options
                option_sets[key] = type(default)
                fields = {f.name: getattr(default, f.name) for f in dataclasses.fields(default)}
                options += fields
                defaults.update(fields)
                continue
            options.append(key)
            if default is not inspect.Parameter.empty:
                defaults[key] = default
        unknown_choices = sorted(set(choices or {}) - set(options))
        if unknown_choices:
            raise EncoderError(f"encoder {name!r}: choices given for options it does not take: {unknown_choices}")
        _REGISTRY[name] = EncoderInfo(
            name,
            tuple(spaces),
            summary,
            build,
            describe,
            tuple(options),
            defaults,
            pretrained,
            tuple(default_for),
            option_sets,
            dict(choices or {}),
        )
        return build

    return decorator


def available_encoders(obs_space: str | None = None) -> list[str]:
    """Registered encoder names, optionally only those accepting `obs_space` (for a fused space: every pair of
    encoders of its parts)."""
    if obs_space is None:
        return sorted(_REGISTRY)
    parts = space_info(obs_space).parts
    if parts:
        return ["+".join(names) for names in itertools.product(*map(available_encoders, parts))]
    return sorted(name for name, info in _REGISTRY.items() if obs_space in info.spaces)


def encoder_info(name: str) -> EncoderInfo:
    if name in _REGISTRY:
        return _REGISTRY[name]
    parts = name.split("+")
    if len(parts) > 1 and all(part in _REGISTRY for part in parts):
        return _fused_info(tuple(parts))
    raise EncoderError(
        f"Unknown encoder {name!r}; registered encoders: {', '.join(sorted(_REGISTRY))} (a fused space takes one "
        f"per part joined by '+', e.g. {default_encoder(available_spaces(lambda s: s.fused)[0])})."
    )


class FusedEncoder(nn.Module):
    """One encoder per part of a fused space: inputs (one per part) -> the parts' tokens side by side with their
    positions (ACT), or their features concatenated (Diffusion Policy)."""

    def __init__(self, parts: list[nn.Module], output: str):
        super().__init__()
        self.parts, self.output = nn.ModuleList(parts), output

    def forward(self, inputs: tuple) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        outs = [part(x) for part, x in zip(self.parts, inputs, strict=True)]
        if self.output == "global":
            return torch.cat(outs, dim=-1)
        tokens = torch.cat([t for t, _ in outs], dim=1)
        batch = max(p.shape[0] for _, p in outs)
        return tokens, torch.cat([p.expand(batch, *p.shape[1:]) for _, p in outs], dim=1)


def _fused_info(parts: tuple[str, ...]) -> EncoderInfo:
    infos = [_REGISTRY[p] for p in parts]

    def accepted(space) -> bool:
        pairs = zip(space.parts, infos, strict=False)
        return len(space.parts) == len(infos) and all(part in info.spaces for part, info in pairs)

    spaces = available_spaces(accepted)
    if not spaces:
        fused = [space_info(name) for name in available_spaces(lambda s: s.fused)]
        raise EncoderError(
            f"encoder {'+'.join(parts)!r}: no fused space has parts these encoders accept in this order "
            f"(fused spaces: {', '.join(f'{s.name} = {" + ".join(s.parts)}' for s in fused)})"
        )
    options = tuple(dict.fromkeys(o for i in infos for o in i.options))
    choices: dict[str, tuple] = {}  # a shared option takes the values every part that offers a set allows
    for info in infos:
        for option, allowed in info.choices.items():
            choices[option] = tuple(v for v in choices.get(option, allowed) if v in allowed)

    def split(options_given: dict) -> list[dict]:
        return [{k: v for k, v in options_given.items() if k in i.options} for i in infos]

    def build(obs_space: str, output: str, dim: int, **given) -> FusedEncoder:
        pieces = zip(parts, space_info(obs_space).parts, split(given), strict=True)
        return FusedEncoder([make_encoder(n, sp, output, dim, **o) for n, sp, o in pieces], output)

    def describe(obs_space: str, output: str, dim: int, context: EncoderContext, given: dict) -> EncoderOutput:
        outs = [
            i.describe(sp, output, dim, context, {**i.defaults, **o})
            for i, sp, o in zip(infos, space_info(obs_space).parts, split(given), strict=True)
        ]
        if output == "tokens":
            return EncoderOutput(sum(o.tokens for o in outs), dim)
        return EncoderOutput(None, sum(o.width for o in outs))

    return EncoderInfo(
        "+".join(parts),
        spaces,
        " + ".join(i.name for i in infos) + ", side by side",
        build,
        describe,
        options,
        {k: v for i in reversed(infos) for k, v in i.defaults.items()},  # a shared option's default: the first part's
        choices=choices,
    )


def default_encoder(obs_space: str) -> str:
    """The registry's default encoder for `obs_space` (the paper's choice; for a fused space, its parts')."""
    parts = space_info(obs_space).parts
    if parts:
        return "+".join(default_encoder(part) for part in parts)
    for info in _REGISTRY.values():
        if obs_space in info.default_for:
            return info.name
    raise EncoderError(f"no encoder is registered as the default for obs_space={obs_space!r}")


def valid_pairs() -> str:
    return "; ".join(f"{n}: {', '.join(i.spaces)}" for n, i in sorted(_REGISTRY.items()))


def check_encoder(name: str, obs_space: str) -> None:
    """Raise a ValueError naming the valid (encoder, space) pairs when `name` cannot encode `obs_space`."""
    info = encoder_info(name)
    check_obs_space(obs_space)
    if obs_space not in info.spaces:
        raise EncoderError(
            f"Encoder {name!r} does not accept obs_space={obs_space!r}. Encoders for {obs_space!r}: "
            f"{', '.join(available_encoders(obs_space))}. Valid pairs: {valid_pairs()}."
        )


def _checked(name: str, obs_space: str, output: str, options: dict) -> EncoderInfo:
    check_encoder(name, obs_space)
    if output not in OUTPUTS:
        raise EncoderError(f"output must be one of {OUTPUTS}; got {output!r}")
    info = encoder_info(name)
    unknown = sorted(set(options) - set(info.options))
    if unknown:
        raise EncoderOptionError(
            f"encoder {name!r} takes no option(s) {unknown}; it accepts: {', '.join(info.options)}"
        )
    for option, allowed in info.choices.items():
        value = options.get(option)
        if value is not None and value not in allowed:
            raise EncoderError(f"encoder {name!r}: {option}={value!r} is not one of {', '.join(map(str, allowed))}")
    return info


def make_encoder(name: str, obs_space: str, output: str = "tokens", dim: int = 512, **options) -> nn.Module:
    """Build encoder `name` for `obs_space`; `options` are the encoder's own (`encoder_info(name).options`)."""
    info = _checked(name, obs_space, output, options)
    if space_info(obs_space).fused:
        return info.build(obs_space, output, dim, **options)
    for key, option_set in info.option_sets.items():  # gather a shared option set's fields into one instance
        names = {f.name for f in dataclasses.fields(option_set)}
        options = {
            **{k: v for k, v in options.items() if k not in names},
            key: option_set(**{k: v for k, v in options.items() if k in names}),
        }
    return info.build(obs_space, output, dim, **options)


def encoder_output(
    name: str,
    obs_space: str,
    output: str = "tokens",
    dim: int = 512,
    context: EncoderContext = EncoderContext(),
    **options,
) -> EncoderOutput:
    """What `make_encoder(name, obs_space, output, dim, **options)` will output, without building it."""
    info = _checked(name, obs_space, output, options)
    return info.describe(obs_space, output, dim, context, {**info.defaults, **options})
