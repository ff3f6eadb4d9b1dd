"""Load a trained checkpoint (a `pretrained_model` directory) with its own pre/post-processors, as stock
`lerobot-eval` does; shared by simulated evaluation and real-robot rollouts."""

from __future__ import annotations

from pathlib import Path


def load_policy(path: str | Path, device: str = "cpu"):
    """(policy in eval mode on `device`, preprocessor, postprocessor) of the checkpoint at `path`."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    config = PreTrainedConfig.from_pretrained(path)
    config.device = device
    policy = get_policy_class(config.type).from_pretrained(path, config=config).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(path))
    return policy, pre, post
