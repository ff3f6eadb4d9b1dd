"""Encoder registry, ResNet stems, PointNet / point tokenizer behaviour."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torchvision

from lerobot_obsbench.encoders import (
    EncoderContext,
    EncoderOutput,
    available_encoders,
    default_encoder,
    encoder_info,
    encoder_output,
    make_encoder,
    register_encoder,
)
from lerobot_obsbench.encoders.point_tokenizer import sine_embedding_3d
from lerobot_obsbench.encoders.pretrained import CheckpointError
from lerobot_obsbench.schema import PointCloud, input_channels
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
from tests.support.helpers import CAM, frame_batch


def test_registry_declares_spaces_and_refuses_wrong_pairs():
    assert set(available_encoders()) == {
        *("resnet18", "resnet50", "vit_b", "multivit_b", "spatial_softmax"),
        *("pointnet", "spunet34", "dp3"),
        *("blind", "oracle"),
    }
    assert available_encoders("pointcloud") == ["dp3", "pointnet", "spunet34"]
    assert available_encoders("rgbd") == ["multivit_b", "resnet18", "resnet50", "spatial_softmax", "vit_b"]
    assert available_encoders("state") == ["oracle"] and available_encoders("none") == ["blind"]
    assert "pointnet" not in available_encoders("rgb") and "multivit_b" not in available_encoders("rgb")
    assert set(encoder_info("resnet18").spaces) == {"rgb", "depth", "rgbd", "pointmap"}
    assert set(encoder_info("vit_b").spaces) == {"rgb", "depth", "rgbd", "pointmap"}
    with pytest.raises(
        ValueError,
        match=r"does not accept obs_space='rgb'.*Encoders for 'rgb': resnet18, resnet50, spatial_softmax, vit_b",
    ):
        make_encoder("pointnet", "rgb")
    with pytest.raises(ValueError, match="Unknown encoder 'vit_h'.*pointnet"):
        make_encoder("vit_h", "rgb")


def test_registry_states_its_contract():
    # one default per space, declared in the registry
    assert [default_encoder(s) for s in ("rgb", "depth", "rgbd", "pointmap", "pointcloud")] == [
        "resnet50",
        "resnet50",
        "resnet50",
        "resnet50",
        "pointnet",
    ]
    # options come from the builder's signature; a typo is refused, naming the accepted ones
    options = "point_features, sampling, num_tokens, knn, position_scale, pipeline, global_head, norm"
    assert ", ".join(encoder_info("pointnet").options) == options
    with pytest.raises(TypeError, match=rf"'pointnet' takes no option\(s\) \['num_token'\]; it accepts: {options}"):
        make_encoder("pointnet", "pointcloud", num_token=64)
    with pytest.raises(
        TypeError, match=r"'resnet18' takes no option\(s\) \['knn'\]; it accepts: pretrained, input_size, zero_extra"
    ):
        encoder_output("resnet18", "rgb", knn=4)

    def build(obs_space, output, dim):
        return torch.nn.Identity()

    with pytest.raises(ValueError, match="'resnet18' is already registered"):
        register_encoder("resnet18", ("rgb",), "a second resnet18", lambda *a: EncoderOutput(None, 1))(build)
    with pytest.raises(ValueError, match="'resnet50' is already the default encoder of 'rgb'"):
        register_encoder("other", ("rgb",), "x", lambda *a: EncoderOutput(None, 1), default_for=("rgb",))(build)

    def swallowing(obs_space, output, dim, **anything):
        return torch.nn.Identity()

    with pytest.raises(ValueError, match=r"must name its options \(no \*args / \*\*kwargs\)"):
        register_encoder("swallower", ("rgb",), "x", lambda *a: EncoderOutput(None, 1))(swallowing)
    assert "other" not in available_encoders() and "swallower" not in available_encoders()


@pytest.mark.parametrize("output", ["tokens", "global"])
@pytest.mark.parametrize(
    "name,space,options",
    [
        ("resnet18", "rgb", {}),
        ("resnet18", "pointmap", {}),
        ("vit_b", "depth", {"image_size": (48, 64)}),
        ("multivit_b", "rgbd", {}),
        ("pointnet", "pointcloud", {"num_tokens": 24, "knn": 4}),
        ("pointnet", "pointcloud", {"num_tokens": 24, "knn": 4, "sampling": "pre"}),
    ],
)
def test_declared_output_is_what_the_encoder_outputs(name, space, options, output, cloud):
    """`encoder_output` answers before anything is built, for one or several cameras."""
    for cameras in (1, 2):
        declared = encoder_output(name, space, output, dim=40, context=EncoderContext(cameras, (48, 64)), **options)
        encoder = make_encoder(name, space, output, dim=40, **options).eval()
        with torch.no_grad():
            if space == "pointcloud":  # cameras are fused into one cloud
                result = encoder(cloud)
            else:
                result = encoder(torch.randn(2, cameras, input_channels(space), 48, 64))
        if output == "tokens":
            tokens, pos = result
            assert (
                declared.tokens is not None and tokens.shape[1:] == (declared.tokens, declared.width) == pos.shape[1:]
            )
        else:
            assert declared.tokens is None and result.shape[1:] == (declared.width,)


@pytest.mark.parametrize("space,channels", [("rgb", 3), ("depth", 1), ("rgbd", 4), ("pointmap", 6)])
def test_resnet_any_channel_count_tokens_and_global(space, channels):
    images = torch.randn(2, 2, channels, 64, 64)  # two cameras
    tok_enc = make_encoder("resnet18", space, output="tokens", dim=32)
    tokens, pos = tok_enc(images)
    assert tokens.shape == (2, 2 * 2 * 2, 32) and pos.shape == (1, 8, 32)
    assert encoder_output("resnet18", space, "tokens", dim=32, context=EncoderContext(2, (64, 64))) == EncoderOutput(
        8, 32
    )
    glob = make_encoder("resnet18", space, output="global")
    assert glob(images).shape == (2, 2 * 512)
    assert encoder_output("resnet18", space, "global", context=EncoderContext(2, (64, 64))) == EncoderOutput(None, 1024)


def _save_torchvision_resnet18(path):
    torch.manual_seed(0)
    net = torchvision.models.resnet18(weights=None)
    torch.save(net.state_dict(), path)
    return net


def test_pretrained_stem_extra_channels_start_at_zero(tmp_path):
    ckpt = tmp_path / "resnet18.pth"
    source = _save_torchvision_resnet18(ckpt).eval()
    rgbd = make_encoder("resnet18", "rgbd", output="global", pretrained=str(ckpt)).eval()
    stem = rgbd.body[0].weight
    assert torch.equal(stem[:, :3], source.conv1.weight) and (stem[:, 3] == 0).all()
    x = torch.randn(2, 1, 4, 64, 64)
    with torch.no_grad():
        ref = torch.flatten(source.avgpool(torch.nn.Sequential(*list(source.children())[:-2])(x[:, 0, :3])), 1)
        assert torch.allclose(rgbd(x), ref, atol=1e-5), "depth channel must not change the pretrained response"
    depth_only = make_encoder("resnet18", "depth", output="global", pretrained=str(ckpt))
    assert torch.allclose(depth_only.body[0].weight, source.conv1.weight.mean(1, keepdim=True))


def test_pretrained_wrong_architecture_is_refused(tmp_path):
    ckpt = tmp_path / "resnet50.pth"
    torch.save(torchvision.models.resnet50(weights=None).state_dict(), ckpt)
    with pytest.raises(CheckpointError, match="another architecture.*shape mismatches.*layer1.0.conv1.weight"):
        make_encoder("resnet18", "rgb", pretrained=str(ckpt))
    with pytest.raises(CheckpointError, match="is not a file"):
        make_encoder("resnet18", "rgb", pretrained=str(tmp_path / "nope.pth"))


def test_no_weights_are_downloaded_unless_asked(monkeypatch, tmp_path):
    def refuse(*args, **kwargs):
        raise AssertionError("tried to download weights")

    monkeypatch.setattr(torch.hub, "download_url_to_file", refuse)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))  # no cached copy may stand in for the download
    make_encoder("resnet50", "rgb")
    with pytest.raises(AssertionError, match="tried to download"):
        make_encoder("resnet18", "rgb", pretrained="imagenet")


def test_imagenet_offline_gives_a_clear_error(monkeypatch, tmp_path):
    def offline(*args, **kwargs):
        raise OSError("Name or service not known")

    monkeypatch.setattr(torch.hub, "download_url_to_file", offline)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    with pytest.raises(CheckpointError, match="--policy.pretrained=/path/to/resnet18.pth"):
        make_encoder("resnet18", "rgb", pretrained="imagenet")


@pytest.fixture(scope="module")
def cloud(synthetic_module):
    batch = frame_batch(synthetic_module, batch_size=3, size=40)
    return ObservationAdapter(AdapterConfig("pointcloud", [CAM], workspace=(-0.5, 0.5, -0.5, 0.5, 0.005, 0.5))).eval()(
        batch
    )


@pytest.mark.parametrize("sampling", ["post", "pre"])
def test_pointnet_tokens_and_global(cloud, sampling):
    enc = make_encoder("pointnet", "pointcloud", output="tokens", dim=48, num_tokens=32, knn=8, sampling=sampling)
    tokens, pos = enc(cloud)
    assert tokens.shape == (3, 32, 48) and pos.shape == (3, 32, 48)
    assert torch.isfinite(tokens).all()
    glob = make_encoder("pointnet", "pointcloud", output="global", num_tokens=32, knn=8, sampling=sampling)
    assert glob(cloud).shape == (3, 512)
    assert encoder_output("pointnet", "pointcloud", "global", sampling=sampling) == EncoderOutput(None, 512)


def _with_padding(cloud: PointCloud, extra: int) -> PointCloud:
    pad = lambda t, v: torch.cat([t, torch.full((t.shape[0], extra, *t.shape[2:]), v, dtype=t.dtype)], 1)
    return PointCloud(pad(cloud.xyz, 3.0), pad(cloud.features, 7.0), pad(cloud.mask, False))


@pytest.mark.parametrize("sampling", ["post", "pre"])
def test_padding_never_changes_the_output(cloud, sampling):
    """Masked BatchNorm + masked FPS/kNN: garbage in padded slots has no effect, in training mode too."""
    torch.manual_seed(0)
    enc = make_encoder("pointnet", "pointcloud", output="tokens", dim=16, num_tokens=16, knn=4, sampling=sampling)
    enc.train()
    a = enc(cloud)[0]
    b = enc(_with_padding(cloud, 50))[0]
    assert torch.allclose(a, b, atol=1e-5)


def test_fewer_points_than_tokens_repeats_the_first_token(cloud):
    enc = make_encoder("pointnet", "pointcloud", output="tokens", dim=16, num_tokens=4096, knn=4).eval()
    tokens, pos = enc(cloud)
    n0 = int(cloud.mask[0].sum())
    assert n0 < 4096
    assert torch.equal(tokens[0, n0:], tokens[0, :1].expand(4096 - n0, -1))
    assert not torch.equal(tokens[0, 1], tokens[0, 0])


def test_sine_embedding_is_distinct_per_position():
    xyz = torch.tensor([[[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.0, 0.01]]])
    emb = sine_embedding_3d(xyz, 64)
    assert emb.shape == (1, 3, 64)
    assert (emb[0, 0] - emb[0, 1]).abs().sum() > 0.1 and (emb[0, 1] - emb[0, 2]).abs().sum() > 0.1


def test_every_encoder_module_in_the_package_registers_with_no_list_to_edit():
    """The package imports each of its modules: every module that registers an encoder is in the registry, and
    nothing else is."""
    import lerobot_obsbench.encoders as package

    folder = Path(package.__file__).parent
    defining = {
        f"{package.__name__}.{path.stem}"
        for path in folder.glob("*.py")
        if path.stem != "registry" and "register_encoder(" in path.read_text()
    }
    registered = {encoder_info(name).build.__module__ for name in available_encoders()}
    assert len(defining) >= 8 and registered == defining
