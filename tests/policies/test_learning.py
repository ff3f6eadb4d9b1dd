"""A point-cloud policy learns a task whose action depends on where an object is.

Synthetic task: move the gripper above a red cube placed at random. The goal (environment_state) is withheld, so
the cube position is only visible in the point cloud; joint values in the state are noise. Evaluated on
held-out episodes, with a control that shuffles the point clouds across the batch.

Training lands elsewhere on another CPU's float path, so the test asserts means over three training seeds, with
bounds set outside the spread measured here (2026-11-26, `train_and_measure` for seeds 0-4, torch on 1 and on 2
threads: two float paths of one machine). Ratios, single runs (min-max) and means of any three seeds:

| ratio | single runs | means of 3 seeds | bound |
|---|---|---|---|
| training L1 / mean action's | 0.38-0.47 | 0.39-0.44 | < 0.55 |
| held-out L1 / mean action's | 0.48-0.59 | 0.50-0.57 | < 0.70 |
| held-out L1 with shuffled clouds / held-out L1 | 1.32-1.74 | 1.42-1.66 | > 1.25 |

(With half the episodes, 30 to train and 6 held out, single runs spread over 0.54-0.78 and 1.08-1.66: the first
version's bounds of 0.65 and 1.3 on one seed sat inside that spread, and failed on another machine.)
"""

from __future__ import annotations

from statistics import mean

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy, make_pre_post_processors
from lerobot.utils.feature_utils import dataset_to_policy_features

from tests.support.helpers import one_thread

TRAIN_EPISODES, TEST_EPISODES = 60, 12
SEEDS = (0, 1, 2)


@pytest.fixture(scope="module")
def task_dataset(tmp_path_factory, synthetic_module):
    return synthetic_module.write_dataset(
        tmp_path_factory.mktemp("learn") / "ds", episodes=TRAIN_EPISODES + TEST_EPISODES, frames=10, size=48, seed=3
    )


def train_and_measure(
    dataset, seed: int = 0, steps: int = 400, train_episodes: int = TRAIN_EPISODES, test_episodes: int = TEST_EPISODES
) -> dict[str, float]:
    """Train the point-cloud policy `steps` AdamW steps from `seed` on the training episodes; its L1 errors (the
    last 25 training batches, the held-out episodes, the held-out episodes with their point clouds shuffled) and
    the mean action's."""
    torch.manual_seed(seed)
    meta = LeRobotDatasetMetadata("local/learn", root=dataset)
    feats = dataset_to_policy_features(meta.features)
    cfg = PreTrainedConfig.get_choice_class("obs_act")(
        obs_space="pointcloud",
        encoder="pointnet",
        device="cpu",
        dim_model=64,
        n_heads=4,
        dim_feedforward=128,
        n_encoder_layers=2,
        use_vae=False,
        chunk_size=1,
        n_action_steps=1,
        temporal_ensemble_coeff=None,
        num_tokens=64,
        knn=8,
        workspace=[-0.5, 0.5, -0.5, 0.5, 0.005, 0.5],
    )
    cfg.input_features = {k: v for k, v in feats.items() if k not in ("action", "observation.environment_state")}
    policy = make_policy(cfg, ds_meta=meta)
    pre, _ = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    deltas = resolve_delta_timestamps(cfg, meta)
    train = LeRobotDataset("local/learn", root=dataset, episodes=list(range(train_episodes)), delta_timestamps=deltas)
    test = LeRobotDataset(
        "local/learn",
        root=dataset,
        delta_timestamps=deltas,
        episodes=list(range(train_episodes, train_episodes + test_episodes)),
    )
    loader = torch.utils.data.DataLoader(
        train, batch_size=16, shuffle=True, drop_last=True, generator=torch.Generator().manual_seed(seed)
    )
    batches = [pre(b) for b in loader]
    held_out = pre(next(iter(torch.utils.data.DataLoader(test, batch_size=len(test)))))
    mean_action = torch.cat([b["action"] for b in batches]).mean(dim=0, keepdim=True)

    def l1(batch):
        policy.eval()
        with torch.no_grad():
            return (policy.model(batch)[0] - batch["action"]).abs().mean().item()

    optimizer = torch.optim.AdamW(policy.parameters(), lr=1e-3)
    policy.train()
    losses = []
    for step in range(steps):
        loss, _ = policy.forward(batches[step % len(batches)])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    # the control: the same states with other frames' point clouds
    perm = torch.roll(torch.arange(len(test)), 7)
    shuffled = {
        k: (v[perm] if k.startswith(("observation.images", "observation.depth")) else v) for k, v in held_out.items()
    }
    return {
        "train": sum(losses[-25:]) / 25,
        "train_mean_action": torch.stack([(b["action"] - mean_action).abs().mean() for b in batches]).mean().item(),
        "held_out": l1(held_out),
        "held_out_mean_action": (held_out["action"] - mean_action).abs().mean().item(),
        "held_out_shuffled": l1(shuffled),
    }


@pytest.mark.slow
def test_pointcloud_policy_beats_the_mean_action(task_dataset):
    with one_thread():
        runs = [train_and_measure(task_dataset, seed) for seed in SEEDS]
    ratios = {
        "train": mean(r["train"] / r["train_mean_action"] for r in runs),
        "held_out": mean(r["held_out"] / r["held_out_mean_action"] for r in runs),
        "shuffled": mean(r["held_out_shuffled"] / r["held_out"] for r in runs),
    }
    print(ratios, runs)
    assert ratios["train"] < 0.55, ratios  # it fits the training episodes
    assert ratios["held_out"] < 0.70, ratios  # and the held-out ones
    assert ratios["shuffled"] > 1.25, ratios  # with the point cloud: another frame's cloud makes it worse
