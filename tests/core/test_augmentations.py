"""Training augmentations: registered by name and space, the identity at evaluation, shape- and dtype-keeping,
seeded by torch's generator, geometrically what they say, stored in the checkpoint's config, and refused in one
line where they do not apply (a config, a grid)."""

from __future__ import annotations

import math

import pytest
import torch

from lerobot_obsbench import augmentations as aug
from lerobot_obsbench.augmentations import AugmentationError, Augmenter, parse_augment
from lerobot_obsbench.schema import DEPTH_PREFIX, available_spaces, reads_images, reads_points, space_info
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
from tests.support.helpers import CAM, frame_batch

BOX = (-0.3, 0.3, -0.2, 0.2, 0.01, 0.25)
IMAGE_AUGS = aug.available_augmentations("rgb")
POINT_AUGS = [n for n in aug.available_augmentations("pointcloud") if aug.augmentation_info(n).kind == "points"]
DEPTH_AUGS = [n for n in aug.available_augmentations() if aug.augmentation_info(n).kind == "depth"]


def _images(seed: int = 0) -> torch.Tensor:
    return torch.rand(3, 2, 6, 20, 24, generator=torch.Generator().manual_seed(seed))


def _cloud(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    bounds = torch.tensor(BOX).reshape(3, 2)
    xyz = bounds[:, 0] + torch.rand(2, 500, 3, generator=g) * (bounds[:, 1] - bounds[:, 0])
    return xyz, torch.ones(2, 500, dtype=torch.bool), torch.tensor(BOX)


def test_every_augmentation_declares_known_spaces_and_the_registry_refuses_a_second_name():
    assert set(aug.available_augmentations()) == set(IMAGE_AUGS) | set(POINT_AUGS) | set(DEPTH_AUGS)
    assert DEPTH_AUGS == ["depth_noise_1", "depth_noise_2"]
    reads = {
        "points": reads_points,
        "depth": lambda s: DEPTH_PREFIX in space_info(s).sensors,
        "image": reads_images,
        "colour": reads_images,
    }
    for name in aug.available_augmentations():
        info = aug.augmentation_info(name)
        assert info.spaces and set(info.spaces) <= set(available_spaces()) and info.kind in aug.KINDS
        # point transforms apply to spaces with a cloud, depth ones to those built from depth, the others to spaces
        # with images (a fused space has what its parts have)
        assert set(info.spaces) <= {s for s in available_spaces() if reads[info.kind](s)}
    assert set(aug.augmentation_info("depth_noise_1").spaces) == {"depth", "rgbd", "pointmap", "pointcloud"} | {
        s for s in available_spaces() if "+" in s and DEPTH_PREFIX in space_info(s).sensors
    }
    with pytest.raises(ValueError, match="already registered"):
        aug.register_augmentation("random_shift", "image", "again")(lambda x, t: x)


@pytest.mark.parametrize("name", [n for n in IMAGE_AUGS if n != "random_crop"])
def test_image_augmentations_keep_shape_and_dtype_and_are_the_identity_at_eval(name):
    images = _images()
    augmenter = Augmenter(parse_augment(name, "rgb"))
    kind = aug.augmentation_info(name).kind
    apply = augmenter.colour if kind == "colour" else augmenter.image
    x = images[:, 0, :3] if kind == "colour" else images
    out = apply(x)
    assert out.shape == x.shape and out.dtype == x.dtype and not torch.equal(out, x)
    augmenter.eval()
    assert torch.equal(apply(x), x)


def test_random_crop_takes_a_random_crop_in_training_and_the_centre_crop_at_test():
    images = _images()
    augmenter = Augmenter(("random_crop",))
    out = augmenter.image(images)
    assert out.shape == images.shape and out.dtype == images.dtype
    augmenter.eval()
    first, second = augmenter.image(images), augmenter.image(images)
    assert torch.equal(first, second)  # deterministic at test
    h, w = 18, round(0.9 * 24)  # the centre 90%, resized back to the frame
    centre = images.flatten(0, 1)[..., 1 : 1 + h, (24 - w) // 2 : (24 - w) // 2 + w]
    expected = torch.nn.functional.interpolate(centre, size=(20, 24), mode="bilinear", align_corners=False)
    torch.testing.assert_close(first, expected.unflatten(0, (3, 2)))


def test_random_shift_moves_every_channel_of_a_camera_alike_by_at_most_its_pad():
    images = _images()
    out = Augmenter(("random_shift",)).image(images)
    pad = round(aug.SHIFT_FRACTION * 24)
    padded = torch.nn.functional.pad(images.flatten(0, 1), (pad,) * 4, mode="replicate")
    for i, frame in enumerate(out.flatten(0, 1)):  # each output frame is one window of its padded input
        windows = [
            (dv, du)
            for dv in range(2 * pad + 1)
            for du in range(2 * pad + 1)
            if torch.equal(padded[i, :, dv : dv + 20, du : du + 24], frame)
        ]
        assert len(windows) == 1, f"frame {i} is no single shift of its input"


@pytest.mark.parametrize("name", POINT_AUGS)
def test_point_augmentations_keep_shapes_stay_within_their_reach_and_are_the_identity_at_eval(name):
    xyz, valid, box = _cloud()
    augmenter = Augmenter((name,))
    torch.manual_seed(1)
    moved, kept = augmenter.points(xyz, valid, box)
    assert moved.shape == xyz.shape and moved.dtype == xyz.dtype and kept.shape == valid.shape
    assert not (torch.equal(moved, xyz) and torch.equal(kept, valid))
    assert float((moved - xyz).norm(dim=-1).max()) <= augmenter.point_reach(BOX) + 1e-6
    augmenter.eval()
    assert augmenter.point_reach(BOX) == 0.0
    same, same_valid = augmenter.points(xyz, valid, box)
    assert torch.equal(same, xyz) and torch.equal(same_valid, valid)


def test_point_rotation_turns_a_known_point_about_the_box_centres_vertical_axis():
    centre = torch.tensor([0.0, 0.0, 0.13])  # BOX's centre
    known = torch.tensor([[[0.1, 0.0, 0.05], [0.0, 0.0, 0.2], [0.0, 0.1, 0.13]]])
    torch.manual_seed(3)
    moved, _ = Augmenter(("point_rotate",)).points(known, torch.ones(1, 3, dtype=torch.bool), torch.tensor(BOX))
    theta = math.atan2(float(moved[0, 0, 1]), float(moved[0, 0, 0]))  # the first point started on +x
    assert 0 < abs(theta) <= math.radians(aug.POINT_ROTATION_DEG)
    c, s = math.cos(theta), math.sin(theta)
    rotation = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    expected = (known - centre) @ rotation.T + centre
    torch.testing.assert_close(moved, expected)
    torch.testing.assert_close(moved[0, 1], known[0, 1])  # on the axis: stays


def test_point_dropout_drops_points_and_moves_none():
    xyz, valid, box = _cloud()
    moved, kept = Augmenter(("point_dropout",)).points(xyz, valid, box)
    assert torch.equal(moved, xyz)
    assert 0.8 < float(kept.float().mean()) < 1.0


@pytest.mark.parametrize(
    "space,recipe",
    [
        ("rgb", "random_shift+colour_jitter"),
        ("rgbd", "random_crop"),
        ("pointcloud", "point_jitter+point_dropout+point_rotate"),
    ],
)
def test_the_adapter_augments_in_training_only_and_the_same_seed_gives_the_same_batch(synthetic_module, space, recipe):
    batch = frame_batch(synthetic_module, batch_size=2, size=32)
    workspace = (-0.5, 0.5, -0.5, 0.5, 0.005, 0.5)
    plain = ObservationAdapter(AdapterConfig(space, [CAM], workspace=workspace)).eval()
    adapter = ObservationAdapter(AdapterConfig(space, [CAM], workspace=workspace, augment=recipe))

    def run(seed: int):
        torch.manual_seed(seed)
        out = adapter(batch)
        return out if isinstance(out, torch.Tensor) else torch.cat([out.xyz, out.features], -1)

    first, again, other = run(0), run(0), run(1)
    torch.testing.assert_close(first, again, rtol=0, atol=0)
    assert not torch.equal(first, other)
    adapter.eval()
    evaluated, reference = adapter(batch), plain(batch)
    if space == "pointcloud":
        assert torch.equal(evaluated.xyz, reference.xyz) and torch.equal(evaluated.mask, reference.mask)
        torch.manual_seed(2)
        cloud = adapter.train()(batch)
        inside = _inside(cloud.xyz[cloud.mask], workspace)
        assert bool(inside.all())  # augmented in the world frame, then cropped
    elif "random_crop" not in recipe:
        assert torch.equal(evaluated, reference)


@pytest.mark.parametrize("name", aug.available_augmentations())
def test_every_registered_augmentation_reaches_what_the_adapter_gives_in_training(synthetic_module, name):
    """docs/architecture.md's extension row "an augmentation of a new kind": whatever its kind, a registered
    transform changes the adapter's training output (a kind the adapter does not apply would train silently
    unaugmented), differs between two seeds, and leaves evaluation alone (random_crop's centre crop aside)."""
    info = aug.augmentation_info(name)
    space = next(s for s in ("rgb", "depth", "rgbd", "pointcloud") if info.applies_to(s))
    batch = frame_batch(synthetic_module, batch_size=2, size=64)  # ~40 points in the box: dropout drops some
    workspace = (-0.5, 0.5, -0.5, 0.5, 0.005, 0.5)
    plain = ObservationAdapter(AdapterConfig(space, [CAM], workspace=workspace)).eval()
    adapter = ObservationAdapter(AdapterConfig(space, [CAM], workspace=workspace, augment=name))

    def flat(out):
        return out if isinstance(out, torch.Tensor) else torch.cat([out.xyz, out.features, out.mask[..., None]], -1)

    def trained(seed: int):
        torch.manual_seed(seed)
        return flat(adapter.train()(batch))

    torch.manual_seed(0)
    reference = flat(plain(batch))
    first = trained(0)
    assert not torch.equal(first, reference), f"{name} ({info.kind}) changed nothing the adapter gives"
    assert not torch.equal(first, trained(1))
    if name != "random_crop":
        torch.manual_seed(0)
        assert torch.equal(flat(adapter.eval()(batch)), reference)


def _inside(points: torch.Tensor, box) -> torch.Tensor:
    b = torch.tensor(box).reshape(3, 2)
    return ((points >= b[:, 0]) & (points <= b[:, 1])).all(-1)


def test_names_are_checked_against_the_registry_and_the_space():
    assert parse_augment("", "rgb") == ()
    assert parse_augment("random_shift+colour_jitter", "rgb") == ("random_shift", "colour_jitter")
    with pytest.raises(AugmentationError, match="unknown augmentation 'random_shfit'; registered: colour_jitter"):
        parse_augment("random_shfit", "rgb")
    with pytest.raises(AugmentationError, match="'point_jitter' does not apply to obs_space='rgb'.*random_shift"):
        parse_augment("point_jitter", "rgb")
    with pytest.raises(AugmentationError, match="augmentations for 'none': none"):
        parse_augment("random_shift", "none")
    with pytest.raises(AugmentationError, match="each once"):
        parse_augment("random_shift+random_shift", "rgb")


def test_a_policy_config_refuses_a_misplaced_recipe_in_one_line_and_keeps_its_recipe_through_lerobots_loader(tmp_path):
    from lerobot.configs.policies import PreTrainedConfig

    from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig

    with pytest.raises(ValueError, match=r"^augment: 'random_shift' does not apply to obs_space='pointcloud'[^\n]*$"):
        ObsACTConfig(device="cpu", obs_space="pointcloud", augment="random_shift")
    for config_cls, recipe, space in (
        (ObsACTConfig, "random_shift", "rgb"),
        (ObsDiffusionConfig, "point_jitter", "pointcloud"),
    ):
        config = config_cls(device="cpu", obs_space=space, augment=recipe)
        folder = tmp_path / config.type
        folder.mkdir()
        config._save_pretrained(folder)
        assert f'"augment": "{recipe}"' in (folder / "config.json").read_text()
        loaded = PreTrainedConfig.from_pretrained(folder)
        assert type(loaded) is config_cls and loaded.augment == recipe


@pytest.mark.parametrize("policy_type", ["obs_act", "obs_diffusion"])
def test_a_policy_trains_with_its_recipe_and_acts_without_it(synthetic_module, policy_type):
    from tests.encoders.test_compact_encoders import _policy, _training_batch

    policy = _policy(policy_type, "rgb", "spatial_softmax", augment="random_shift")
    observation = policy.model.observation if policy_type == "obs_act" else policy.diffusion.observation
    assert observation.adapter.augment.names == ("random_shift",)
    batch = _training_batch(synthetic_module, policy)
    policy.train()
    torch.manual_seed(0)
    loss, _ = policy.forward(batch)
    loss.backward()
    assert torch.isfinite(loss)
    policy.eval()
    assert not observation.adapter.augment.training
