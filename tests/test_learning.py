"""A point-cloud policy learns a task whose action depends on where an object is.

Synthetic task: move the gripper above a red cube placed at random. The goal (environment_state) is withheld, so
the cube position is only visible in the point cloud; joint values in the state are noise. Evaluated on
held-out episodes, with a control that shuffles the point clouds across the batch.
"""

from __future__ import annotations

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy, make_pre_post_processors
from lerobot.utils.feature_utils import dataset_to_policy_features

TRAIN_EPISODES, TEST_EPISODES = 30, 6


@pytest.fixture(scope="module")
def task_dataset(tmp_path_factory, synthetic_module):
    return synthetic_module.write_dataset(
        tmp_path_factory.mktemp("learn") / "ds", episodes=TRAIN_EPISODES + TEST_EPISODES, frames=10, size=48, seed=3
    )


@pytest.mark.slow
def test_pointcloud_policy_beats_the_mean_action(task_dataset):
    torch.manual_seed(0)
    meta = LeRobotDatasetMetadata("local/learn", root=task_dataset)
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
    train = LeRobotDataset(
        "local/learn", root=task_dataset, episodes=list(range(TRAIN_EPISODES)), delta_timestamps=deltas
    )
    test = LeRobotDataset(
        "local/learn",
        root=task_dataset,
        delta_timestamps=deltas,
        episodes=list(range(TRAIN_EPISODES, TRAIN_EPISODES + TEST_EPISODES)),
    )
    loader = torch.utils.data.DataLoader(
        train, batch_size=16, shuffle=True, drop_last=True, generator=torch.Generator().manual_seed(0)
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
    for step in range(400):
        loss, _ = policy.forward(batches[step % len(batches)])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())

    baseline_train = torch.stack([(b["action"] - mean_action).abs().mean() for b in batches]).mean().item()
    baseline_test = (held_out["action"] - mean_action).abs().mean().item()
    train_loss = sum(losses[-25:]) / 25
    test_loss = l1(held_out)
    print(
        f"train L1 {train_loss:.3f} vs mean-action {baseline_train:.3f}; "
        f"held-out {test_loss:.3f} vs {baseline_test:.3f}"
    )
    assert train_loss < 0.5 * baseline_train, (train_loss, baseline_train)
    assert test_loss < 0.65 * baseline_test, (test_loss, baseline_test)
    # control: the same states with other frames' point clouds -> much worse, so the cloud is what is used
    perm = torch.roll(torch.arange(len(test)), 7)
    shuffled = {
        k: (v[perm] if k.startswith(("observation.images", "observation.depth")) else v) for k, v in held_out.items()
    }
    shuffled_loss = l1(shuffled)
    print(f"held-out with shuffled point clouds {shuffled_loss:.3f}")
    assert shuffled_loss > 1.3 * test_loss
