"""Load a trained checkpoint (a `pretrained_model` directory) with its own pre/post-processors, as stock
`lerobot-eval` does; shared by simulated evaluation and real-robot rollouts."""

from __future__ import annotations

from pathlib import Path


def load_policy(path: str | Path, device: str = "cpu"):
    """(policy in eval mode on `device`, preprocessor, postprocessor) of the checkpoint at `path`: a
    `pretrained_model` directory, or a Hub repo id (`ORG/NAME`)."""
    from lerobot.configs.policies import PreTrainedConfig

    check_policy_path(path)
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    config = PreTrainedConfig.from_pretrained(path)
    config.device = device
    policy = get_policy_class(config.type).from_pretrained(path, config=config).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(path))
    return policy, pre, post


def check_policy_path(path: str | Path) -> None:
    """Fail early, with the fix, on a local checkpoint path that does not exist (instead of LeRobot's Hub repo-id
    validation error); `ORG/NAME` (one slash, no local directory of that name) is left to the Hub."""
    text = str(path)
    local = Path(text).expanduser()
    if local.is_dir():
        if not (local / "config.json").is_file():
            raise FileNotFoundError(
                f"{local} is not a checkpoint: it has no config.json (pass the `pretrained_model` directory, e.g. "
                "outputs/train/RUN/checkpoints/last/pretrained_model)"
            )
        return
    looks_like_repo_id = text.count("/") == 1 and not text.startswith((".", "/", "~")) and not local.suffix
    if not looks_like_repo_id:
        raise FileNotFoundError(
            f"policy checkpoint {text} not found (a `pretrained_model` directory written by lerobot-train, or a "
            "Hub repo id ORG/NAME)"
        )
