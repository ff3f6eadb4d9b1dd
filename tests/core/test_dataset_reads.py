"""lerobot-train loads only what the policy reads, decoded once (`lerobot_obsbench.dataset_reads`): every key a
policy reads is served exactly as LeRobot's reader serves it, and a sample holds no other feature."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from lerobot.datasets import factory
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from safetensors.torch import load_file

from lerobot_obsbench import dataset_reads
from lerobot_obsbench.errors import ObsBenchError
from lerobot_obsbench.policies import ObsACTConfig, ObsDiffusionConfig
from lerobot_obsbench.presets import preset_args

# (policy config, obs space, encoder): ACT reads single frames with an action chunk, Diffusion an observation
# history (video and depth queried at two timestamps) with an action horizon
POLICIES = [
    (ObsACTConfig, "none", None),
    (ObsACTConfig, "state", None),
    (ObsACTConfig, "rgb", "spatial_softmax"),
    (ObsACTConfig, "depth", None),
    (ObsDiffusionConfig, "pointcloud", "dp3"),
    (ObsDiffusionConfig, "rgbd", None),
]
INDEX_KEYS = {*dataset_reads.INDEX_COLUMNS, "task"}
VIDEO = "observation.images.base_camera"


@pytest.fixture(scope="module")
def dataset(synthetic_module, tmp_path_factory) -> Path:
    """5 episodes x 9 frames at 40x40 (the AV1 encoder's smallest tested size), RGB as video, with the oracle's object
    poses."""
    root = tmp_path_factory.mktemp("reads") / "ds"
    return synthetic_module.write_dataset(root, episodes=5, frames=9, size=40, seed=3, privileged=True)


def open_dataset(root: Path, config, reader: str, monkeypatch, episodes=None) -> LeRobotDataset:
    monkeypatch.setenv(dataset_reads.READER_ENV, reader)
    meta = LeRobotDatasetMetadata("local/test", root=root)
    delta_timestamps = factory.resolve_delta_timestamps(config, meta)
    return LeRobotDataset(
        "local/test", root=root, episodes=episodes, delta_timestamps=delta_timestamps, return_uint8=True
    )


def make_config(cls, obs_space: str, encoder: str | None):
    return cls(obs_space=obs_space, device="cpu", **({"encoder": encoder} if encoder else {}))


def assert_same(served: dict, stock: dict) -> None:
    for key, value in served.items():
        if isinstance(value, torch.Tensor):
            expected = stock[key]
            assert value.dtype == expected.dtype and value.shape == expected.shape, key
            assert torch.equal(value, expected), key
        else:
            assert value == stock[key], key


@pytest.mark.parametrize("reader", ["memory", "filtered"])
@pytest.mark.parametrize("episodes", [None, [1, 2, 4]])
@pytest.mark.parametrize(("cls", "obs_space", "encoder"), POLICIES)
def test_served_keys_are_lerobots_and_only_what_the_policy_reads(
    dataset, monkeypatch, reader, episodes, cls, obs_space, encoder
):
    config = make_config(cls, obs_space, encoder)
    reads = config.dataset_reads(LeRobotDatasetMetadata("local/test", root=dataset))
    served = open_dataset(dataset, config, reader, monkeypatch, episodes)
    stock = open_dataset(dataset, config, "stock", monkeypatch, episodes)
    rows = served.reader._obsbench_rows
    assert isinstance(rows, dataset_reads.MemoryRows if reader == "memory" else dataset_reads.StreamedRows)
    assert len(served) == len(stock)
    queried = set(served.reader.delta_indices)
    allowed = reads | INDEX_KEYS | {f"{key}_is_pad" for key in reads & queried}
    for i in range(len(stock)):  # every frame: episode starts and ends give the padded queries
        sample, expected = served[i], stock[i]
        assert set(sample) == allowed & set(expected), i
        assert_same(sample, expected)
    assert served[len(served) - 1]["action_is_pad"].any()
    # what each space reads: the controls no camera, the images no depth, the clouds no oracle poses
    sensors = {
        k
        for k in reads
        if k.startswith(("observation.images", "observation.depth", "observation.intrinsics", "observation.cam2world"))
    }
    expected_sensors = {
        "none": set(),
        "state": set(),
        "rgb": {VIDEO},
        "depth": {"observation.depth.base_camera"},
        "rgbd": {VIDEO, "observation.depth.base_camera"},
        "pointcloud": {
            VIDEO,
            "observation.depth.base_camera",
            "observation.intrinsics.base_camera",
            "observation.cam2world.base_camera",
        },
    }[obs_space]
    assert sensors == expected_sensors
    assert ("observation.privileged_state" in reads) == (obs_space == "state")
    assert {"observation.state", "action"} <= reads


@pytest.mark.parametrize(
    ("obs_space", "options"),
    [("none", {}), ("state", {}), ("depth", {}), ("pointcloud", {"encoder": "dp3", "point_features": "xyz"})],
)
def test_inputs_without_colour_never_decode_video(dataset, monkeypatch, obs_space, options):
    """The controls, depth and a point cloud whose points carry no colour (DP3's xyz) read no colour frame."""
    import lerobot.datasets.dataset_reader as lerobot_reader

    def no_decoding(*args, **kwargs):
        raise AssertionError("a video was decoded")

    monkeypatch.setattr(lerobot_reader, "decode_video_frames", no_decoding)
    served = open_dataset(dataset, ObsACTConfig(obs_space=obs_space, device="cpu", **options), "memory", monkeypatch)
    assert VIDEO not in served[0] and len([served[i] for i in range(len(served))]) == 45


def test_spawned_loader_workers_serve_the_same_batches(dataset, monkeypatch):
    """lerobot-train starts DataLoader workers with spawn: they import the plugin when they unpickle the dataset
    and serve what the main process serves."""
    served = open_dataset(dataset, make_config(ObsACTConfig, "rgb", None), "memory", monkeypatch)
    loader = torch.utils.data.DataLoader(served, batch_size=4, num_workers=1, multiprocessing_context="spawn")
    batch = next(iter(loader))
    expected = torch.utils.data.default_collate([served[i] for i in range(4)])
    assert batch.keys() == expected.keys() and "observation.depth.base_camera" not in batch
    assert all(torch.equal(batch[k], expected[k]) for k in batch if isinstance(batch[k], torch.Tensor))


def test_over_the_memory_budget_the_read_keys_stream(dataset, monkeypatch, caplog):
    config = make_config(ObsDiffusionConfig, "pointcloud", "dp3")
    monkeypatch.setenv(dataset_reads.MEMORY_ENV, "0.01")
    with caplog.at_level(logging.INFO, logger="lerobot_obsbench.dataset_reads"):
        served = open_dataset(dataset, config, "memory", monkeypatch)
    assert isinstance(served.reader._obsbench_rows, dataset_reads.StreamedRows)
    assert f"over {dataset_reads.MEMORY_ENV}" in caplog.text and "streaming" in caplog.text
    stock = open_dataset(dataset, config, "stock", monkeypatch)
    assert_same(served[17], stock[17])
    assert "observation.privileged_state" not in served[17]


def test_stock_policies_and_datasets_opened_by_hand_read_everything(dataset):
    from lerobot.policies.act.configuration_act import ACTConfig

    everything = {VIDEO, "observation.depth.base_camera", "observation.privileged_state"}
    assert LeRobotDataset("local/test", root=dataset)[0].keys() >= everything
    delta_timestamps = factory.resolve_delta_timestamps(
        ACTConfig(device="cpu"), LeRobotDatasetMetadata("local/test", root=dataset)
    )
    assert not isinstance(delta_timestamps, dataset_reads.PolicyQuery)
    stock_act = LeRobotDataset("local/test", root=dataset, delta_timestamps=delta_timestamps)
    assert stock_act.reader._obsbench_rows is None and stock_act[0].keys() >= everything


@pytest.mark.parametrize(
    ("variable", "value", "message"),
    [
        (dataset_reads.READER_ENV, "fast", "choose one of memory, filtered, stock"),
        (dataset_reads.MEMORY_ENV, "lots", "must be a finite number >= 0"),
        (dataset_reads.MEMORY_ENV, "-1", "must be a finite number >= 0"),
        (dataset_reads.MEMORY_ENV, "nan", "must be a finite number >= 0"),
    ],
)
def test_bad_settings_are_refused_naming_the_variable(dataset, monkeypatch, variable, value, message):
    """When the policy config is built (where lerobot-train's parser shows the reason), and by the reader."""
    config = make_config(ObsACTConfig, "rgb", None)
    monkeypatch.setenv(variable, value)
    with pytest.raises(ObsBenchError, match=f"{variable}=.*{message}"):
        make_config(ObsACTConfig, "rgb", None)
    with pytest.raises(ObsBenchError, match=f"{variable}=.*{message}"):
        LeRobotDataset(
            "local/test",
            root=dataset,
            delta_timestamps=factory.resolve_delta_timestamps(
                config, LeRobotDatasetMetadata("local/test", root=dataset)
            ),
        )


@pytest.mark.slow
def test_stock_lerobot_train_learns_the_same_weights_from_either_reader(dataset, tmp_path):
    """Same batches, same seed: three steps of stock lerobot-train give bit-identical weights from LeRobot's
    reader and from the plugin's."""
    weights = {}
    for reader in ("stock", "memory"):
        out = tmp_path / reader
        command = [
            str(Path(sys.executable).parent / "lerobot-train"),
            "--policy.type=obs_diffusion",
            "--policy.obs_space=pointcloud",
            "--policy.device=cpu",
            "--dataset.repo_id=local/test",
            f"--dataset.root={dataset}",
            "--batch_size=4",
            "--steps=3",
            "--save_freq=3",
            "--num_workers=0",
            "--seed=7",
            "--wandb.enable=false",
            f"--output_dir={out}",
            *preset_args("tiny", "obs_diffusion", "pointcloud"),
        ]
        env = {**os.environ, "OMP_NUM_THREADS": "1", dataset_reads.READER_ENV: reader, "HF_HUB_OFFLINE": "1"}
        proc = subprocess.run(command, capture_output=True, text=True, timeout=600, env=env, stdin=subprocess.DEVNULL)
        assert proc.returncode == 0, proc.stderr[-3000:]
        model = out / "checkpoints" / "last" / "pretrained_model"
        weights[reader] = load_file(model / "model.safetensors")
        assert json.loads((model / "config.json").read_text())["obs_space"] == "pointcloud"
        if reader == "memory":
            assert "decoded into memory" in proc.stderr + proc.stdout
        # the start-up line says which reader trained (docs/architecture.md's table of replaced functions)
        routes = "reader `memory`" if reader == "memory" else "LeRobot's reader (OBSBENCH_DATASET_READER=stock)"
        assert "lerobot_obsbench patches" in proc.stderr + proc.stdout and routes in proc.stderr + proc.stdout
    assert weights["stock"].keys() == weights["memory"].keys()
    assert all(torch.equal(weights["stock"][k], weights["memory"][k]) for k in weights["stock"])
