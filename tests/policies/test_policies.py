"""obs_act / obs_diffusion: config checks, schema errors, save/load round trip, inference queues."""

from __future__ import annotations

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.utils.feature_utils import dataset_to_policy_features
from safetensors.torch import load_file

from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig
from lerobot_obsbench.policies.obs_act.modeling_obs_act import ObsACTPolicy
from lerobot_obsbench.policies.obs_diffusion.modeling_obs_diffusion import ObsDiffusionPolicy
from lerobot_obsbench.schema import SchemaError
from tests.support.helpers import first_batch, training_setup

POLICIES = {"obs_act": (ObsACTConfig, ObsACTPolicy), "obs_diffusion": (ObsDiffusionConfig, ObsDiffusionPolicy)}


def test_paper_defaults():
    act = ObsACTConfig(device="cpu")
    assert (act.obs_space, act.encoder, act.num_tokens, act.knn, act.voxel_size) == (
        "pointcloud",
        "pointnet",
        2048,
        16,
        0.005,
    )
    assert (act.dim_model, act.n_heads, act.dim_feedforward, act.n_encoder_layers, act.n_decoder_layers) == (
        512,
        8,
        32,
        4,
        1,
    )
    assert (act.chunk_size, act.temporal_ensemble_coeff, act.kl_weight, act.latent_dim) == (100, 0.01, 10.0, 32)
    assert act.pretrained_backbone_weights is None and act.push_to_hub is False
    dp = ObsDiffusionConfig(device="cpu", obs_space="rgb")
    assert dp.encoder == "resnet50"
    assert (dp.horizon, dp.n_obs_steps, dp.n_action_steps, tuple(dp.down_dims)) == (16, 2, 8, (512, 1024, 2048))
    assert (dp.kernel_size, dp.n_groups, dp.diffusion_step_embed_dim, dp.num_train_timesteps) == (5, 8, 128, 100)
    for cfg in (act, dp):
        opt, sched = cfg.get_optimizer_preset(), cfg.get_scheduler_preset()
        assert opt.weight_decay == 0.05 and sched.type == "onecycle" and sched.pct_start == 0.15


@pytest.mark.parametrize("policy_type", list(POLICIES))
def test_config_time_errors(policy_type):
    cfg_cls = POLICIES[policy_type][0]
    with pytest.raises(ValueError, match="does not accept obs_space='rgb'.*Valid pairs"):
        cfg_cls(device="cpu", obs_space="rgb", encoder="pointnet")
    with pytest.raises(ValueError, match="Unknown obs_space 'voxels'"):
        cfg_cls(device="cpu", obs_space="voxels")
    with pytest.raises(ValueError, match="point_features"):
        cfg_cls(device="cpu", point_features="normals")
    with pytest.raises(ValueError, match="sampling"):
        cfg_cls(device="cpu", sampling="mid")
    with pytest.raises(ValueError, match="workspace must be"):
        cfg_cls(device="cpu", workspace=[1, -1, -1, 1, 0, 1])
    with pytest.raises(ValueError, match="depth_clip must be"):
        cfg_cls(device="cpu", depth_clip=[2.0, 0.5])


def _features_without(root, prefix):
    meta = LeRobotDatasetMetadata("local/test", root=root)
    feats = dataset_to_policy_features(meta.features)
    return {k: v for k, v in feats.items() if not k.startswith(prefix)}


@pytest.mark.parametrize("policy_type", list(POLICIES))
def test_dataset_lacking_a_needed_key_is_named(tiny_dataset, policy_type):
    cfg_cls, policy_cls = POLICIES[policy_type]
    feats = _features_without(tiny_dataset, "observation.depth.")
    cfg = cfg_cls(device="cpu", obs_space="pointcloud")
    cfg.input_features = {k: v for k, v in feats.items() if k != "action"}
    cfg.output_features = {"action": feats["action"]}
    with pytest.raises(SchemaError, match=r"obs_space='pointcloud' needs.*observation\.depth\.<cam>"):
        policy_cls(cfg)
    # an RGB policy is fine on the same features
    cfg = cfg_cls(device="cpu", obs_space="rgb", encoder="resnet18")
    cfg.input_features = {k: v for k, v in feats.items() if k != "action"}
    cfg.output_features = {"action": feats["action"]}
    policy_cls(cfg)
    assert cfg.cameras == ["base_camera"]
    assert not any(k.startswith("observation.images") for k in cfg.input_features), "sensors leave the normaliser"


def test_ee_frame_needs_the_pose_in_the_state(tiny_dataset):
    feats = _features_without(tiny_dataset, "observation.state")
    cfg = ObsACTConfig(device="cpu", obs_space="pointcloud", frame="ee")
    cfg.input_features = {k: v for k, v in feats.items() if k != "action"}
    cfg.output_features = {"action": feats["action"]}
    with pytest.raises(SchemaError, match="frame='ee' reads the end-effector pose"):
        ObsACTPolicy(cfg)


@pytest.mark.parametrize(
    "policy_type,obs_space,extra",
    [
        ("obs_act", "pointcloud", {}),
        ("obs_act", "pointcloud", {"frame": "ee", "sampling": "pre"}),
        ("obs_act", "rgbd", {}),
        ("obs_diffusion", "pointcloud", {"frame": "ee"}),
        ("obs_diffusion", "pointmap", {"frame": "camera"}),
    ],
)
def test_save_load_round_trip_and_inference(tiny_dataset, tmp_path, policy_type, obs_space, extra):
    policy, pre, _, dataset = training_setup(policy_type, obs_space, tiny_dataset, **extra)
    batch = first_batch(dataset, pre, batch_size=4, shuffle=True)
    policy.train()
    loss, _ = policy.forward(batch)
    loss.backward()
    policy.save_pretrained(tmp_path)
    saved = load_file(tmp_path / "model.safetensors")
    fresh = POLICIES[policy_type][1].from_pretrained(tmp_path)
    # LeRobot loads with strict=False and only logs problems: check the key sets ourselves
    assert set(saved) == set(fresh.state_dict()), set(saved) ^ set(fresh.state_dict())
    missing, unexpected = fresh.load_state_dict(saved, strict=True)
    assert not missing and not unexpected
    for key, value in policy.state_dict().items():
        assert torch.equal(value, fresh.state_dict()[key]), key
    assert fresh.config.cameras == ["base_camera"] and fresh.config.obs_space == obs_space

    # inference as lerobot-eval calls it: one observation (no time axis) at a time
    obs = {
        k: v[:, -1] if policy_type == "obs_diffusion" and k.startswith("observation") else v
        for k, v in batch.items()
        if k.startswith("observation")
    }
    policy.eval()
    policy.reset()
    fresh.reset()
    torch.manual_seed(0)  # DDPM sampling draws noise at every denoising step
    a = policy.select_action(dict(obs))
    torch.manual_seed(0)
    b = fresh.select_action(dict(obs))
    assert a.shape == (4, 7) and torch.allclose(a, b, atol=1e-5)
    if policy_type == "obs_diffusion":
        # the sensor keys were queued: a second step reuses the cached chunk without failing
        assert all(len(policy._queues[k]) == policy.config.n_obs_steps for k in policy.diffusion.observation.input_keys)
        policy.select_action(dict(obs))


@pytest.mark.parametrize("policy_type", list(POLICIES))
def test_env_passthrough_reaches_the_policy(tiny_dataset, policy_type):
    """What stock lerobot-eval feeds the policy (preprocess_observation of the env's dict, with depth and camera
    parameters in `robot_state`) gives the same action as the same frame presented like a dataset batch."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_obsbench import schema

    policy, pre, _, dataset = training_setup(policy_type, "pointcloud", tiny_dataset)
    sample = dataset[5]
    frame = {
        k: (v[-1] if policy_type == "obs_diffusion" else v)[None]  # one frame, batch of 1
        for k, v in sample.items()
        if k.startswith("observation") and not k.endswith("_is_pad")
    }
    env_frame = {k: v.numpy() for k, v in frame.items()}  # what ObsBenchEnv sends: uint8 HWC colour, uint16 depth
    env_frame["observation.images.base_camera"] = (
        (frame["observation.images.base_camera"] * 255).round().byte().permute(0, 2, 3, 1).numpy()
    )
    env_frame["observation.depth.base_camera"] = env_frame["observation.depth.base_camera"].astype("uint16")
    via_env = pre(preprocess_observation(schema.frame_to_env_observation(env_frame)))
    assert "observation.robot_state" in via_env
    direct = pre(dict(frame))
    policy.eval()
    actions = []
    for batch in (via_env, direct):
        policy.reset()
        torch.manual_seed(0)
        actions.append(policy.select_action(batch))
    assert torch.allclose(actions[0], actions[1], atol=1e-5)


def test_policy_env_compatibility_names_each_mismatch(tiny_dataset):
    from lerobot_obsbench.envs.evaluate import check_compatible

    policy, *_ = training_setup("obs_act", "rgbd", tiny_dataset)
    assert policy.config.camera_resolution == [40, 40]
    # the synthetic dataset has a 15-D state; ObsBenchEnv gives 16 (9 joints + TCP pose)
    with pytest.raises(SchemaError) as err:
        check_compatible(policy.config, ["hand_camera"], 64, "pd_joint_pos", "PushCube-v1")  # pd_joint_pos: 8-D actions
    message = str(err.value)
    assert "cameras ['base_camera'] but the env renders ['hand_camera']" in message
    assert "trained on 40x40 frames" in message and "--env.image_size=40" in message
    assert "observation.state of size 15, the env gives 16" in message
    assert "7-D actions" in message and "takes 8" in message


def test_a_compiled_encoder_trains_the_same_model_and_acts_eagerly(tiny_dataset, tmp_path):
    """`compile_encoder`: training runs the encoder through torch.compile, with the eager encoder's parameters (the
    same loss and gradients to rounding, the same state dict); evaluation runs the eager encoder."""
    setups = {
        compiled: training_setup("obs_act", "rgb", tiny_dataset, encoder="spatial_softmax", compile_encoder=compiled)
        for compiled in (False, True)
    }
    eager, pre, _, dataset = setups[False]
    compiled = setups[True][0]
    compiled.load_state_dict(eager.state_dict())
    assert set(compiled.state_dict()) == set(eager.state_dict())
    batch = first_batch(dataset, pre, batch_size=4)
    losses, grads = {}, {}
    for name, policy in (("eager", eager), ("compiled", compiled)):
        policy.train()
        torch.manual_seed(0)  # dropout
        loss, _ = policy.forward(dict(batch))
        loss.backward()
        losses[name] = loss.item()
        grads[name] = policy.model.observation.encoder.backbone[0].weight.grad.clone()
    assert losses["compiled"] == pytest.approx(losses["eager"], rel=1e-4)
    assert torch.allclose(grads["compiled"], grads["eager"], rtol=1e-3, atol=1e-6)
    compiled.eval()
    assert compiled.model.observation._compiled is not None and not compiled.model.observation.training
    compiled.save_pretrained(tmp_path)
    assert set(load_file(tmp_path / "model.safetensors")) == set(eager.state_dict())


def test_the_named_types_table_is_the_classes():
    """configuration_named's docstring table names each written class's type, policy, space and default encoder, and
    each type presets the encoder its space defaults to (but the SpUNet types)."""
    import importlib
    import re

    from lerobot_obsbench.encoders import default_encoder
    from lerobot_obsbench.policies.named import configuration_named, modeling_named, processor_named

    table = {}
    for row in re.findall(r"^\| (\w+), (\w+) \| ACT, DP \| (\w+) \| (\w+)", configuration_named.__doc__, re.M):
        act, dp, space, encoder = row
        table[act], table[dp] = ("obs_act", space, encoder), ("obs_diffusion", space, encoder)
    assert table == configuration_named.NAMED_POLICIES and len(table) == 12
    for name, (base, space, encoder) in table.items():
        assert encoder == default_encoder(space) or name.endswith("_spunet")
        policy = getattr(modeling_named, "".join(p.capitalize() for p in name.split("_")) + "Policy")
        assert policy.name == name and policy.config_class is configuration_named.NAMED_CONFIGS[name]
        base_processors = importlib.import_module(f"lerobot_obsbench.policies.{base}.processor_{base}")
        made = getattr(processor_named, f"make_{name}_pre_post_processors")
        assert made is getattr(base_processors, f"make_{base}_pre_post_processors")
