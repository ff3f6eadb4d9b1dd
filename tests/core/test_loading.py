"""The plugin's dataset-loading fixes return exactly what stock LeRobot returns."""

from __future__ import annotations

import logging
import sys

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_obsbench import patches

DELTAS = {  # ACT-style action chunk and Diffusion-style observation history on every kind of column
    "action": [i / 10 for i in range(12)],
    "observation.images.base_camera": [-0.1, 0.0],
    "observation.depth.base_camera": [-0.1, 0.0],
    "observation.state": [-0.1, 0.0],
}


def assert_same_sample(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        if isinstance(a[key], torch.Tensor):
            assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, key
            assert torch.equal(a[key], b[key]), key
        else:
            assert a[key] == b[key], key


@pytest.mark.parametrize("fixture", ["tiny_dataset", "image_dataset"])
@pytest.mark.parametrize("episodes", [None, [1]])
def test_samples_identical_to_stock_lerobot(request, fixture, episodes):
    root = request.getfixturevalue(fixture)
    fast = LeRobotDataset("local/test", root=root, delta_timestamps=DELTAS, episodes=episodes)
    with patches.stock_loading():
        stock = LeRobotDataset("local/test", root=root, delta_timestamps=DELTAS, episodes=episodes)
        expected = [stock[i] for i in range(len(stock))]
    assert fast.hf_dataset.format["type"] == patches.FORMAT_TYPE
    assert stock.hf_dataset.format["type"] == "custom"
    assert len(fast) == len(expected)
    for i, sample in enumerate(expected):
        assert_same_sample(sample, fast[i])
    # padding flags at episode ends are part of the contract
    assert fast[len(fast) - 1]["action_is_pad"].any()


def test_depth_arrays_keep_lerobot_dtype_and_layout(tiny_dataset):
    sample = LeRobotDataset("local/test", root=tiny_dataset)[3]
    assert sample["observation.depth.base_camera"].dtype == torch.int64
    assert sample["observation.depth.base_camera"].shape == (40, 40, 1)
    assert sample["observation.images.base_camera"].dtype == torch.float32
    assert sample["observation.images.base_camera"].shape == (3, 40, 40)


def test_video_backend_falls_back_to_pyav_when_torchcodec_cannot_load(tiny_dataset, monkeypatch, caplog):
    """LeRobot 0.6.1 falls back itself (the plugin's 0.4.4 patch is gone): a machine whose torchcodec cannot load
    FFmpeg still reads the plugin's datasets with the default backend."""
    # torchcodec's modules unimportable (and not already imported, which they are here when this machine's FFmpeg
    # let an earlier test load them)
    for name in [m for m in sys.modules if m == "torchcodec" or m.startswith("torchcodec.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setattr("builtins.__import__", _failing_import("torchcodec", __import__))
    with caplog.at_level(logging.WARNING):
        dataset = LeRobotDataset("local/test", root=tiny_dataset)
        frame = dataset[0]
    assert dataset._video_backend == "pyav"
    assert frame["observation.images.base_camera"].shape == (3, 40, 40)
    assert "Falling back to 'pyav'" in caplog.text


def _failing_import(name, real_import):
    def fake(module, *args, **kwargs):
        if module == name or module.startswith(name + "."):
            raise OSError("libavutil.so: cannot open shared object file")
        return real_import(module, *args, **kwargs)

    return fake


def test_forked_dataloader_workers_use_the_fast_format(tiny_dataset):
    """lerobot-train loads with worker processes: the registered formatter must work there too."""
    ds = LeRobotDataset("local/test", root=tiny_dataset, delta_timestamps=DELTAS)
    serial = next(iter(torch.utils.data.DataLoader(ds, batch_size=8, num_workers=0)))
    workers = next(iter(torch.utils.data.DataLoader(ds, batch_size=8, num_workers=2, multiprocessing_context="fork")))
    assert_same_sample(serial, workers)
