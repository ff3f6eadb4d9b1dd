"""The `paper` preset reproduces the official code's protocol (README: Differences from the paper): one test per
item that can be checked without a GPU. The plugin's own behaviour stays the default of every field."""

from __future__ import annotations

import pytest
import torch
from lerobot.configs.default import DatasetConfig
from lerobot.configs.train import TrainPipelineConfig

from lerobot_obsbench import geometry
from lerobot_obsbench.encoders import EncoderContext, encoder_output, make_encoder
from lerobot_obsbench.encoders.point_tokenizer import sine_embedding_3d
from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig
from lerobot_obsbench.presets import preset_overrides
from lerobot_obsbench.schema import PointCloud
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
from tests.support.helpers import CAM, first_batch, frame_batch, training_setup


def paper(policy: str, space: str, encoder: str | None = None) -> dict:
    return preset_overrides("paper", policy, space, encoder)


def test_resnet50_sees_224_pixels_49_tokens_per_camera():
    options = {"input_size": paper("obs_act", "rgb")["image_input_size"]}
    assert encoder_output("resnet50", "rgb", "tokens", 512, EncoderContext(1, (128, 128)), **options).tokens == 49
    assert encoder_output("resnet50", "rgb", "tokens", 512, EncoderContext(1, (128, 128))).tokens == 16  # plugin's
    encoder = make_encoder("resnet50", "rgb", "tokens", dim=32, **options).eval()
    with torch.no_grad():
        tokens, pos = encoder(torch.rand(2, 1, 3, 128, 128))
    assert tokens.shape == (2, 49, 32) and pos.shape == (1, 49, 32)


def test_vit_and_multivit_see_196_patches_per_modality():
    vit = make_encoder("vit_b", "rgb", "global", image_size=(128, 128), input_size=224)
    assert vit.vit.patch_embed.grid_size == (14, 14) and vit.vit.pos_embed.shape[1] == 1 + 196
    multivit = make_encoder("multivit_b", "rgbd", "global", input_size=224).eval()
    seen = []
    multivit.encoder[0].register_forward_hook(lambda module, args, out: seen.append(args[0].shape[1]))
    with torch.no_grad():
        multivit(torch.rand(1, 1, 4, 128, 128))
    assert seen == [2 * 196 + 1]  # rgb and depth patches + the global token


def test_extra_stem_channels_start_at_zero_from_scratch():
    assert paper("obs_act", "rgbd", "resnet50")["zero_init_extra_channels"] is True
    rgbd = make_encoder("resnet50", "rgbd", "global", zero_extra_channels=True).body[0].weight
    assert (rgbd[:, 3] == 0).all() and (rgbd[:, :3] != 0).any()
    depth = make_encoder("resnet50", "depth", "global", zero_extra_channels=True).body[0].weight
    assert (depth == 0).all()  # depth-only: the whole first conv, as the official code
    pointmap = make_encoder("vit_b", "pointmap", "global", image_size=32, zero_extra_channels=True)
    assert (pointmap.vit.patch_embed.proj.weight[:, 3:] == 0).all()
    plugin = make_encoder("resnet50", "rgbd", "global").body[0].weight  # the plugin's default: random
    assert (plugin[:, 3] != 0).any()


def test_depth_and_xyz_scaling_as_the_official_code(synthetic_module):
    batch = frame_batch(synthetic_module, batch_size=2, size=24)
    depth_m = batch[f"observation.depth.{CAM}"][..., 0].float() / 1000
    official = ObservationAdapter(AdapterConfig("rgbd", [CAM], depth_normalization="official"))(batch)
    torch.testing.assert_close(official[:, 0, 3], (depth_m - 0.5) / 0.5)
    pointmap = ObservationAdapter(AdapterConfig("pointmap", [CAM], depth_normalization="official"))(batch)
    plain = ObservationAdapter(AdapterConfig("pointmap", [CAM]))(batch)
    torch.testing.assert_close(pointmap[:, 0, 3:], (plain[:, 0, 3:] - 0.5) / 0.5)
    with pytest.raises(ValueError, match="depth_normalization='official' scales depth / xyz images"):
        ObsACTConfig(device="cpu", obs_space="rgb", depth_normalization="official")


def test_act_mse_loss_on_a_known_batch(tiny_dataset):
    assert paper("obs_act", "pointcloud")["action_loss"] == "mse"
    policy, pre, _, dataset = training_setup("obs_act", "rgb", tiny_dataset, action_loss="mse")
    batch = first_batch(dataset, pre, batch_size=3)
    policy.train()
    torch.manual_seed(0)
    loss, terms = policy.forward(dict(batch))
    torch.manual_seed(0)
    actions, (mu, log_sigma_x2) = policy.model(dict(batch))
    valid = ~batch["action_is_pad"].unsqueeze(-1)
    mse = ((batch["action"] - actions) ** 2 * valid).mean()
    kld = (-0.5 * (1 + log_sigma_x2 - mu.pow(2) - log_sigma_x2.exp())).sum(-1).mean()
    torch.testing.assert_close(loss, mse + policy.config.kl_weight * kld)
    assert set(terms) == {"mse_loss", "kld_loss"} and terms["mse_loss"] == pytest.approx(mse.item())


def test_point_positions_in_raw_metres():
    assert paper("obs_act", "pointcloud")["position_scale"] == 1.0
    xyz = torch.tensor([[[0.1, -0.2, 0.3]]])
    torch.testing.assert_close(sine_embedding_3d(xyz, 48, scale=1.0), sine_embedding_3d(xyz * 100, 48, scale=0.01))
    encoder = make_encoder("pointnet", "pointcloud", "tokens", dim=24, num_tokens=4, knn=2, position_scale=1.0).eval()
    cloud = PointCloud(torch.rand(1, 20, 3) * 0.2, torch.rand(1, 20, 6), torch.ones(1, 20, dtype=torch.bool))
    with torch.no_grad():
        _, pos = encoder(cloud)
    # every position is the sine code of an FPS seed's raw metres, in the seeds' order
    idx, _ = geometry.farthest_point_sample(cloud.xyz, cloud.mask, 4, encoder.fps_start)
    torch.testing.assert_close(pos, sine_embedding_3d(geometry.gather(cloud.xyz, idx), 24, scale=1.0))
    assert pos.abs().max() <= 1 and not torch.allclose(pos[0, 0], pos[0, 1])


def test_official_point_pipeline():
    assert paper("obs_diffusion", "pointcloud")["point_pipeline"] == "official"
    encoder = make_encoder("pointnet", "pointcloud", "tokens", dim=16, num_tokens=8, knn=4, pipeline="official")
    norm = encoder.group_act[0]
    assert (norm.eps, norm.momentum) == (1e-5, 0.1)  # PyTorch's defaults, as the official tokenizer
    plugin = make_encoder("pointnet", "pointcloud", "tokens", dim=16, num_tokens=8, knn=4).group_act[0]
    assert (plugin.eps, plugin.momentum) == (1e-3, 0.01)


@pytest.mark.parametrize("sampling", ["post", "pre"])
def test_official_point_pipeline_starts_fps_at_each_clouds_first_point(sampling):
    """The official tokenizer's seeds are FPS from each cloud's first valid point on CPU too, as the official CUDA
    FPS on a GPU; the plugin's may start where QuickFPS's tree does (faster on CPU). Clouds of more than
    QUICK_FPS_MIN_POINTS points (QuickFPS's size), one padded at the front: token positions are the seeds'."""
    assert paper("obs_act", "pointcloud")["point_pipeline"] == "official"
    g = torch.Generator().manual_seed(0)
    n, k = geometry.QUICK_FPS_MIN_POINTS + 500, 32
    mask = torch.ones(2, n, dtype=torch.bool)
    mask[1, :7] = False
    cloud = PointCloud(torch.rand(2, n, 3, generator=g) * 0.2, torch.rand(2, n, 6, generator=g), mask)
    for pipeline, start in (("official", "first"), ("plugin", "any")):
        options = {"num_tokens": k, "knn": 4, "sampling": sampling, "pipeline": pipeline}
        encoder = make_encoder("pointnet", "pointcloud", "tokens", dim=24, **options).eval()
        with torch.no_grad():
            _, pos = encoder(cloud)
        seeds = geometry.gather(cloud.xyz, geometry.farthest_point_sample(cloud.xyz, mask, k, start)[0])
        torch.testing.assert_close(pos, sine_embedding_3d(seeds, 24, scale=encoder.position_scale))
        if pipeline == "official":
            torch.testing.assert_close(seeds[:, 0], cloud.xyz[[0, 1], [0, 7]])


def test_official_point_pipeline_samples_randomly_also_at_evaluation(synthetic_module):
    batch = frame_batch(synthetic_module, batch_size=1, size=96)  # several points per 2 cm voxel
    workspace = (-0.5, 0.5, -0.5, 0.5, 0.005, 0.5)
    clouds = {}
    for pipeline in ("plugin", "official"):
        adapter = ObservationAdapter(
            AdapterConfig("pointcloud", [CAM], workspace=workspace, voxel_size=0.02, point_pipeline=pipeline)
        )
        adapter.eval()
        torch.manual_seed(0)
        first = adapter(batch)
        torch.manual_seed(1)
        clouds[pipeline] = (first, adapter(batch))
    a, b = clouds["plugin"]
    assert torch.equal(a.xyz, b.xyz)  # deterministic voxel point at evaluation
    a, b = clouds["official"]
    assert a.mask.sum() == b.mask.sum() and not torch.equal(a.xyz, b.xyz)  # one random point per voxel


def test_diffusion_policy_official_point_head():
    assert paper("obs_diffusion", "pointcloud")["dp_point_head"] == "official"
    pointnet = make_encoder("pointnet", "pointcloud", "global", num_tokens=8, knn=4, global_head="official").eval()
    counted = (
        pointnet.backbone,
        pointnet.dp_projection,
        pointnet.feature_proj,
        pointnet.offset_proj,
        pointnet.group_act,
    )
    assert sum(p.numel() for m in counted for p in m.parameters()) == 142_912  # Table 1's "PointNet 0.14M"
    cloud = PointCloud(torch.rand(2, 30, 3) * 0.2, torch.rand(2, 30, 6), torch.ones(2, 30, dtype=torch.bool))
    with torch.no_grad():
        assert pointnet(cloud).shape == (2, 128)
    assert encoder_output("pointnet", "pointcloud", "global", global_head="official").width == 128
    with pytest.raises(ValueError, match="dp_point_head='official' is not an option of encoder 'resnet18'"):
        ObsDiffusionConfig(device="cpu", obs_space="rgb", encoder="resnet18", dp_point_head="official")


def test_diffusion_weight_decay_exempts_biases_and_norms(tiny_dataset):
    fields = {
        k: v
        for k, v in paper("obs_diffusion", "rgb").items()
        if k not in ("image_input_size", "zero_init_extra_channels")
    }
    assert (fields["optimizer_weight_decay"], fields["optimizer_decay_exempt_1d"]) == (1e-4, True)
    policy, *_ = training_setup("obs_diffusion", "rgb", tiny_dataset, **fields)
    groups = policy.get_optim_params()
    decayed, exempt = [g for g in groups if "weight_decay" not in g], [g for g in groups if "weight_decay" in g]
    assert exempt and all(g["weight_decay"] == 0.0 and all(p.ndim <= 1 for p in g["params"]) for g in exempt)
    assert decayed and all(p.ndim > 1 for g in decayed for p in g["params"])
    assert sum(len(g["params"]) for g in groups) == len([p for p in policy.parameters() if p.requires_grad])
    optimizer = policy.config.get_optimizer_preset().build(groups)
    assert {g["weight_decay"] for g in optimizer.param_groups} == {1e-4, 0.0}
    act, *_ = training_setup("obs_act", "rgb", tiny_dataset)  # ACT: weight decay 0.05 on everything
    assert len(act.get_optim_params()) == 1 and act.config.get_optimizer_preset().weight_decay == 0.05


def test_gradient_clip_reaches_lerobots_trainer(tmp_path):
    assert paper("obs_act", "rgb")["optimizer_grad_clip_norm"] == 0.5
    config = ObsACTConfig(device="cpu", obs_space="rgb", **paper("obs_act", "rgb"))
    train = TrainPipelineConfig(dataset=DatasetConfig(repo_id="local/x"), policy=config, output_dir=tmp_path / "o")
    train.validate()  # what lerobot-train does: the optimizer comes from the policy's preset
    assert train.optimizer.grad_clip_norm == 0.5 and train.scheduler.pct_start == 0.1
    assert ObsACTConfig(device="cpu").get_optimizer_preset().grad_clip_norm == 10.0  # LeRobot's default kept
