"""The compact encoders: DP3's point encoder (`dp3`) and the spatial soft-argmax keypoint encoder
(`spatial_softmax`): shapes against the registry's declaration, DP3's published sizes, padding invariance,
keypoints that follow what is bright, and one training step of each policy with each encoder."""

from __future__ import annotations

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_obsbench import geometry
from lerobot_obsbench.encoders import EncoderContext, EncoderOutput, available_encoders, encoder_output, make_encoder
from lerobot_obsbench.presets import model_sizes
from lerobot_obsbench.schema import PointCloud, available_spaces, input_channels, single_spaces
from tests.support.helpers import CAM, frame_batch

IMAGE_SPACES = single_spaces(lambda s: s.image)
POINT_SPACES = single_spaces(lambda s: s.points)


def _cloud(n: int, channels: int, batch: int = 2, seed: int = 0) -> PointCloud:
    g = torch.Generator().manual_seed(seed)
    xyz = torch.rand(batch, n, 3, generator=g) * 0.3
    rgb = torch.rand(batch, n, 3, generator=g) * 2 - 1
    features = torch.cat([rgb, xyz], -1) if channels == 6 else xyz
    return PointCloud(xyz, features, torch.ones(batch, n, dtype=torch.bool))


def _params(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


# ---- dp3 ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("point_features", ["xyz", "rgb+xyz"])
def test_dp3_outputs_what_the_registry_declares(point_features):
    cloud = _cloud(40, input_channels("pointcloud", point_features))
    options = {"point_features": point_features, "num_tokens": 16}
    encoder = make_encoder("dp3", "pointcloud", "global", **options).eval()
    with torch.no_grad():
        feature = encoder(cloud)
    assert encoder_output("dp3", "pointcloud", "global", **options) == EncoderOutput(None, 64)
    assert feature.shape == (2, 64) and torch.isfinite(feature).all()

    encoder = make_encoder("dp3", "pointcloud", "tokens", dim=24, **options).eval()
    with torch.no_grad():
        tokens, pos = encoder(cloud)
    assert encoder_output("dp3", "pointcloud", "tokens", dim=24, **options) == EncoderOutput(1, 24)
    assert tokens.shape == (2, 1, 24) and pos.shape == (1, 1, 24)
    assert not torch.allclose(tokens[0], tokens[1])  # the token depends on the cloud


def test_dp3_has_dp3s_published_sizes():
    # DP3, 3D-Diffusion-Policy/diffusion_policy_3d/model/vision/pointnet_extractor.py, with dp3.yaml's
    # pointcloud_encoder_cfg (use_layernorm: true, final_norm: layernorm, out_channels: encoder_output_dim = 64).
    def linear(i, o):
        return i * o + o

    def layer_norm(c):
        return 2 * c

    # PointNetEncoderXYZ: block_channel [64, 128, 256], each Linear + LayerNorm + ReLU; final_projection
    # Linear(256, 64) + LayerNorm(64).
    xyz = (
        linear(3, 64)
        + layer_norm(64)
        + linear(64, 128)
        + layer_norm(128)
        + linear(128, 256)
        + layer_norm(256)
        + linear(256, 64)
        + layer_norm(64)
    )
    assert xyz == 59_072
    assert _params(make_encoder("dp3", "pointcloud", "global", point_features="xyz")) == xyz
    # PointNetEncoderXYZRGB: block_channel [64, 128, 256, 512]; the last Linear(256, 512) has no norm or ReLU;
    # final_projection Linear(512, 64) + LayerNorm(64).
    rgb = (
        linear(6, 64)
        + layer_norm(64)
        + linear(64, 128)
        + layer_norm(128)
        + linear(128, 256)
        + layer_norm(256)
        + linear(256, 512)
        + linear(512, 64)
        + layer_norm(64)
    )
    assert rgb == 207_232
    encoder = make_encoder("dp3", "pointcloud", "global", point_features="rgb+xyz")
    assert _params(encoder) == rgb
    assert isinstance(encoder.mlp[-1], torch.nn.Linear)  # max-pooled straight after the bare 512 layer
    # ACT's token adds Linear(64, dim) and one learned position
    assert _params(make_encoder("dp3", "pointcloud", "tokens", dim=32, point_features="xyz")) == xyz + 64 * 32 + 32 + 32


@pytest.mark.parametrize("num_tokens", [16, 512])  # FPS to 16 of the 40 points; all 40 points
@pytest.mark.parametrize("output", ["global", "tokens"])
def test_dp3_ignores_padding(num_tokens, output):
    cloud = _cloud(40, 6)
    g = torch.Generator().manual_seed(1)
    # garbage points, far away and bright, interleaved with the real ones and appended after them
    real = torch.ones(2, 100, dtype=torch.bool)
    real[:, 1:60:2] = False
    real[:, 70:] = False  # 40 slots: the real points, in order
    xyz = torch.randn(2, 100, 3, generator=g) * 50
    features = torch.randn(2, 100, 6, generator=g) * 50
    xyz[real], features[real] = cloud.xyz.reshape(-1, 3), cloud.features.reshape(-1, 6)
    padded = PointCloud(xyz, features, real)
    torch.manual_seed(0)
    encoder = make_encoder("dp3", "pointcloud", output, dim=16, point_features="rgb+xyz", num_tokens=num_tokens)
    encoder.eval()
    with torch.no_grad():
        plain, with_padding = encoder(cloud), encoder(padded)
    if output == "tokens":
        plain, with_padding = plain[0], with_padding[0]
    torch.testing.assert_close(with_padding, plain)
    # and the sampled points are FPS's when the cloud has more than num_tokens
    features, mask = encoder.sample(padded)
    assert int(mask[0].sum()) == min(num_tokens, 40)
    if num_tokens < 40:
        idx, _ = geometry.farthest_point_sample(cloud.xyz, cloud.mask, num_tokens)
        torch.testing.assert_close(features, geometry.gather(cloud.features, idx))


def test_dp3_is_refused_where_it_does_not_fit():
    with pytest.raises(ValueError, match="Encoder 'dp3' does not accept obs_space='rgb'"):
        make_encoder("dp3", "rgb")
    with pytest.raises(ValueError, match="'dp3' encodes xyz .* or rgb\\+xyz .*point_features='rgb'"):
        make_encoder("dp3", "pointcloud", point_features="rgb")
    with pytest.raises(ValueError, match="point_features='rgb'"):
        encoder_output("dp3", "pointcloud", point_features="rgb")
    with pytest.raises(TypeError, match="'dp3' takes no option"):
        make_encoder("dp3", "pointcloud", knn=4)
    assert "dp3" in available_encoders("pointcloud")
    assert [s for s in available_spaces() if "dp3" in available_encoders(s)] == list(POINT_SPACES)


# ---- spatial_softmax -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("cameras", [1, 2])
@pytest.mark.parametrize("output", ["tokens", "global"])
def test_spatial_softmax_outputs_what_the_registry_declares(cameras, output):
    size = (48, 64)
    context = EncoderContext(cameras=cameras, image_size=size)
    declared = encoder_output("spatial_softmax", "rgbd", output, dim=24, context=context, image_size=size)
    torch.manual_seed(0)
    encoder = make_encoder("spatial_softmax", "rgbd", output, dim=24, image_size=size).eval()
    with torch.no_grad():
        out = encoder(torch.randn(3, cameras, 4, *size))
    if output == "tokens":
        tokens, pos = out
        assert declared == EncoderOutput(32 * cameras, 24)
        assert tokens.shape == (3, declared.tokens, declared.width) and pos.shape == (1, declared.tokens, 24)
        if cameras == 2:  # the cameras' keypoints sit at different positions
            assert not torch.allclose(pos[0, :32], pos[0, 32:])
    else:
        assert declared == EncoderOutput(None, 64 * cameras)
        assert out.shape == (3, declared.width)
    keypoints = encoder.keypoints(torch.randn(3, cameras, 4, *size))
    assert keypoints.shape == (3, cameras, 32, 2) and keypoints.abs().max() <= 1


def test_spatial_softmax_frame_size_and_channels():
    for space in IMAGE_SPACES:
        encoder = make_encoder("spatial_softmax", space, "global", image_size=32, num_keypoints=8)
        assert encoder.backbone[0].in_channels == input_channels(space)
        assert encoder(torch.randn(1, 1, input_channels(space), 32, 32)).shape == (1, 16)
    assert encoder.pool.pos_grid.shape == (8 * 8, 2)  # 32 px -> an 8 x 8 soft-argmax grid
    # frames resized first (image_input_size): the grid is built for the resized frame
    resized = make_encoder("spatial_softmax", "rgb", "global", image_size=(40, 50), input_size=64)
    assert resized.pool.pos_grid.shape == (16 * 16, 2)
    assert resized(torch.randn(1, 1, 3, 40, 50)).shape == (1, 64)
    with pytest.raises(ValueError, match="built for 32x32 frames .* got 40x40"):
        make_encoder("spatial_softmax", "rgb", "global", image_size=32)(torch.randn(1, 1, 3, 40, 40))


def _blob(x: int, y: int, size: int = 32, side: int = 6) -> torch.Tensor:
    """(1, 1, 1, size, size) depth-like frame: zero with a bright square whose top-left corner is (x, y)."""
    frame = torch.zeros(1, 1, 1, size, size)
    frame[..., y : y + side, x : x + side] = 1.0
    return frame


def _brightness_follower() -> torch.nn.Module:
    """spatial_softmax whose convolutions average (all channels alike) and whose keypoint maps are a steep
    function of that average: every keypoint sits where the frame is brightest."""
    encoder = make_encoder("spatial_softmax", "depth", "global", image_size=32, num_keypoints=4)
    with torch.no_grad():
        for conv in [m for m in encoder.backbone if isinstance(m, torch.nn.Conv2d)]:
            conv.weight.fill_(1.0 / conv.weight[0].numel())
            conv.bias.zero_()
        encoder.pool.nets.weight.fill_(20.0 / encoder.pool.nets.in_channels)
        encoder.pool.nets.bias.zero_()
    return encoder.eval()


def test_keypoints_follow_a_bright_square():
    encoder = _brightness_follower()
    with torch.no_grad():
        top_left = encoder.keypoints(_blob(4, 4))[0, 0]
        right = encoder.keypoints(_blob(22, 4))[0, 0]
        down = encoder.keypoints(_blob(4, 22))[0, 0]
    assert (top_left < -0.3).all()  # x along the width, y along the height, both in [-1, 1]
    assert (right[:, 0] - top_left[:, 0] > 0.8).all() and (right[:, 1] - top_left[:, 1]).abs().max() < 0.1
    assert (down[:, 1] - top_left[:, 1] > 0.8).all() and (down[:, 0] - top_left[:, 0]).abs().max() < 0.1

    # gradient: brightening a spot right of the square pulls the keypoint right, one left of it pulls it left
    frame = _blob(12, 13).requires_grad_()
    encoder.keypoints(frame)[0, 0, :, 0].sum().backward()
    pull = frame.grad[0, 0, 0]
    assert pull[14:17, 20:23].sum() > 0 and pull[14:17, 7:10].sum() < 0

    # a freshly initialised (seeded) encoder's features also move with the square, in both outputs
    torch.manual_seed(0)
    fresh = make_encoder("spatial_softmax", "depth", "global", image_size=32).eval()
    torch.manual_seed(0)
    tokens = make_encoder("spatial_softmax", "depth", "tokens", dim=16, image_size=32).eval()
    with torch.no_grad():
        assert (fresh(_blob(4, 4)) - fresh(_blob(22, 22))).abs().max() > 1e-3
        assert (tokens(_blob(4, 4))[0] - tokens(_blob(22, 22))[0]).abs().max() > 1e-3
        torch.testing.assert_close(fresh(_blob(4, 4)), fresh(_blob(4, 4)))


def test_spatial_softmax_trains_end_to_end():
    torch.manual_seed(0)
    encoder = make_encoder("spatial_softmax", "rgb", "tokens", dim=16, image_size=32, num_keypoints=8)
    tokens, pos = encoder(torch.randn(2, 2, 3, 32, 32))
    (tokens.square().mean() + pos.square().mean()).backward()
    for name, param in encoder.named_parameters():
        assert param.grad is not None and param.grad.abs().sum() > 0, name


def test_spatial_softmax_is_refused_where_it_does_not_fit():
    assert set(s for s in available_spaces() if "spatial_softmax" in available_encoders(s)) == set(IMAGE_SPACES)
    for space in (*POINT_SPACES, "none"):
        with pytest.raises(ValueError, match=f"Encoder 'spatial_softmax' does not accept obs_space='{space}'"):
            make_encoder("spatial_softmax", space)
    with pytest.raises(TypeError, match="'spatial_softmax' takes no option"):
        make_encoder("spatial_softmax", "rgb", pretrained="imagenet")


# ---- through the policies ----------------------------------------------------------------------------------


SENSOR_SHAPES = {"images": (3, 32, 32), "depth": (32, 32, 1), "intrinsics": (3, 3), "cam2world": (4, 4)}


def _policy(policy_type: str, obs_space: str, encoder: str, **fields):
    from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig
    from lerobot_obsbench.policies.obs_act.modeling_obs_act import ObsACTPolicy
    from lerobot_obsbench.policies.obs_diffusion.modeling_obs_diffusion import ObsDiffusionPolicy

    config_cls, policy_cls = {
        "obs_act": (ObsACTConfig, ObsACTPolicy),
        "obs_diffusion": (ObsDiffusionConfig, ObsDiffusionPolicy),
    }[policy_type]
    inputs = {
        f"observation.{kind}.{CAM}": PolicyFeature(FeatureType.VISUAL if kind == "images" else FeatureType.STATE, shape)
        for kind, shape in SENSOR_SHAPES.items()
    }
    inputs["observation.state"] = PolicyFeature(FeatureType.STATE, (15,))
    config = config_cls(
        device="cpu",
        obs_space=obs_space,
        encoder=encoder,
        workspace=[-0.5, 0.5, -0.5, 0.5, 0.005, 0.5],
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (7,))},
        **model_sizes("tiny", policy_type),
        **fields,
    )
    torch.manual_seed(0)
    return policy_cls(config)


def _training_batch(synthetic, policy) -> dict:
    frames = {k: v for k, v in frame_batch(synthetic, batch_size=2, size=32).items() if k.startswith("observation")}
    config = policy.config
    if config.type == "obs_diffusion":  # n_obs_steps observation steps, a horizon of actions
        frames = {k: torch.stack([v] * config.n_obs_steps, 1) for k, v in frames.items()}
        steps = config.horizon
    else:
        steps = config.chunk_size
    g = torch.Generator().manual_seed(0)
    return {
        **frames,
        "action": torch.randn(2, steps, 7, generator=g),
        "action_is_pad": torch.zeros(2, steps, dtype=torch.bool),
    }


@pytest.mark.parametrize("policy_type", ["obs_act", "obs_diffusion"])
@pytest.mark.parametrize(
    "obs_space,encoder,fields",
    [("pointcloud", "dp3", {"num_tokens": 4, "point_features": "xyz"}), ("rgb", "spatial_softmax", {})],
)
def test_policies_train_with_the_compact_encoders(synthetic_module, policy_type, obs_space, encoder, fields):
    policy = _policy(policy_type, obs_space, encoder, **fields)
    observation = policy.model.observation if policy_type == "obs_act" else policy.diffusion.observation
    context = policy.config.encoder_context()
    output = "tokens" if policy_type == "obs_act" else "global"
    declared = encoder_output(encoder, obs_space, output, dim=32, context=context, **policy.config.encoder_options())
    if policy_type == "obs_act":
        assert declared.tokens == (1 if encoder == "dp3" else 32) and observation.out_dim == 32
    else:
        assert observation.out_dim == declared.width == 64
    if encoder == "dp3":
        assert observation.encoder.num_points == 4 and observation.encoder.mlp[0].in_features == 3
        cloud = observation.adapter(frame_batch(synthetic_module, batch_size=2, size=32))
        assert (cloud.mask.sum(1) > 4).all()  # so DP3's FPS runs
    else:
        assert observation.encoder.frame_size == (32, 32)  # the soft-argmax grid of the camera resolution
    policy.train()
    loss, _ = policy.forward(_training_batch(synthetic_module, policy))
    assert torch.isfinite(loss)
    loss.backward()
    grads = [p.grad for p in observation.encoder.parameters()]
    assert all(g is not None for g in grads) and sum(float(g.abs().sum()) for g in grads) > 0


def test_policy_configs_refuse_what_the_compact_encoders_do_not_take():
    from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig

    with pytest.raises(ValueError, match="knn=4 is not an option of encoder 'dp3'"):
        ObsACTConfig(device="cpu", obs_space="pointcloud", encoder="dp3", knn=4)
    with pytest.raises(ValueError, match="dp_point_head='official' is not an option of encoder 'dp3'"):
        ObsDiffusionConfig(device="cpu", obs_space="pointcloud", encoder="dp3", dp_point_head="official")
    with pytest.raises(ValueError, match="does not accept obs_space='pointcloud'"):
        ObsACTConfig(device="cpu", obs_space="pointcloud", encoder="spatial_softmax")
    with pytest.raises(ValueError, match="zero_init_extra_channels=True is not an option of encoder 'spatial_softmax'"):
        ObsDiffusionConfig(device="cpu", obs_space="rgbd", encoder="spatial_softmax", zero_init_extra_channels=True)


@pytest.mark.parametrize(
    ("preset", "policy_type"),
    [(p, t) for p in ("paper", "cpu", "tiny") for t in ("obs_act", "obs_diffusion")] + [("dp3", "obs_diffusion")],
)
def test_every_preset_configures_every_registered_encoder(preset, policy_type):
    """A preset keys fields by the encoders that take them: each (space, encoder) pair gets a config its policy
    accepts (a field the encoder would ignore is refused, so this fails on a preset that sets one)."""
    from lerobot.configs.policies import PreTrainedConfig

    from lerobot_obsbench.presets import preset_overrides

    for obs_space in available_spaces():
        for encoder in available_encoders(obs_space):
            fields = preset_overrides(preset, policy_type, obs_space, encoder)
            fields.pop("encoder", None)
            PreTrainedConfig.get_choice_class(policy_type)(obs_space=obs_space, encoder=encoder, **fields)


# ---- normalisation choices -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "encoder,norm,layer",
    [
        ("dp3", None, torch.nn.LayerNorm),
        ("dp3", "batch", torch.nn.BatchNorm1d),
        ("pointnet", None, torch.nn.BatchNorm1d),
        ("pointnet", "layer", torch.nn.LayerNorm),
        ("spatial_softmax", None, torch.nn.GroupNorm),
        ("spatial_softmax", "batch", torch.nn.BatchNorm2d),
    ],
)
def test_an_encoders_norm_option_builds_that_norm_and_padding_still_changes_nothing(encoder, norm, layer):
    space = "rgb" if encoder == "spatial_softmax" else "pointcloud"
    options = {"norm": norm} if space == "rgb" else {"norm": norm, "point_features": "xyz", "num_tokens": 8}
    if encoder == "pointnet":
        options["knn"] = 4
    if space == "rgb":
        options["image_size"] = 32
    module = make_encoder(encoder, space, "global", **options)
    norms = {
        type(m)
        for m in module.modules()
        if isinstance(m, (torch.nn.LayerNorm, torch.nn.modules.batchnorm._BatchNorm, torch.nn.GroupNorm))
    }
    assert layer in norms and not norms - {layer, torch.nn.BatchNorm1d if encoder == "pointnet" else layer}
    module.train()
    if space == "rgb":
        out = module(torch.rand(4, 1, 3, 32, 32))
        assert out.shape == (4, 64) and torch.isfinite(out).all()
        return
    cloud = _cloud(40, 3, batch=3)
    padded = PointCloud(
        torch.cat([cloud.xyz, torch.full((3, 7, 3), 9.0)], 1),
        torch.cat([cloud.features, torch.full((3, 7, 3), 9.0)], 1),
        torch.cat([cloud.mask, torch.zeros(3, 7, dtype=torch.bool)], 1),
    )
    torch.manual_seed(0)
    plain = module(cloud)
    torch.manual_seed(0)
    torch.testing.assert_close(module(padded), plain)  # the padded points reach no statistic and no output


def test_a_norm_the_encoder_does_not_offer_is_refused_at_config_time():
    from lerobot_obsbench.policies import ObsACTConfig

    with pytest.raises(ValueError, match=r"encoder_norm='group': encoder 'dp3' takes batch, layer"):
        ObsACTConfig(device="cpu", obs_space="pointcloud", encoder="dp3", encoder_norm="group")
    with pytest.raises(ValueError, match="encoder_norm='group' is not an option of encoder 'resnet18'"):
        ObsACTConfig(device="cpu", obs_space="rgb", encoder="resnet18", encoder_norm="group")
    config = ObsACTConfig(device="cpu", obs_space="rgb", encoder="spatial_softmax", encoder_norm="batch")
    assert config.encoder_options()["norm"] == "batch"
