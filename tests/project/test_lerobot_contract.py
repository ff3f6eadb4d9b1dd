"""The plugin's contract with LeRobot 0.6.1, checked so that a LeRobot change fails here loudly:

- obs_act on rgb with an encoder equal to ACT's own (ResNet-18, layer4 tokens, 1x1 projection, 2-D sine
  positions) gives stock ACT's loss on the same weights and batch;
- obs_diffusion's denoiser, noise scheduler and loss are stock Diffusion Policy's: with the observation feature
  handed to stock Diffusion as part of its environment state, both give the same loss and the same actions;
- the loading patches apply only to the LeRobot version they were written for;
- every inherited config field is honoured or refused, never silently ignored.
"""

from __future__ import annotations

import logging

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.datasets.dataset_reader import DatasetReader
from lerobot.policies.act.configuration_act import ACTConfig
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionModel

from lerobot_obsbench import patches
from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig
from lerobot_obsbench.presets import model_sizes
from lerobot_obsbench.schema import ACTION_KEY, ENV_STATE_KEY, STATE_KEY, image_key
from lerobot_obsbench.spaces import IMAGENET_MEAN, IMAGENET_STD
from tests.support.helpers import CAM, first_batch, training_setup

# stock ACT's backbone (torchvision ResNet under IntermediateLayerGetter) -> the plugin's ResNetEncoder.body
RESNET_CHILDREN = {"conv1": 0, "bn1": 1, "layer1": 4, "layer2": 5, "layer3": 6, "layer4": 7}


def _stock_act_key(key: str) -> str:
    """The plugin's obs_act state-dict key -> stock ACTPolicy's."""
    if key.startswith("model.observation.encoder.body."):
        index, rest = key.removeprefix("model.observation.encoder.body.").split(".", 1)
        child = {v: k for k, v in RESNET_CHILDREN.items()}[int(index)]
        return f"model.backbone.{child}.{rest}"
    return key.replace("model.observation.encoder.proj.", "model.encoder_img_feat_input_proj.")


def test_obs_act_gives_stock_act_loss(tiny_dataset):
    policy, pre, _, dataset = training_setup("obs_act", "rgb", tiny_dataset, encoder="resnet18")
    batch = first_batch(dataset, pre, batch_size=4, shuffle=True)
    size = policy.config.camera_resolution
    stock = ACTPolicy(
        ACTConfig(
            input_features={
                **policy.config.input_features,
                image_key(CAM): PolicyFeature(FeatureType.VISUAL, (3, *size)),
            },
            output_features=policy.config.output_features,
            pretrained_backbone_weights=None,
            device="cpu",
            n_action_steps=policy.config.n_action_steps,
            **model_sizes("tiny", "obs_act"),
        )
    )
    own = policy.state_dict()
    stock_keys = set(stock.state_dict())
    # everything but BatchNorm's step counter and the ee-frame state buffers has a stock counterpart
    mapped = {
        _stock_act_key(k): v
        for k, v in own.items()
        if not k.endswith("num_batches_tracked") and not k.startswith("model.observation.state.")
    }
    assert set(mapped) == stock_keys
    stock.load_state_dict(mapped, strict=True)

    # stock ACT normalises images in its preprocessor; the plugin's adapter uses ImageNet statistics
    mean, std = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
    stock_batch = {**batch, image_key(CAM): (batch[image_key(CAM)] - mean) / std}
    losses = []
    for model, inputs in ((policy, batch), (stock, stock_batch)):
        model.train()
        if model is policy:
            policy.model.observation.eval()  # BatchNorm with running statistics = ACT's FrozenBatchNorm2d
        torch.manual_seed(0)  # same latent sample and dropout masks
        losses.append(model.forward(dict(inputs)))
    (own_loss, own_terms), (stock_loss, stock_terms) = losses
    torch.testing.assert_close(own_loss, stock_loss, rtol=1e-5, atol=1e-6)
    assert own_terms.keys() == stock_terms.keys() == {"l1_loss", "kld_loss"}
    for name in own_terms:
        assert own_terms[name] == pytest.approx(stock_terms[name], rel=1e-5, abs=1e-6), name


def test_obs_diffusion_denoiser_and_loss_are_stock_diffusion(tiny_dataset):
    policy, pre, _, dataset = training_setup("obs_diffusion", "rgb", tiny_dataset, encoder="resnet18")
    batch = first_batch(dataset, pre, batch_size=3, shuffle=True)
    model = policy.diffusion
    model.observation.eval()
    steps = policy.config.n_obs_steps
    with torch.no_grad():
        frames = {k: batch[k].flatten(0, 1) for k in model.observation.input_keys}
        feature = model.observation(frames).reshape(len(batch[STATE_KEY]), steps, -1)
    env = torch.cat([feature, batch[ENV_STATE_KEY]], dim=-1)
    stock = DiffusionModel(
        DiffusionConfig(
            input_features={
                STATE_KEY: policy.config.input_features[STATE_KEY],
                ENV_STATE_KEY: PolicyFeature(FeatureType.ENV, (env.shape[-1],)),
            },
            output_features=policy.config.output_features,
            device="cpu",
            **model_sizes("tiny", "obs_diffusion"),
        )
    )
    stock.unet.load_state_dict(model.unet.state_dict(), strict=True)
    stock_batch = {
        STATE_KEY: batch[STATE_KEY],
        ENV_STATE_KEY: env,
        ACTION_KEY: batch[ACTION_KEY],
        "action_is_pad": batch["action_is_pad"],
    }
    results = []
    for diffusion, inputs in ((model, batch), (stock, stock_batch)):
        torch.manual_seed(0)  # same noise and timesteps
        loss = diffusion.compute_loss(dict(inputs))
        torch.manual_seed(1)
        with torch.no_grad():
            actions = diffusion.generate_actions(dict(inputs))
        results.append((loss, actions))
    torch.testing.assert_close(results[0][0], results[1][0], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(results[0][1], results[1][1], rtol=1e-5, atol=1e-6)


def test_loading_patches_apply_only_to_the_lerobot_they_were_written_for(caplog, monkeypatch):
    stock_query = patches._STOCK["query"]
    monkeypatch.setattr(DatasetReader, "_query_hf_dataset", stock_query)
    with caplog.at_level(logging.WARNING):
        assert patches.apply("0.5.0") is False
    assert DatasetReader._query_hf_dataset is stock_query
    assert "LeRobot 0.5.0 is installed" in caplog.text and patches.LEROBOT_VERSION in caplog.text
    assert patches.apply() is True  # the installed 0.6.1
    assert DatasetReader._query_hf_dataset is patches.query_hf_dataset_by_column


def test_one_opencv_in_the_environment():
    """sapien asks for opencv-python, LeRobot for opencv-python-headless: both install `cv2`, so a version
    mismatch leaves whichever was installed last in charge, and `pip check` says nothing."""
    from importlib.metadata import version

    import cv2

    full, headless = version("opencv-python"), version("opencv-python-headless")
    assert full == headless, f"opencv-python {full} beside opencv-python-headless {headless}"
    assert full.startswith(cv2.__version__ + "."), (cv2.__version__, full)


def test_diffusion_fields_the_plugin_relies_on_are_pinned():
    """LeRobot 0.6 changed Diffusion's defaults (horizon 64, 32 action steps, ImageNet backbone weights, no group
    norm, one encoder per camera); the plugin keeps the paper's values whatever LeRobot's defaults are."""
    config = ObsDiffusionConfig(device="cpu")
    assert (config.horizon, config.n_action_steps, config.n_obs_steps) == (16, 8, 2)
    assert config.pretrained_backbone_weights is None  # nothing downloads
    assert (config.use_group_norm, config.use_separate_rgb_encoder_per_camera) == (True, False)


@pytest.mark.parametrize(
    "config_class,fields,words",
    [
        (ObsACTConfig, {"vision_backbone": "resnet34"}, ["vision_backbone='resnet34'", "--policy.encoder"]),
        (ObsACTConfig, {"pretrained_backbone_weights": "ResNet18_Weights.IMAGENET1K_V1"}, ["--policy.pretrained"]),
        (ObsACTConfig, {"replace_final_stride_with_dilation": True}, ["keep their strides"]),
        (ObsDiffusionConfig, {"crop_shape": (84, 84)}, ["crop_shape=(84, 84)", "image pipeline"]),
        (ObsDiffusionConfig, {"spatial_softmax_num_keypoints": 16}, ["spatial_softmax_num_keypoints=16"]),
        (ObsDiffusionConfig, {"use_group_norm": False}, ["use_group_norm=False"]),
        (ObsDiffusionConfig, {"scheduler_name": "linear"}, ["scheduler_name='linear'", "OneCycle"]),
        (ObsACTConfig, {"obs_space": "rgb", "num_tokens": 64}, ["num_tokens=64", "point-cloud design choice"]),
        (ObsACTConfig, {"obs_space": "rgb", "knn": 8}, ["knn=8", "point-cloud design choice"]),
    ],
)
def test_inherited_fields_that_would_be_ignored_are_refused(config_class, fields, words):
    with pytest.raises(ValueError) as err:
        config_class(device="cpu", **fields)
    for word in words:
        assert word in str(err.value)


def test_inherited_optimiser_fields_are_honoured(tiny_dataset):
    dp = ObsDiffusionConfig(device="cpu", obs_space="rgb", optimizer_betas=(0.95, 0.999), optimizer_eps=1e-6)
    preset = dp.get_optimizer_preset()
    assert (preset.betas, preset.eps, preset.weight_decay) == ((0.95, 0.999), 1e-6, 0.05)
    # the paper's effective betas by default (the official code never passes its configured (0.9, 0.95))
    assert tuple(ObsDiffusionConfig(device="cpu").get_optimizer_preset().betas) == (0.9, 0.999)

    policy, *_ = training_setup("obs_act", "rgb", tiny_dataset, encoder="resnet18")
    assert len(policy.get_optim_params()) == 1  # optimizer_lr_backbone None: the encoder trains at optimizer_lr
    policy, *_ = training_setup("obs_act", "rgb", tiny_dataset, encoder="resnet18", optimizer_lr_backbone=1e-5)
    rest, encoder = policy.get_optim_params()
    encoder_params = {id(p) for p in policy.model.observation.encoder.parameters()}
    assert encoder["lr"] == 1e-5 and {id(p) for p in encoder["params"]} == encoder_params
    assert not encoder_params & {id(p) for p in rest["params"]}
    assert len(rest["params"]) + len(encoder["params"]) == len(list(policy.parameters()))

    policy, *_ = training_setup("obs_diffusion", "rgb", tiny_dataset, encoder="resnet18", compile_model=True)
    assert type(policy.diffusion.unet).__name__ == "OptimizedModule"
