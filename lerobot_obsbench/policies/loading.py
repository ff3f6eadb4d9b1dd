"""Load a trained checkpoint (a `pretrained_model` directory) with its own pre/post-processors, as stock
`lerobot-eval` does; shared by simulated evaluation and real-robot rollouts."""

from __future__ import annotations

from pathlib import Path

from lerobot_obsbench.errors import MissingFileError, ObsBenchError


class CheckpointError(ObsBenchError, ValueError):
    """A checkpoint's files are there but cannot be read (truncated, edited by hand, written by another tool)."""


def predict_chunk(policy, post, batch: dict):
    """The policy's whole next action chunk (n, action_dim) as a NumPy array, each action through the
    postprocessor (unnormalised), for callers that act on more than the next action."""
    import numpy as np
    import torch

    with torch.inference_mode():
        chunk = policy.predict_action_chunk(batch)  # (1, n, action_dim)
        return np.stack([post(chunk[:, i])[0].cpu().numpy() for i in range(chunk.shape[1])])


def load_policy(path: str | Path, device: str = "cpu"):
    """(policy in eval mode on `device`, preprocessor, postprocessor) of the checkpoint at `path`: a
    `pretrained_model` directory, or a Hub repo id (`ORG/NAME`, from the local cache when HF_HUB_OFFLINE=1)."""
    import os

    from huggingface_hub.errors import LocalEntryNotFoundError, OfflineModeIsEnabled
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    check_policy_path(path)
    try:
        config = _read(path, "config.json", PreTrainedConfig.from_pretrained)
        config.device = device
        policy = _read(path, "model.safetensors", get_policy_class(config.type).from_pretrained, config=config)
        pre, post = make_pre_post_processors(policy.eval().config, pretrained_path=str(path))
    except (LocalEntryNotFoundError, OfflineModeIsEnabled, FileNotFoundError) as err:
        if Path(str(path)).expanduser().is_dir():
            raise
        offline = os.environ.get("HF_HUB_OFFLINE", "0").lower() in ("1", "true", "yes")
        where = "the Hub is off (HF_HUB_OFFLINE=1)" if offline else "the Hub did not provide it"
        raise MissingFileError(
            f"policy {path}: no local directory of that name, not in the Hugging Face cache, and {where} "
            f"({type(err).__name__}). Download it where the Hub is reachable (`huggingface-cli download {path}`) "
            "or pass a local pretrained_model directory."
        ) from None
    return policy, pre, post


def _read(path: str | Path, name: str, load, **kwargs):
    """`load(path, **kwargs)`, a damaged `name` reported as a `CheckpointError` naming the file and the way out."""
    import json

    from draccus.utils import DraccusException
    from safetensors import SafetensorError

    try:
        return load(path, **kwargs)
    except (json.JSONDecodeError, DraccusException, SafetensorError) as err:
        detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise CheckpointError(
            f"{Path(str(path)) / name} cannot be read ({detail}): the checkpoint is damaged. Evaluate another "
            "checkpoint of the run (its checkpoints/<step>/pretrained_model folders), or train it again."
        ) from None


def check_policy_path(path: str | Path) -> None:
    """Fail early, with the fix, on a local checkpoint path that does not exist (instead of LeRobot's Hub repo-id
    validation error); `ORG/NAME` (one slash, no local directory of that name) is left to the Hub."""
    text = str(path)
    local = Path(text).expanduser()
    if local.is_dir():
        if not (local / "config.json").is_file():
            raise MissingFileError(
                f"{local} is not a checkpoint: it has no config.json (pass the `pretrained_model` directory, e.g. "
                "outputs/train/RUN/checkpoints/last/pretrained_model)"
            )
        return
    looks_like_repo_id = text.count("/") == 1 and not text.startswith((".", "/", "~")) and not local.suffix
    if not looks_like_repo_id:
        raise MissingFileError(
            f"policy checkpoint {text} not found (a `pretrained_model` directory written by lerobot-train, or a "
            "Hub repo id ORG/NAME)"
        )
