"""Narrow fixes to LeRobot 0.4.4's dataset loading, applied when the plugin is imported.

1. Array columns through Python lists. LeRobot formats its `datasets.Dataset` with
   `set_transform(hf_transform_to_torch)`: every read first turns the Arrow rows into Python lists, then
   `torch.tensor(list)`. A 128² depth frame is 16k nested Python ints: ~30 ms per row, and an ACT chunk query
   (`hf_dataset[key][indices]`) formats every column of its 100 rows, depth included: seconds per sample.
   `LeRobotTorchFormatter` produces the same output — tensors per row, lists of tensors per batch / column,
   PIL images as float CHW in [0, 1], same dtypes — from NumPy extraction instead, and
   `query_hf_dataset_by_column` reads only the queried column. Drop both once LeRobot fixes this upstream.
2. Video decoding. LeRobot picks torchcodec whenever the package is installed, even when its FFmpeg shared
   libraries are missing and it cannot load; then decode with the `pyav` backend instead of crashing.
3. Aggregating datasets with array features (`array_safe_aggregation()`, used only around the plugin's own
   calls of `aggregate_datasets`): LeRobot copies data files through pandas unless the dataset has images, and
   pandas cannot write HF `Array3D` columns (depth) back to parquet. Inside the context the data files take
   LeRobot's own image path (read and written through `datasets`), which keeps those columns' types. (Appending
   to an existing data file still concatenates data frames, which pandas cannot do with those columns either:
   callers give each source its own data file.)

Fixes 1 and 2 replace LeRobot functions for every process that imports the plugin (LeRobot's plugin discovery imports it
into every `lerobot-*` command), so `apply()` patches only the LeRobot version they were written and tested
for (`LEROBOT_VERSION`); on any other it warns and leaves LeRobot as it is.

`stock_loading()` restores LeRobot's behaviour for the equivalence test and the loading benchmark.
"""

from __future__ import annotations

import contextlib
import functools
import logging
from importlib import metadata

import datasets
import PIL.Image
import torch
from datasets.formatting import _register_formatter
from datasets.formatting.torch_formatter import TorchFormatter
from lerobot.datasets import lerobot_dataset
from torchvision.transforms.functional import to_tensor

logger = logging.getLogger(__name__)

FORMAT_TYPE = "lerobot_obsbench_torch"
LEROBOT_VERSION = "0.4.4"  # the version these patches replace functions of
_STOCK = {
    "query": lerobot_dataset.LeRobotDataset._query_hf_dataset,
    "load": lerobot_dataset.LeRobotDataset.load_hf_dataset,
    "decode": lerobot_dataset.decode_video_frames,
}


class LeRobotTorchFormatter(TorchFormatter):
    """`hf_transform_to_torch`'s exact output, built from NumPy extraction instead of Python lists."""

    def _tensorize(self, value):
        if isinstance(value, PIL.Image.Image):
            return to_tensor(value)  # what LeRobot's transform does: (C, H, W) float in [0, 1]
        return super()._tensorize(value)

    def _per_row(self, column):
        return [self._recursive_tensorize(value) for value in column]

    def format_column(self, pa_table):
        column = self.numpy_arrow_extractor().extract_column(pa_table)
        column = self.python_features_decoder.decode_column(column, pa_table.column_names[0])
        return self._per_row(column)

    def format_batch(self, pa_table):
        batch = self.numpy_arrow_extractor().extract_batch(pa_table)
        batch = self.python_features_decoder.decode_batch(batch)
        return {name: self._per_row(column) for name, column in batch.items()}


_register_formatter(LeRobotTorchFormatter, FORMAT_TYPE)


def load_hf_dataset_fast(self) -> datasets.Dataset:
    hf_dataset = _STOCK["load"](self)
    hf_dataset.set_format(FORMAT_TYPE)
    return hf_dataset


def query_hf_dataset_by_column(self, query_indices: dict[str, list[int]]) -> dict:
    """Same contract as LeRobot's `_query_hf_dataset`, but formats only the queried column."""
    result: dict = {}
    for key, q_idx in query_indices.items():
        if key in self.meta.video_keys:
            continue
        relative = (
            q_idx if self._absolute_to_relative_idx is None else [self._absolute_to_relative_idx[i] for i in q_idx]
        )
        result[key] = torch.stack(self.hf_dataset.select_columns([key])[relative][key])
    return result


@functools.cache
def torchcodec_loads() -> bool:
    """Whether torchcodec's native decoder can actually be loaded (it needs FFmpeg's shared libraries)."""
    try:
        import torchcodec.decoders  # noqa: F401
    except Exception as err:  # torchcodec raises RuntimeError/OSError when FFmpeg is missing
        first_line = str(err).splitlines()[0] if str(err) else type(err).__name__
        logger.warning("torchcodec cannot load (%s); decoding videos with the 'pyav' backend.", first_line)
        return False
    return True


def decode_video_frames_with_fallback(video_path, timestamps, tolerance_s, backend=None):
    if backend in (None, "torchcodec") and not torchcodec_loads():
        backend = "pyav"
    return _STOCK["decode"](video_path, timestamps, tolerance_s, backend)


def _set(query, load) -> None:
    lerobot_dataset.LeRobotDataset._query_hf_dataset = query
    lerobot_dataset.LeRobotDataset.load_hf_dataset = load


def apply(lerobot_version: str | None = None) -> bool:
    """Patch LeRobot if it is the version the patches were written for; returns whether it patched."""
    version = lerobot_version or metadata.version("lerobot")
    if version != LEROBOT_VERSION:
        logger.warning(
            "lerobot_obsbench: LeRobot %s is installed, the dataset-loading fixes were written for %s; "
            "leaving LeRobot unpatched (loading depth datasets may be slow).",
            version,
            LEROBOT_VERSION,
        )
        return False
    _set(query_hf_dataset_by_column, load_hf_dataset_fast)
    lerobot_dataset.decode_video_frames = decode_video_frames_with_fallback
    return True


class _ArrayFeaturesAsImages:
    """A destination dataset's metadata as `aggregate_data` sees it: "with images" when it has array features, so
    that its data files go through `datasets` rather than pandas."""

    def __init__(self, meta):
        self._meta = meta

    def __getattr__(self, name):
        return getattr(self._meta, name)

    @property
    def image_keys(self) -> list[str]:
        arrays = [k for k, ft in self._meta.features.items() if ft["dtype"] not in ("video", "image", "string")]
        arrays = [k for k in arrays if len(ft_shape(self._meta.features[k])) >= 2]
        return self._meta.image_keys or arrays


def ft_shape(feature: dict) -> tuple:
    return tuple(feature.get("shape") or ())


@contextlib.contextmanager
def array_safe_aggregation():
    """LeRobot's `aggregate_datasets`, made to keep array (depth) columns; see fix 3 of the module docstring."""
    from lerobot.datasets import aggregate

    stock = aggregate.aggregate_data

    def aggregate_data(src_meta, dst_meta, *args, **kwargs):
        return stock(src_meta, _ArrayFeaturesAsImages(dst_meta), *args, **kwargs)

    aggregate.aggregate_data = aggregate_data
    try:
        yield
    finally:
        aggregate.aggregate_data = stock


@contextlib.contextmanager
def stock_loading():
    """Temporarily restore LeRobot's own array loading (datasets opened inside use the stock path)."""
    _set(_STOCK["query"], _STOCK["load"])
    try:
        yield
    finally:
        apply()
