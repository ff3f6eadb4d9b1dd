"""Two narrow fixes to LeRobot 0.4.4's dataset loading, applied when the plugin is imported.

1. Column-only queries (DESIGN §10). `LeRobotDataset._query_hf_dataset` fetches an action chunk with
   `hf_dataset[key][indices]`; with `datasets` 4.x that formats EVERY column of those rows — depth arrays
   included — through Python lists (~seconds per ACT sample at 128²). Selecting the one column first returns
   the same tensors in milliseconds. Drop this patch once LeRobot queries by column upstream.
2. Video decoding. LeRobot picks torchcodec whenever the package is installed, even when its FFmpeg shared
   libraries are missing and it cannot load; then fall back to the `pyav` backend instead of crashing.

Both patches are idempotent and only target LeRobot 0.4.x, the version this plugin pins.
"""

from __future__ import annotations

import functools
import logging

import torch
from lerobot.datasets import lerobot_dataset

logger = logging.getLogger(__name__)

_ORIGINAL_QUERY = lerobot_dataset.LeRobotDataset._query_hf_dataset
_ORIGINAL_DECODE = lerobot_dataset.decode_video_frames


def query_hf_dataset_by_column(self, query_indices: dict[str, list[int]]) -> dict:
    """Same contract as LeRobot's `_query_hf_dataset`, but formats only the queried column."""
    result: dict = {}
    for key, q_idx in query_indices.items():
        if key in self.meta.video_keys:
            continue
        relative = q_idx if self._absolute_to_relative_idx is None else [self._absolute_to_relative_idx[i] for i in q_idx]
        result[key] = torch.stack(self.hf_dataset.select_columns([key])[relative][key])
    return result


@functools.cache
def torchcodec_loads() -> bool:
    """Whether torchcodec's native decoder can actually be loaded (it needs FFmpeg's shared libraries)."""
    try:
        import torchcodec.decoders  # noqa: F401
    except Exception as err:  # torchcodec raises RuntimeError/OSError when FFmpeg is missing
        logger.warning("torchcodec cannot load (%s); decoding videos with the 'pyav' backend instead.",
                       str(err).splitlines()[0] if str(err) else type(err).__name__)
        return False
    return True


def decode_video_frames_with_fallback(video_path, timestamps, tolerance_s, backend=None):
    if backend in (None, "torchcodec") and not torchcodec_loads():
        backend = "pyav"
    return _ORIGINAL_DECODE(video_path, timestamps, tolerance_s, backend)


def apply() -> None:
    lerobot_dataset.LeRobotDataset._query_hf_dataset = query_hf_dataset_by_column
    lerobot_dataset.decode_video_frames = decode_video_frames_with_fallback


def revert() -> None:
    """Restore stock LeRobot behaviour (used by the equivalence test and the loading benchmark)."""
    lerobot_dataset.LeRobotDataset._query_hf_dataset = _ORIGINAL_QUERY
    lerobot_dataset.decode_video_frames = _ORIGINAL_DECODE
