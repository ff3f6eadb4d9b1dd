"""Training reads only what the policy reads, decoded once.

LeRobot 0.6.1's reader serves every column of a row and decodes every camera's video for every sample: a blind
policy's batch costs the colour video and the depth arrays it never looks at, and a small dataset is decoded again
at every step. A policy config that declares the dataset features it reads — `dataset_reads(dataset_meta)`, as
the plugin's policies do — gets instead, under stock `lerobot-train`:

1. **only those features** (with LeRobot's index columns, the task string and their `_is_pad` masks) in each
   sample: no other video is decoded, no other column formatted;
2. **decoded once**: when they fit `OBSBENCH_DATASET_MEMORY_MB` (default 2048 MiB, estimated from the features
   before anything is decoded), the read columns and every frame of the read videos are decoded into memory when
   the dataset is loaded, and each sample is then served from memory. Every served value is the one LeRobot's
   reader returns for that index (same frames, dtypes and shapes: `tests/core/test_dataset_reads.py`). The cache
   lives in the training process (DataLoader workers, which lerobot-train spawns, each unpickle their own copy)
   and nothing is written to the dataset; a dataset over the budget is streamed with only the read keys, with
   one log line saying so.

How the reads reach the reader: lerobot-train builds the dataset before the policy, and the one call that sees
both the policy config and the dataset is `resolve_delta_timestamps(policy_config, dataset_meta)`, whose result
LeRobot hands to the dataset's `DatasetReader`. The patched resolver returns that mapping tagged with the
policy's reads (`PolicyQuery`); the reader honours the tag. Datasets opened any other way read as LeRobot does.

`OBSBENCH_DATASET_READER` chooses the reader for tagged datasets: `memory` (the default), `filtered` (the read
keys, streamed) or `stock` (LeRobot's reader, untouched: the comparison `benchmarks/bench_train_loop.py` makes).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from importlib import metadata

import av
import numpy as np
import torch
from datasets.formatting.formatting import NumpyArrowExtractor
from lerobot.configs import DEPTH_METER_UNIT
from lerobot.datasets import factory
from lerobot.datasets.dataset_reader import DatasetReader
from lerobot.datasets.depth_utils import MM_PER_METRE

from lerobot_obsbench import patches
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.numeric import number_from_environment
from lerobot_obsbench.patches import LeRobotTorchFormatter, Patch
from lerobot_obsbench.schema import DEPTH_PREFIX, SchemaError

logger = logging.getLogger(__name__)

READER_ENV = "OBSBENCH_DATASET_READER"
MEMORY_ENV = "OBSBENCH_DATASET_MEMORY_MB"
READERS = ("memory", "filtered", "stock")
DEFAULT_MEMORY_MB = 2048
# What LeRobot's decoders raise on a truncated or damaged video: torchcodec RuntimeError or ValueError, PyAV its
# FFmpegError (InvalidDataError, an OSError for a broken container), LeRobot a FrameTimestampError for missing frames
VIDEO_DECODE_ERRORS = (RuntimeError, ValueError, OSError, av.error.FFmpegError)
# LeRobot's own per-row columns, which its reader uses to place a sample in its episode
INDEX_COLUMNS = ("timestamp", "frame_index", "episode_index", "index", "task_index")


READS_FIX = "the plugin's policies read only their features"
READS_RETIRE = "a reader that serves only the features a policy declares, decoded once"
READS_PATCHES = (
    Patch(factory, "resolve_delta_timestamps", READS_FIX, READS_RETIRE),
    *(
        Patch(DatasetReader, name, READS_FIX, READS_RETIRE)
        for name in ("__init__", "try_load", "load_and_activate", "get_item")
    ),
)
patches.register(*READS_PATCHES)
# LeRobot's own functions by name, as the records captured them
_STOCK = {patch.attribute: patch.stock for patch in READS_PATCHES}
ARCHITECTURE_TABLE = "docs/architecture.md#lerobot-functions-the-plugin-replaces"
_announced: list[str] = []  # the start-up line, once logged (once per process)


def routes_line() -> str:
    """The start-up line: what the plugin routes in this process and where the list of replaced functions is."""
    in_place = [patch for patch in patches.PATCHES if patch.in_place()]
    fixes = list(dict.fromkeys(patch.fix for patch in in_place))
    reader = os.environ.get(READER_ENV, "memory")  # unchecked here: the reader refuses a bad value, naming it
    if READS_FIX in fixes:
        reads = f"{READS_FIX} (reader `{reader}`, {READER_ENV})"
        fixes[fixes.index(READS_FIX)] = (
            reads if reader != "stock" else f"datasets read by LeRobot's reader ({READER_ENV}=stock)"
        )
    return (
        f"lerobot_obsbench patches {len(in_place)} functions on LeRobot {metadata.version('lerobot')}'s path: "
        f"{'; '.join(fixes)} "
        f"(every one: {ARCHITECTURE_TABLE})"
    )


def announce() -> None:
    """Log the start-up line the first time logging shows it: at import when logging is already set up
    (lerobot-eval), else when lerobot-train first resolves a dataset's query (it sets logging up after importing
    plugins)."""
    if not _announced and logger.isEnabledFor(logging.INFO) and logger.hasHandlers():
        _announced.append(routes_line())
        logger.info(_announced[0])


class PolicyQuery(dict):
    """`resolve_delta_timestamps`'s mapping (feature -> time offsets), carrying the features the policy reads."""

    def __init__(self, delta_timestamps: dict | None, reads: frozenset[str]):
        super().__init__(delta_timestamps or {})
        self.reads = reads


def reader_choice() -> str:
    choice = os.environ.get(READER_ENV, "memory")
    if choice not in READERS:
        raise ConfigError(f"{READER_ENV}={choice!r}: choose one of {', '.join(READERS)} (default memory).")
    return choice


def memory_budget_bytes() -> int:
    """The budget of `OBSBENCH_DATASET_MEMORY_MB` (MiB; 0 streams) in bytes."""
    return int(number_from_environment(MEMORY_ENV, DEFAULT_MEMORY_MB, minimum=0) * 2**20)


def resolve_delta_timestamps(cfg, ds_meta):
    """LeRobot's resolver; for a config that declares its reads, the result tagged with them."""
    announce()
    delta_timestamps = _STOCK["resolve_delta_timestamps"](cfg, ds_meta)
    declare: Callable | None = getattr(cfg, "dataset_reads", None)
    if declare is None or reader_choice() == "stock":
        return delta_timestamps
    return PolicyQuery(delta_timestamps, frozenset(declare(ds_meta)))


def every_feature(delta_timestamps: dict | None) -> dict | None:
    """The same query without the policy's reads: a dataset opened with it serves every feature, for code that
    reads more than the policy does (the held-out diagnostics read the simulator's object poses)."""
    return dict(delta_timestamps) if delta_timestamps else None


def query_videos(reader: DatasetReader, query: dict[str, list[float]], ep_idx: int) -> dict[str, torch.Tensor]:
    """LeRobot's `_query_videos` (frames of episode `ep_idx` at each video key's timestamps); a video that cannot be
    decoded is refused in one line naming its file, instead of the decoder's traceback."""
    try:
        return reader._query_videos(query, ep_idx)
    except VIDEO_DECODE_ERRORS:
        for key, timestamps in query.items():  # LeRobot decodes the keys together: find the file that failed
            try:
                reader._query_videos({key: timestamps}, ep_idx)
            except VIDEO_DECODE_ERRORS as err:
                raise undecodable_video(reader, key, ep_idx, err) from None
        raise


def undecodable_video(reader: DatasetReader, key: str, ep_idx: int, err: Exception) -> SchemaError:
    """The one-line refusal of video `key`'s file for episode `ep_idx`, which the decoder failed on with `err`."""
    path = reader.root / reader._meta.get_video_file_path(ep_idx, key)
    return SchemaError(
        f"{path}: the {key} frames of episode {ep_idx} cannot be decoded ({error_reason(err)}): the video is "
        "truncated or damaged (an interrupted copy, download or recording); copy it again, or drop its episodes "
        f"(lerobot-edit-dataset --operation.type=delete_episodes); `obsbench validate --root {reader.root}` decodes "
        "every frame training reads"
    )


def error_reason(err: Exception) -> str:
    """A decoder's error in one line: its first."""
    return str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__


class StreamedRows:
    """The read keys of each sample, streamed from the dataset's files as LeRobot does, without the others."""

    def __init__(self, reader: DatasetReader, columns: list[str], videos: list[str]):
        self.reader, self.videos = reader, videos
        self.table = reader.hf_dataset.select_columns(columns)

    def row(self, rel: int) -> dict:
        return self.table[rel]

    def stack(self, key: str, rels: list[int]) -> torch.Tensor:
        return torch.stack(self.table.select_columns([key])[rels][key])

    def frames(self, ep_idx: int, rels_by_video: dict[str, list[int]]) -> dict[str, torch.Tensor]:
        timestamps = self.table.select_columns(["timestamp"])
        query = {key: torch.stack(timestamps[rels]["timestamp"]).tolist() for key, rels in rels_by_video.items()}
        return query_videos(self.reader, query, ep_idx)


class MemoryRows:
    """Every read column and every frame of every read video, decoded once; samples served by indexing."""

    def __init__(self, reader: DatasetReader, columns: list[str], videos: list[str]):
        self.videos = videos
        self.formatter = LeRobotTorchFormatter(features=reader.hf_dataset.features)
        table = reader.hf_dataset.select_columns(columns).with_format("arrow")[:]
        decoded = self.formatter.python_features_decoder.decode_batch(NumpyArrowExtractor().extract_batch(table))
        # numeric columns tensorized whole by LeRobot's formatter rules (floats -> float32, integers -> int64);
        # anything else (images as PIL) kept as decoded and tensorized per sample, as the formatter does per row
        self.tensors = {k: self.formatter._tensorize(v) for k, v in decoded.items() if is_numeric(v)}
        self.objects = {k: v for k, v in decoded.items() if not is_numeric(v)}
        episodes, timestamps = decoded["episode_index"], decoded["timestamp"]
        per_row: dict[str, list] = {key: [None] * len(table) for key in videos}
        for ep_idx in np.unique(episodes).tolist():
            rels = np.flatnonzero(episodes == ep_idx)
            query = {key: timestamps[rels].tolist() for key in videos}
            for key, frames in query_videos(reader, query, ep_idx).items():
                frames = frames.reshape(len(rels), *frames.shape[-3:])  # one-frame episodes come back squeezed
                for rel, frame in zip(rels.tolist(), frames, strict=True):
                    per_row[key][rel] = frame
        self.frames_of = {key: torch.stack(frames) for key, frames in per_row.items()}

    def row(self, rel: int) -> dict:
        item = {key: column[rel].clone() for key, column in self.tensors.items()}
        item.update({key: self.formatter._recursive_tensorize(column[rel]) for key, column in self.objects.items()})
        return item

    def stack(self, key: str, rels: list[int]) -> torch.Tensor:
        if key in self.tensors:
            return self.tensors[key].index_select(0, torch.tensor(rels))
        return torch.stack([self.formatter._recursive_tensorize(self.objects[key][rel]) for rel in rels])

    def frames(self, ep_idx: int, rels_by_video: dict[str, list[int]]) -> dict[str, torch.Tensor]:
        out = {}
        for key, rels in rels_by_video.items():
            if len(rels) == 1:  # LeRobot squeezes a single queried frame
                out[key] = self.frames_of[key][rels[0]].clone()
            else:
                out[key] = self.frames_of[key].index_select(0, torch.tensor(rels))
        return out


# LeRobot's depth videos give a hole back as this many millimetres (their 12-bit log quantisation's floor)
STOCK_DEPTH_FLOOR_MM = 10.0


def refuse_depth_without_readings(reader: DatasetReader, rows: MemoryRows) -> None:
    """Refuse, as the dataset loads, a read depth key none of whose frames holds a reading: the policy would train
    on empty clouds (and stop only once it has seen enough of them); `obsbench validate` names it too."""
    stock = set(reader._meta.depth_keys)
    columns = {**rows.tensors, **rows.frames_of, **rows.objects}
    for key, values in columns.items():
        if not (key in stock or key.startswith(DEPTH_PREFIX)) or not len(values):
            continue
        floor = STOCK_DEPTH_FLOOR_MM if key in stock else 0
        if torch.is_tensor(values):
            reading = float(values.max()) > floor
        else:  # LeRobot's 16-bit depth images, decoded as pictures
            reading = any(float(np.asarray(frame).max()) > floor for frame in values)
        if not reading:
            raise SchemaError(
                f"{key}: every frame's depth is {'a hole' if floor else '0'} (invalid): no depth was recorded, so a "
                f"policy reading it would see nothing; `obsbench validate --root {reader.root}` lists the dataset's "
                "problems"
            )


def is_numeric(column) -> bool:
    return isinstance(column, np.ndarray) and column.dtype.kind in "iuf"


def estimated_bytes(reader: DatasetReader, columns: list[str], videos: list[str]) -> int:
    """Memory the decoded read keys take, from the features alone (before anything is decoded)."""
    features = reader._meta.features
    per_row = 0
    for key in columns + videos:
        dtype = features[key]["dtype"]
        if key in videos:  # uint8 frames, unless LeRobot returns floats (depth videos, or return_uint8=False)
            itemsize = 1 if reader._return_uint8 and key not in reader._meta.depth_keys else 4
        elif dtype == "image":
            itemsize = 1
        else:  # served as LeRobot's formatter serves them: floats as float32, integers as int64
            try:
                itemsize = 4 if np.dtype(dtype).kind == "f" else 8
            except TypeError:  # strings: a pointer's worth per value
                itemsize = 8
        per_row += int(np.prod(features[key]["shape"])) * itemsize
    return per_row * reader.num_frames


def read_plan(reader: DatasetReader) -> tuple[list[str], list[str]]:
    """(columns, videos) a tagged reader serves: the read features, and LeRobot's index columns."""
    reads = reader._obsbench_reads
    columns = [key for key in reader.hf_dataset.column_names if key in reads or key in INDEX_COLUMNS]
    return columns, [key for key in reader._meta.video_keys if key in reads]


def attach_rows(reader: DatasetReader) -> None:
    """Give a loaded, tagged reader its rows: in memory when they fit the budget, else streamed."""
    columns, videos = read_plan(reader)
    reader._obsbench_placement = Placement(reader)
    needed, budget, choice = estimated_bytes(reader, columns, videos), memory_budget_bytes(), reader_choice()
    if choice == "memory" and needed <= budget:
        start = time.perf_counter()
        reader._obsbench_rows = MemoryRows(reader, columns, videos)
        refuse_depth_without_readings(reader, reader._obsbench_rows)
        logger.info(
            f"obsbench: {reader.num_frames} frames of {len(columns) + len(videos)} read keys decoded into memory "
            f"({needed / 2**20:.0f} MiB, {time.perf_counter() - start:.1f} s); not read: "
            f"{', '.join(sorted(set(reader._meta.features) - set(columns) - set(videos))) or 'nothing'}"
        )
        return
    if choice == "memory":
        logger.info(
            f"obsbench: the read keys need ~{needed / 2**20:.0f} MiB, over {MEMORY_ENV}={budget / 2**20:.0f}: "
            "streaming them from the dataset's files instead"
        )
    reader._obsbench_rows = StreamedRows(reader, columns, videos)


def reader_init(self, *args, **kwargs):
    _STOCK["__init__"](self, *args, **kwargs)
    delta_timestamps = kwargs.get("delta_timestamps", args[5] if len(args) > 5 else None)
    self._obsbench_reads = getattr(delta_timestamps, "reads", None)
    self._obsbench_rows = None


def reader_try_load(self) -> bool:
    loaded = _STOCK["try_load"](self)
    if loaded and self._obsbench_reads is not None:
        attach_rows(self)
    return loaded


def reader_load_and_activate(self) -> None:
    _STOCK["load_and_activate"](self)
    if self._obsbench_reads is not None:
        attach_rows(self)


class Placement:
    """Where a sample's queried offsets land, as LeRobot's `_get_query_indices` places them (rows clamped to the
    sample's episode, `_is_pad` where an offset falls outside it), from arrays built once instead of per sample."""

    def __init__(self, reader: DatasetReader):
        episodes = reader._meta.episodes
        self.starts = np.asarray(list(episodes["dataset_from_index"]))
        self.ends = np.asarray(list(episodes["dataset_to_index"]))
        reads = reader._obsbench_reads
        self.deltas = {key: np.asarray(d) for key, d in (reader.delta_indices or {}).items() if key in reads}
        mapping = reader._absolute_to_relative_idx
        self.relative = None
        if mapping is not None:
            self.relative = np.full(max(mapping) + 1, -1)
            self.relative[list(mapping)] = list(mapping.values())
        self.tasks = list(reader._meta.tasks.index)

    def query(self, key: str, abs_idx: int, ep_idx: int) -> tuple[list[int], torch.Tensor]:
        """(relative rows, padding mask) of `key`'s offsets around absolute frame `abs_idx`."""
        wanted = abs_idx + self.deltas[key]
        start, end = self.starts[ep_idx], self.ends[ep_idx]
        rows = np.clip(wanted, start, end - 1)
        if self.relative is not None:
            rows = self.relative[rows]
        return rows.tolist(), torch.from_numpy((wanted < start) | (wanted >= end))


def reader_get_item(self, idx) -> dict:
    """LeRobot's `DatasetReader.get_item`, serving only the read keys from `self._obsbench_rows`."""
    rows = getattr(self, "_obsbench_rows", None)
    if rows is None:
        return _STOCK["get_item"](self, idx)
    placement = self._obsbench_placement
    item = rows.row(idx)
    ep_idx, abs_idx = item["episode_index"].item(), item["index"].item()
    rels_by_video = {key: [idx] for key in rows.videos}
    for key in placement.deltas:
        rels, item[f"{key}_is_pad"] = placement.query(key, abs_idx, ep_idx)
        if key in rows.videos:
            rels_by_video[key] = rels
        else:
            item[key] = rows.stack(key, rels)
    if rows.videos:
        item = {**rows.frames(ep_idx, rels_by_video), **item}

    if self._image_transforms is not None:
        for cam in self._meta.camera_keys:
            if cam in item and cam not in self._meta.depth_keys:
                item[cam] = self._image_transforms(item[cam])
    for key, stored_unit in self._image_depth_units.items():
        if key in item and stored_unit is not None and stored_unit != self._depth_output_unit:
            item[key] = item[key] * MM_PER_METRE if stored_unit == DEPTH_METER_UNIT else item[key] / MM_PER_METRE
    item["task"] = placement.tasks[item["task_index"].item()]
    return item


def install() -> None:
    """Route lerobot-train's datasets through the policy's reads (see the module docstring)."""
    factory.resolve_delta_timestamps = resolve_delta_timestamps
    DatasetReader.__init__ = reader_init
    DatasetReader.try_load = reader_try_load
    DatasetReader.load_and_activate = reader_load_and_activate
    DatasetReader.get_item = reader_get_item
