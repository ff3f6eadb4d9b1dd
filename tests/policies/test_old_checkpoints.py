"""Checkpoints the plugin saved under LeRobot 0.4.4 still load and act the same under 0.6.1.

The fixtures in tests/support/data/lerobot044 were written by the plugin at commit 6a529e4 with LeRobot 0.4.4
(Python 3.11) by `tests/support/data/lerobot044/make_fixtures.py`: a tiny obs_act and a tiny obs_diffusion
point-cloud policy with their processors, plus one preprocessed observation and the action 0.4.4 selected for it
(torch seed 0)."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import load_file

from lerobot_obsbench.policies.loading import load_policy
from tests.support.paths import DATA

FIXTURES = DATA / "lerobot044"


@pytest.mark.parametrize("policy_type", ["obs_act", "obs_diffusion"])
def test_a_lerobot_044_checkpoint_loads_and_acts_as_it_did(policy_type):
    saved = json.loads((FIXTURES / policy_type / "config.json").read_text())
    policy, _, _ = load_policy(FIXTURES / policy_type)
    # the values it was saved with, not LeRobot 0.6.1's new defaults
    for name in ("chunk_size", "n_action_steps", "horizon", "use_group_norm", "pretrained_backbone_weights"):
        if name in saved:
            assert getattr(policy.config, name) == saved[name], name
    reference = load_file(FIXTURES / policy_type / "reference_batch.safetensors")
    expected = reference.pop("expected_action")
    policy.eval()
    policy.reset()
    torch.manual_seed(0)
    with torch.no_grad():
        action = policy.select_action(reference)
    torch.testing.assert_close(action, expected, rtol=1e-4, atol=1e-4)
