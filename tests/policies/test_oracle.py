"""The oracle control (obs_space `state`): the simulator's object poses as the observation, refused on recordings
that cannot have them, never seen by the other spaces, and kept through save and load."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from lerobot_obsbench.bench.diagnostics import held_out_diagnostics
from lerobot_obsbench.policies.loading import load_policy
from lerobot_obsbench.schema import PRIVILEGED_STATE_KEY, SchemaError
from tests.support.helpers import first_batch, one_thread, training_setup

SYNTHETIC_CUBE = SimpleNamespace(privileged_actors=("cube",), objects={"cube": 0.025 * 3**0.5})


@pytest.fixture(scope="module")
def sim_like_dataset(tmp_path_factory, synthetic_module):
    """The synthetic scene recorded as a simulator would: with the cube's pose, without the goal key."""
    root = tmp_path_factory.mktemp("ds") / "privileged"
    return synthetic_module.write_dataset(
        root, episodes=4, frames=10, size=32, seed=3, with_goal=False, privileged=True
    )


@pytest.mark.parametrize("policy_type", ["obs_act", "obs_diffusion"])
def test_oracle_reads_standardised_object_poses_and_learns_from_them(sim_like_dataset, policy_type):
    with one_thread():
        torch.manual_seed(0)
        policy, pre, _, dataset = training_setup(policy_type, "state", sim_like_dataset)
        assert policy.config.privileged_state_dim == 7 and policy.config.cameras == []
        assert PRIVILEGED_STATE_KEY not in policy.config.input_features  # not LeRobot's normaliser's
        standardize = policy.observation_encoder().privileged
        stats = dataset.meta.stats[PRIVILEGED_STATE_KEY]
        torch.testing.assert_close(standardize.mean, torch.as_tensor(stats["mean"], dtype=torch.float32))
        batch = first_batch(dataset, pre, batch_size=8)
        loss, _ = policy.forward(batch)
        loss.backward()
        # the oracle's input reaches the loss: its projection (ACT) or the denoiser's conditioning (DP) gets gradient
        grads = [p.grad for n, p in policy.named_parameters() if p.grad is not None]
        assert torch.isfinite(loss) and grads
        # a different object pose changes the prediction: the oracle sees its input
        policy.eval()
        moved = {**batch, PRIVILEGED_STATE_KEY: batch[PRIVILEGED_STATE_KEY] + 0.05}
        torch.manual_seed(1)
        before = policy.open_loop_error(batch)
        torch.manual_seed(1)
        after = policy.open_loop_error(moved)
        assert not torch.allclose(before, after)


def test_oracle_is_refused_on_a_recording_without_object_poses(tiny_dataset):
    with pytest.raises(SchemaError, match=r"oracle control.*only simulated.*obs_space='none'"):
        training_setup("obs_act", "state", tiny_dataset)


def test_seeing_spaces_never_read_the_object_poses(sim_like_dataset):
    policy, pre, _, dataset = training_setup("obs_act", "pointcloud", sim_like_dataset)
    assert PRIVILEGED_STATE_KEY not in policy.config.input_features
    assert PRIVILEGED_STATE_KEY not in policy.observation_encoder().input_keys
    batch = first_batch(dataset, pre)
    policy.eval()
    without = {k: v for k, v in batch.items() if k != PRIVILEGED_STATE_KEY}
    torch.testing.assert_close(policy.open_loop_error(batch), policy.open_loop_error(without))


@pytest.mark.parametrize("obs_space", ["state", "pointcloud", "rgb"])
def test_diagnostics_of_a_saved_checkpoint(sim_like_dataset, tmp_path, obs_space):
    """held_out_diagnostics on a trained-then-saved tiny policy: the open-loop error, and what a camera or a point
    cloud shows of the cube, against independent expectations."""
    with one_thread():
        torch.manual_seed(0)
        sizes = {"num_tokens": 16} if obs_space == "pointcloud" else {}
        policy, pre, post, dataset = training_setup("obs_act", obs_space, sim_like_dataset, **sizes)
        optimizer = torch.optim.Adam(policy.parameters(), lr=1e-3)
        for step in range(3):
            loss, _ = policy.forward(first_batch(dataset, pre, batch_size=8, shuffle=True, seed=step))
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        for part in (policy, pre, post):
            part.save_pretrained(tmp_path)
        found = held_out_diagnostics(tmp_path, sim_like_dataset, [3], SYNTHETIC_CUBE)
        # the same error computed here on the held-out episode, with the loaded policy
        loaded, loaded_pre, _ = load_policy(tmp_path)
        episode = [i for i in range(len(dataset)) if int(dataset[i]["episode_index"]) == 3]
        batch = loaded_pre(torch.utils.data.default_collate([dataset[i] for i in episode]))
        with torch.inference_mode():
            expected = float(loaded.open_loop_error(batch).mean())
    assert found["held_out_episodes"] == [3]
    assert found["open_loop_error"] == pytest.approx(expected, abs=1e-3)
    if obs_space == "state":
        assert "object_pixels" not in found and "object_token_share" not in found
        return
    # the synthetic camera: 60° field of view over 32 px, about 0.7 m from the cube
    focal = 16 / torch.tan(torch.deg2rad(torch.tensor(30.0))).item()
    assert 0.7 * 2 * 0.0433 * focal / 0.85 < found["object_pixels"]["cube"] < 2 * 0.0433 * focal / 0.55
    if obs_space == "pointcloud":
        # the cloud holds the cube and the gripper only (the table is cropped): a good share of tokens is on the cube
        assert 0.2 < found["object_token_share"] <= 1.0
    else:
        assert "object_token_share" not in found


def test_a_checkpoint_names_its_objects_and_eval_refuses_other_ones(sim_like_dataset, tmp_path):
    """An oracle trained on one task's object poses used to be evaluated on another task whose poses have the same
    width, without a word (PushCube's fed StackCube's)."""
    from lerobot_obsbench.schema import check_compatibility, oracle_problems

    policy, pre, post, _ = training_setup("obs_act", "state", sim_like_dataset)
    assert policy.config.privileged_state_names == [
        "cube.x",
        "cube.y",
        "cube.z",
        "cube.qw",
        "cube.qx",
        "cube.qy",
        "cube.qz",
    ]
    for part in (policy, pre, post):
        part.save_pretrained(tmp_path / "ckpt")
    loaded, _, _ = load_policy(tmp_path / "ckpt")
    assert loaded.config.privileged_state_names == policy.config.privileged_state_names
    assert oracle_problems(loaded.config, ("cube",)) == []
    with pytest.raises(
        SchemaError, match=r"trained on the poses of \['cube'\] but this task gives the poses of \['peg'\]"
    ):
        check_compatibility(loaded.config, objects=("peg",))  # the same width, other objects
    # a checkpoint that does not name its objects (trained before they were recorded): the width is still checked
    loaded.config.privileged_state_names = []
    assert oracle_problems(loaded.config, ("peg",)) == []
    assert (
        "reads 7 object-pose values (1 objects) but this task gives 14"
        in oracle_problems(loaded.config, ("cubeA", "cubeB"))[0]
    )
    # every other space has no object poses to check
    seeing, *_ = training_setup("obs_act", "rgb", sim_like_dataset)
    assert seeing.config.privileged_state_names == [] and oracle_problems(seeing.config, ("peg",)) == []
