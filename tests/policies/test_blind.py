"""The blind control (`obs_space=none`): the same policy, proprioception and goal, and no visual observation."""

from __future__ import annotations

import pytest
import torch

from lerobot_obsbench.encoders import EncoderOutput, default_encoder, encoder_output
from tests.support.helpers import first_batch, training_setup

SENSORS = ("observation.images.", "observation.depth.", "observation.intrinsics.", "observation.cam2world.")


def _other_frames(batch: dict) -> dict:
    """The same states (and goals), with every sensor tensor replaced: other scenes rolled in, plus noise."""
    out = {}
    for key, value in batch.items():
        if key.startswith(SENSORS):
            value = torch.roll(value, 1, dims=0)
            value = value + torch.rand_like(value.float()).to(value.dtype) if value.is_floating_point() else value + 7
        out[key] = value
    return out


def _actions(policy, batch: dict) -> torch.Tensor:
    policy.eval()
    policy.reset()
    torch.manual_seed(0)  # Diffusion samples noise
    with torch.no_grad():
        return policy.select_action(dict(batch))


@pytest.mark.parametrize("policy_type", ["obs_act", "obs_diffusion"])
def test_blind_actions_do_not_depend_on_what_the_cameras_show(tiny_dataset, policy_type):
    seeing, pre, _, dataset = training_setup(policy_type, "rgb", tiny_dataset)
    batch = first_batch(dataset, pre, batch_size=4, shuffle=True)
    steps_last = {
        k: v[:, -1] if policy_type == "obs_diffusion" else v for k, v in batch.items() if k.startswith("observation")
    }
    other = _other_frames(steps_last)
    blind, *_ = training_setup(policy_type, "none", tiny_dataset)
    assert blind.config.encoder == "blind" and blind.config.cameras == []
    assert torch.equal(_actions(blind, steps_last), _actions(blind, other))
    # the loss's gradient never reaches a sensor tensor: the blind policy does not read them
    train = {
        k: v.float().requires_grad_() if k.startswith(SENSORS) and v.is_floating_point() else v
        for k, v in batch.items()
    }
    blind.train()
    blind.forward(train)[0].backward()
    assert all(v.grad is None for k, v in train.items() if k.startswith(SENSORS) and v.is_floating_point())
    # control: a seeing policy's actions do change with the frames, so the comparison above can fail
    assert not torch.equal(_actions(seeing, steps_last), _actions(seeing, other))


def test_blind_is_a_space_like_the_others():
    assert default_encoder("none") == "blind"
    assert encoder_output("blind", "none", "tokens", dim=32) == EncoderOutput(0, 32)
    assert encoder_output("blind", "none", "global") == EncoderOutput(None, 0)
    from lerobot_obsbench.policies import ObsACTConfig

    with pytest.raises(ValueError, match="sampling='pre' is a point-cloud design choice"):
        ObsACTConfig(device="cpu", obs_space="none", sampling="pre")
    with pytest.raises(ValueError, match="does not accept obs_space='none'"):
        ObsACTConfig(device="cpu", obs_space="none", encoder="resnet18")
