"""The encoder zoo: parameter counts against the paper's Table 1, pretrained loaders on checkpoints written in
each official key layout (every key consumed, outputs identical to the source module's), bad checkpoints, and
every (encoder x accepted space x policy) pair training a few steps."""

from __future__ import annotations

import pytest
import torch
import torchvision
from torch import nn

from lerobot_obsbench.encoders import available_encoders, encoder_info, make_encoder
from lerobot_obsbench.encoders.pretrained import CheckpointError
from tests.support.helpers import first_batch, one_thread, training_setup

WIDTH = 768


def n_params(*modules: nn.Module) -> float:
    return sum(p.numel() for m in modules for p in m.parameters()) / 1e6


def test_parameter_counts_match_table_1():
    """Counted modules: the backbone the paper counts, without policy-specific heads (token projections).
    resnet50: torchvision ResNet-50 up to layer4 (no fc). vit_b: timm ViT-B/16 at 224 px incl. patch
    embedding, [CLS], position embedding and final norm. multivit_b: both patch adapters (incl. their fixed
    position maps), the global token and the 12 blocks."""
    resnet = make_encoder("resnet50", "rgb", output="global")
    assert n_params(resnet.body) == pytest.approx(23.5, rel=0.05)
    vit = make_encoder("vit_b", "rgb", output="global", image_size=224)
    assert n_params(vit.vit) == pytest.approx(85.8, rel=0.05)
    multivit = make_encoder("multivit_b", "rgbd", output="global")
    counted = n_params(multivit.input_adapters, multivit.encoder) + multivit.global_tokens.numel() / 1e6
    assert counted == pytest.approx(86.1, rel=0.05)
    spunet = make_encoder("spunet34", "pointcloud", output="global")
    assert n_params(spunet.backbone) == pytest.approx(39.2, rel=0.05)
    # PointNet: the paper's own PointNet (5 bias-free kernel-1 convs + BN, 6 input channels) has 84,480
    # parameters, which is what `pointnet` has; Table 1's 0.14M is not that module (see README).
    pointnet = make_encoder("pointnet", "pointcloud", output="global")
    assert sum(p.numel() for p in pointnet.backbone.parameters()) == 6 * 64 + 64 * 64 * 2 + 64 * 128 + 128 * 512 + 2 * (
        64 * 3 + 128 + 512
    )


def timm_vit(**kwargs):
    from timm.models.vision_transformer import VisionTransformer

    return VisionTransformer(
        patch_size=16, num_classes=0, embed_dim=WIDTH, depth=12, num_heads=12, global_pool="token", **kwargs
    ).eval()


def test_vc1_mae_checkpoint_loads_into_vit_b(tmp_path):
    torch.manual_seed(0)
    source = timm_vit(img_size=224, dynamic_img_size=True)
    state = dict(source.state_dict())
    decoder = {
        "mask_token": torch.zeros(1, 1, 512),
        "decoder_embed.weight": torch.zeros(512, WIDTH),
        "decoder_pos_embed": torch.zeros(1, 197, 512),
        "decoder_pred.weight": torch.zeros(768, 512),
    }
    ckpt = tmp_path / "vc1_vitb.pth"
    torch.save({"model": {**state, **decoder}}, ckpt)

    x224, x128 = torch.randn(2, 3, 224, 224), torch.randn(2, 3, 128, 128)
    same = make_encoder("vit_b", "rgb", output="global", pretrained=str(ckpt), image_size=224).eval()
    report = same.load_mae(str(ckpt))
    assert report["loaded"] == len(state) and sorted(report["ignored"]) == sorted(decoder)
    resized = make_encoder("vit_b", "rgb", output="global", pretrained=str(ckpt), image_size=128).eval()
    assert resized.vit.pos_embed.shape == (1, 1 + 8 * 8, WIDTH)  # resampled to the 128 px patch grid
    rgbd = make_encoder("vit_b", "rgbd", output="global", pretrained=str(ckpt), image_size=128).eval()
    with torch.no_grad():
        torch.testing.assert_close(same(x224[:, None]), source(x224))
        # timm resamples its 14x14 position grid on the fly for 128 px: the same numbers as loading resized
        torch.testing.assert_close(resized(x128[:, None]), source(x128))
        extra = torch.cat([x128, torch.randn(2, 1, 128, 128)], dim=1)
        torch.testing.assert_close(rgbd(extra[:, None]), source(x128))  # depth filters start at zero


def test_r3m_checkpoint_loads_into_resnet50(tmp_path):
    torch.manual_seed(0)
    convnet = torchvision.models.resnet50(weights=None)
    convnet.fc = nn.Identity()
    convnet.eval()
    language = {"module.lang_enc.weight": torch.zeros(8, 8), "module.lang_rew.0.weight": torch.zeros(4, 8)}
    r3m = {f"module.convnet.{k}": v for k, v in convnet.state_dict().items()}
    ckpt = tmp_path / "r3m_50.pt"
    torch.save({"r3m": {**r3m, **language}}, ckpt)
    encoder = make_encoder("resnet50", "rgb", output="global", pretrained=str(ckpt)).eval()
    x = torch.randn(2, 3, 96, 96)
    with torch.no_grad():
        torch.testing.assert_close(encoder(x[:, None]), convnet(x))


def test_multimae_checkpoint_loads_into_multivit_b(tmp_path):
    torch.manual_seed(0)
    source = make_encoder("multivit_b", "rgbd", output="global").eval()
    backbone = {k: v for k, v in source.state_dict().items() if not k.startswith("head.")}
    others = {
        "input_adapters.semseg.class_emb.weight": torch.zeros(134, 64),
        "output_adapters.rgb.decoder.0.weight": torch.zeros(4, 4),
    }
    ckpt = tmp_path / "multimae-b.pth"
    torch.save({"model": {**backbone, **others}}, ckpt)
    torch.manual_seed(1)
    loaded = make_encoder("multivit_b", "rgbd", output="global", pretrained=str(ckpt)).eval()
    report = loaded.load_multimae(str(ckpt))
    assert report["loaded"] == len(backbone)
    x = torch.randn(2, 1, 4, 128, 128)
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), source(x))
    # the layout is MultiMAE's: adapters per modality, one global token appended after the patch tokens
    assert {
        "input_adapters.rgb.proj.weight",
        "input_adapters.depth.pos_emb",
        "global_tokens",
        "encoder.11.mlp.fc2.weight",
    } <= set(backbone)
    assert backbone["input_adapters.depth.proj.weight"].shape == (WIDTH, 1, 16, 16)


def test_wrong_architecture_and_offline_hub_are_clear(tmp_path, monkeypatch):
    from timm.models.vision_transformer import VisionTransformer

    vit_small = VisionTransformer(img_size=224, patch_size=16, num_classes=0, embed_dim=384, depth=2, num_heads=6)
    ckpt = tmp_path / "vit_s.pth"
    torch.save({"model": vit_small.state_dict()}, ckpt)
    with pytest.raises(CheckpointError, match="another architecture.*shape mismatches.*cls_token"):
        make_encoder("vit_b", "rgb", pretrained=str(ckpt))
    torch.save(torchvision.models.resnet50(weights=None).state_dict(), tmp_path / "r50.pth")
    with pytest.raises(CheckpointError, match="another architecture.*missing keys.*global_tokens"):
        make_encoder("multivit_b", "rgbd", pretrained=str(tmp_path / "r50.pth"))

    import socket

    import huggingface_hub.constants

    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hub"))
    connections = []  # offline must fail at once: no connection is even attempted (no timeout to wait out)
    monkeypatch.setattr(socket.socket, "connect", lambda self, address: connections.append(address))
    with pytest.raises(CheckpointError, match="could not fetch 'vc1_vitb.pth' from the Hub.*local file path"):
        make_encoder("vit_b", "rgb", pretrained="facebook/vc1-base:vc1_vitb.pth")
    assert connections == []
    with pytest.raises(CheckpointError, match="ORG/REPO:FILENAME"):
        make_encoder("vit_b", "rgb", pretrained="not-a-file.pth")


def small_cloud(batch: int = 2, points: int = 400, seed: int = 0):
    from lerobot_obsbench.schema import PointCloud

    g = torch.Generator().manual_seed(seed)
    xyz = torch.rand(batch, points, 3, generator=g) * 0.15
    mask = torch.ones(batch, points, dtype=torch.bool)
    mask[1, points // 2 :] = False
    return PointCloud(xyz, torch.cat([torch.rand(batch, points, 3, generator=g) * 2 - 1, xyz], dim=-1), mask)


def test_spunet34_forward_backward_on_cpu():
    encoder = make_encoder("spunet34", "pointcloud", output="tokens", dim=32, num_tokens=16, knn=4)
    cloud = small_cloud()
    tokens, pos = encoder(cloud)
    assert tokens.shape == (2, 16, 32) and pos.shape == (2, 16, 32)
    tokens.square().mean().backward()  # spconv's CPU backward: needs the stream guard on a CUDA-built torch
    grads = [p.grad for p in encoder.backbone.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert encoder.backbone.conv_input.conv.weight.grad.abs().sum() > 0
    # padding never leaks: the second cloud's padded points do not change its valid points' features
    # (one thread: spconv's CPU kernels then add in a fixed order, so equal means bit-identical)
    with one_thread(), torch.no_grad():
        features = encoder.backbone.eval()(cloud.xyz, cloud.features, cloud.mask)
        cloud.features[1, 300:] += 5.0
        again = encoder.backbone(cloud.xyz, cloud.features, cloud.mask)
    assert torch.equal(again[1, :200], features[1, :200])


def test_ponderv2_checkpoint_loads_with_its_conditional_norms(tmp_path):
    """A checkpoint in PonderV2's layout (PDNorm: per-dataset BatchNorms + adaptive modulation from a dataset
    embedding) gives the same outputs as the source network running PDNorm for the chosen dataset."""
    torch.manual_seed(0)
    source = make_encoder("spunet34", "pointcloud", output="global").backbone.eval()
    for module in source.modules():  # non-trivial norm statistics
        if isinstance(module, nn.BatchNorm1d):
            module.running_mean.uniform_(-0.1, 0.1)
            module.running_var.uniform_(0.5, 1.5)
            module.weight.data.uniform_(0.5, 1.5)
    table = torch.randn(3, 256)
    state, modulations = {"module.embedding_table.weight": table}, {}
    norms = {name for name, m in source.named_modules() if isinstance(m, nn.BatchNorm1d)}
    for key, value in source.state_dict().items():
        norm, _, field = key.rpartition(".")
        if norm in norms:
            for k in range(3):  # condition 0 (ScanNet) holds the source's statistics, the others garbage
                state[f"module.backbone.{norm}.bns.{k}.{field}"] = (
                    value if k == 0 else torch.randn_like(value.float()).to(value.dtype)
                )
        else:
            state[f"module.backbone.{key}"] = value
    for norm in norms:
        linear = nn.Linear(256, 2 * source.get_submodule(norm).num_features)
        nn.init.normal_(linear.weight, std=0.01)
        modulations[norm] = linear
        state[f"module.backbone.{norm}.modulation.1.weight"] = linear.weight.detach()
        state[f"module.backbone.{norm}.modulation.1.bias"] = linear.bias.detach()
    ckpt = tmp_path / "ponderv2.pth"
    torch.save({"state_dict": state}, ckpt)

    loaded = make_encoder("spunet34", "pointcloud", output="global", pretrained=str(ckpt)).backbone.eval()
    cloud = small_cloud()

    def pdnorm(norm):  # PDNorm semantics, written out: BN, then feat * (1 + scale) + shift from the context
        def hook(module, args, out):
            shift, scale = modulations[norm](nn.functional.silu(table[0])).chunk(2)
            return out * (1 + scale) + shift

        return hook

    for norm in norms:
        source.get_submodule(norm).register_forward_hook(pdnorm(norm))
    with one_thread(), torch.no_grad():  # spconv's multi-threaded CPU sums differ run to run (~1e-3 here)
        expected = source(cloud.xyz, cloud.features, cloud.mask)
        error = (loaded(cloud.xyz, cloud.features, cloud.mask) - expected).abs()
    # Folding the scale into the affine only changes float rounding, but through 24 random layers a rounding
    # difference can flip a ReLU near zero and move a few outputs by ~1%. So: the bulk must agree to rounding
    # (mean and 99.9th percentile), the worst element within a few percent. A skipped modulation or the wrong
    # dataset's norms move the mean error to ~1e-1 of the output scale.
    scale = expected.abs().max()
    print(f"PonderV2 load: max error {error.max() / scale:.2e}, mean {error.mean() / scale:.2e} of the output scale")
    assert error.mean() <= 1e-5 * scale and torch.quantile(error.flatten(), 0.999) <= 1e-3 * scale
    assert error.max() <= 5e-2 * scale
    assert expected[cloud.mask].abs().mean() > 0.05  # not a trivially small output


# resnet18 / pointnet train in test_policies.py and test_train_cli.py; the rest of the registry here.
ZOO = [(name, space) for name in ("resnet50", "vit_b", "multivit_b") for space in encoder_info(name).spaces]
ZOO += [pytest.param("spunet34", "pointcloud", marks=pytest.mark.slow)]


@pytest.mark.parametrize("policy_type", ["obs_act", "obs_diffusion"])
@pytest.mark.parametrize("encoder,obs_space", ZOO)
def test_zoo_encoders_train(tiny_dataset, policy_type, encoder, obs_space):
    policy, pre, _, dataset = training_setup(policy_type, obs_space, tiny_dataset, encoder=encoder)
    optimizer = torch.optim.AdamW(policy.parameters(), lr=1e-4)
    for _ in range(2):
        loss, _ = policy.forward(first_batch(dataset, pre, batch_size=2, shuffle=True))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert torch.isfinite(loss)
    assert encoder in available_encoders(obs_space)


@pytest.mark.parametrize(
    "fields, words",
    [
        ({"obs_space": "rgb", "sampling": "pre"}, ["sampling='pre'", "point-cloud design choice", "obs_space='rgb'"]),
        ({"obs_space": "rgbd", "point_features": "xyz"}, ["point_features='xyz'", "point-cloud design choice"]),
        ({"obs_space": "depth", "frame": "ee"}, ["frame='ee'", "pointcloud or pointmap"]),
        ({"obs_space": "pointcloud", "pretrained": "w.pth"}, ["'pointnet' has no pretrained weights", "spunet34"]),
    ],
)
def test_ablation_values_that_do_not_fit_fail_at_config_time(fields, words):
    from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig

    for config_class in (ObsACTConfig, ObsDiffusionConfig):
        with pytest.raises(ValueError) as err:
            config_class(**fields)
        for word in words:
            assert word in str(err.value)
    with pytest.raises(ValueError, match="Unknown denoiser 'mlp'; choose one of unet, transformer"):
        ObsDiffusionConfig(denoiser="mlp")


def test_ablations_as_config_values_train(tiny_dataset):
    """The paper's design ablations are plain config values: pre-sampling, xyz / rgb point features, the
    camera and end-effector frames, pointmap and depth with ViT, and DP's transformer denoiser."""
    cases = [
        ("obs_act", "pointcloud", {"sampling": "pre"}),
        ("obs_act", "pointcloud", {"point_features": "xyz"}),
        ("obs_act", "pointcloud", {"point_features": "rgb", "frame": "camera"}),
        ("obs_diffusion", "pointcloud", {"frame": "ee", "sampling": "pre"}),
        ("obs_act", "pointmap", {"encoder": "vit_b"}),
        ("obs_diffusion", "depth", {"encoder": "vit_b"}),
        (
            "obs_diffusion",
            "rgb",
            {"encoder": "resnet18", "denoiser": "transformer", "transformer_layers": 2, "transformer_dim": 32},
        ),
    ]
    for policy_type, space, fields in cases:
        policy, pre, _, dataset = training_setup(policy_type, space, tiny_dataset, **fields)
        loss, _ = policy.forward(first_batch(dataset, pre, batch_size=2))
        loss.backward()
        assert torch.isfinite(loss), (policy_type, space, fields)
        if fields.get("denoiser") == "transformer":
            assert type(policy.diffusion.unet).__name__ == "DiffusionTransformer"
            policy.eval()
            with torch.no_grad():
                actions = policy.diffusion.generate_actions(first_batch(dataset, pre, batch_size=1))
            assert actions.shape == (1, policy.config.n_action_steps, dataset.meta.features["action"]["shape"][0])
