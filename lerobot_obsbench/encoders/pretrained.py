"""Pretrained checkpoints in their official key layouts: where they come from and how they load.

`pretrained=` is a local file, or a Hugging Face Hub file written `ORG/REPO:FILENAME` (downloaded only when
given, with a short timeout: an offline machine gets a clear error, not a hang). `load_matching` loads a state
dict into a module and reports what it did: every module key must be found with the right shape (a shape
mismatch means a checkpoint of another architecture and fails), checkpoint keys the module does not use are
counted in the report (decoders, language heads...).

Licences of the official weights (the user downloads them; nothing here ships them): R3M — MIT; VC-1 —
CC-BY-NC 4.0 (non-commercial); MultiMAE — CC-BY-NC 4.0 (non-commercial); PonderV2 — MIT (check each model
card before use).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import torch
from torch import Tensor, nn

from lerobot_obsbench.errors import ObsBenchError

logger = logging.getLogger(__name__)
HUB_ID = re.compile(r"^[\w.-]+/[\w.-]+:.+$")


class CheckpointError(ObsBenchError, ValueError):
    """A checkpoint that cannot be found, fetched, or loaded into the encoder."""


def resolve_checkpoint(pretrained: str) -> Path:
    path = Path(pretrained).expanduser()
    if path.is_file():
        return path
    if not HUB_ID.match(pretrained):
        raise CheckpointError(
            f"pretrained={pretrained!r} is not a file; give a local checkpoint or a Hub file as ORG/REPO:FILENAME"
        )
    from huggingface_hub import hf_hub_download

    repo_id, filename = pretrained.split(":", 1)
    try:
        return Path(hf_hub_download(repo_id, filename, etag_timeout=10))
    except Exception as err:
        raise CheckpointError(
            f"could not fetch {filename!r} from the Hub repo {repo_id!r} ({type(err).__name__}: {err}). On an offline "
            "machine, download it elsewhere and pass the local file path as pretrained=."
        ) from None


def read_state_dict(pretrained: str, wrappers=("state_dict", "model", "r3m", "module")) -> dict[str, Tensor]:
    """The tensors of a checkpoint, unwrapped from the usual containers ({'state_dict': ...}, {'model': ...})."""
    path = resolve_checkpoint(pretrained)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:
        raise CheckpointError(f"{path} is not a readable PyTorch checkpoint ({err})") from None
    while isinstance(state, dict) and not any(isinstance(v, Tensor) for v in state.values()):
        key = next((k for k in wrappers if k in state), None)
        if key is None:
            raise CheckpointError(f"{path}: no tensors found (top-level keys: {sorted(state)[:10]})")
        state = state[key]
    return {k: v for k, v in state.items() if isinstance(v, Tensor)}


def strip_prefix(state: dict[str, Tensor], prefix: str) -> dict[str, Tensor]:
    return {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}


def load_matching(module: nn.Module, state: dict[str, Tensor], source: str, allow_missing=()) -> dict:
    """Load `state` into `module`: every module key (except `allow_missing` prefixes) must be present with the
    right shape. Returns {'loaded', 'ignored'} counts and logs them."""
    own = module.state_dict()
    missing = [k for k in own if k not in state and not k.startswith(tuple(allow_missing))]
    wrong = [
        f"{k}: checkpoint {tuple(state[k].shape)} vs model {tuple(own[k].shape)}"
        for k in own
        if k in state and state[k].shape != own[k].shape
    ]
    if wrong or missing:
        raise CheckpointError(
            f"{source} does not fit this encoder (a checkpoint of another architecture?): "
            + (
                f"shape mismatches {wrong[:5]}" + (f" (+{len(wrong) - 5} more)" if len(wrong) > 5 else "")
                if wrong
                else ""
            )
            + ("; " if wrong and missing else "")
            + (
                f"missing keys {missing[:8]}" + (f" (+{len(missing) - 8} more)" if len(missing) > 8 else "")
                if missing
                else ""
            )
        )
    used = {k: v for k, v in state.items() if k in own}
    module.load_state_dict(used, strict=False)
    report = {"loaded": len(used), "ignored": sorted(k for k in state if k not in own)}
    logger.info(
        "%s: loaded %d tensors, ignored %d checkpoint keys%s",
        source,
        len(used),
        len(report["ignored"]),
        f" (e.g. {report['ignored'][:3]})" if report["ignored"] else "",
    )
    return report


def expand_input_channels(weight: Tensor, in_channels: int) -> Tensor:
    """Adapt a pretrained RGB input filter (out, 3, kh, kw) to `in_channels`.

    Extra channels (depth, xyz) start at zero so the pretrained RGB response is unchanged at initialisation,
    as in the paper. A single-channel (depth-only) input gets the mean of the RGB filters instead, since an
    all-zero filter would make the whole network blind.
    """
    out, _, kh, kw = weight.shape
    if in_channels == 1:
        return weight.mean(dim=1, keepdim=True)
    new = weight.new_zeros(out, in_channels, kh, kw)
    new[:, :3] = weight
    return new
