"""Narrow fixes to LeRobot 0.6.1's dataset code, applied when the plugin is imported.

1. Array columns through Python lists. LeRobot's `DatasetReader` formats its `datasets.Dataset` with
   `set_transform(hf_transform_to_torch)`: every read first turns the Arrow rows into Python lists, then
   `torch.tensor(list)`. A depth frame is thousands of nested Python ints, and an ACT chunk query
   (`_query_hf_dataset`) formats every column of its 100 rows, depth included, so loading dominates training
   (`benchmarks/bench_loading.py` measures it). `LeRobotTorchFormatter` produces the same output — tensors per
   row, lists of tensors per batch / column, PIL images through LeRobot's own `pil_to_chw_tensor`, same dtypes,
   language columns untouched — from NumPy extraction instead, and `query_hf_dataset_by_column` reads only the
   queried column. Drop both once LeRobot fixes this upstream.
2. Aggregating datasets with array features (`array_safe_aggregation()`, used only around the plugin's own
   calls of `aggregate_datasets`): LeRobot copies data files through pandas unless the dataset has images, and
   pandas cannot write HF `Array3D` columns (depth) back to parquet. Inside the context the data files take
   LeRobot's own image path (read and written through `datasets`), which keeps those columns' types. (Callers
   pass `concatenate_data=False`: appending to an existing data file still concatenates data frames, which
   pandas cannot do with those columns either.)
3. The AV1 encoder's real-time priority. SVT-AV1 (LeRobot's default codec, `libsvtav1`, in PyAV's wheel) switches
   the thread that opens an encoder to SCHED_FIFO priority 99 whenever the process may, that is as root. That
   thread is usually the main one: it then preempts every normal process on the machine, and every process it
   starts afterwards (a grid's lerobot-train and evaluation units, a test's subprocesses) inherits the policy.
   `apply()` wraps LeRobot's `encode_video_frames` in `thread_scheduling_kept()`, which gives the calling thread
   its policy back.

4. The reason for a refused config. LeRobot's commands build configs with draccus, which turns every TypeError or
   ValueError raised while a dataclass is built into "Couldn't instantiate class ... using the given arguments",
   keeping the reason only as the exception's cause; LeRobot then prints the wrapper alone. `apply()` wraps
   `draccus.parse` (which LeRobot's parser and its `from_pretrained` loaders call) so that a failure caused by one
   of the plugin's own refusals (an `ObsBenchError`) is raised as draccus' own `DecodingError` carrying that
   message: LeRobot prints it as the one error line (`error: `policy`: ...`). Other failures are left as they are.

5. A resumed run that trains what the uninterrupted one trains. LeRobot saves the torch, NumPy and Python RNG
   states with each checkpoint and restores them on `--resume`, and positions its `EpisodeAwareSampler` at the
   step's epoch and offset (`compute_sampler_state`). Two things undo that in 0.6.1: accelerate's `DataLoaderShard`
   sets the sampler's epoch to its own iteration count, which a new process starts at 0, so a run resumed after
   its first epoch replays the first epoch's order; and a DataLoader draws its base seed from torch's global RNG
   when its iterator is made — an uninterrupted run made it at the start of the epoch, before the checkpoint
   saved that RNG, a run resumed mid-epoch makes it right after restoring it, so every later random draw (dropout,
   the VAE's sample, point sampling, diffusion noise) is shifted by one. lerobot-train's `cycle` is replaced by one
   that, in a resumed run (`compute_sampler_state`, called only then, noted as it is computed), first sets the
   loader's epoch to the resumed one and, when the run resumes inside an epoch, fetches its first batch with
   torch's CPU RNG forked. A run resumed at an epoch boundary draws there as the uninterrupted run does; a run
   that is not resumed is trained exactly as LeRobot trains it.

Fixes 1, 3, 4 and 5 replace LeRobot (or draccus) functions for every process that imports the plugin (LeRobot's
plugin discovery imports it into every `lerobot-*` command), so `apply()` patches only the LeRobot version they were
written and tested for (`LEROBOT_VERSION`); on any other it warns and leaves LeRobot as it is.

`stock_loading()` restores LeRobot's behaviour for the equivalence test and the loading benchmark. Every replaced
attribute is a `Patch` record in `PATCHES` (`dataset_reads` adds its own): the start-up line that lerobot-train and
lerobot-eval log, and docs/architecture.md's table, are written from them.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import sys
import types
from dataclasses import dataclass, field
from importlib import metadata

import datasets
import draccus
import numpy as np
import PIL.Image
import torch
from datasets.formatting import _register_formatter
from datasets.formatting.torch_formatter import TorchFormatter
from lerobot.datasets import aggregate, dataset_tools, dataset_writer, video_utils
from lerobot.datasets.dataset_reader import DatasetReader
from lerobot.datasets.io_utils import pil_to_chw_tensor
from lerobot.datasets.language import LANGUAGE_COLUMNS
from lerobot.scripts import lerobot_train

from lerobot_obsbench.errors import ObsBenchError

logger = logging.getLogger(__name__)

FORMAT_TYPE = "lerobot_obsbench_torch"
LEROBOT_VERSION = "0.6.1"  # the version these patches replace methods of


@dataclass(frozen=True)
class Patch:
    """One attribute of LeRobot (or of the parser it uses) that the plugin replaces: the records behind the start-up
    line and `docs/architecture.md`'s table of replaced functions."""

    owner: object  # the module or class holding the attribute
    attribute: str
    fix: str  # the fix it is part of, as the start-up line names it
    retire: str  # the upstream change after which the plugin can drop it
    versions: str = LEROBOT_VERSION  # the LeRobot version it is applied on
    when: str = "on import"  # when it is replaced: on importing the plugin, or inside which of the plugin's calls
    stock: object = field(init=False, repr=False)  # the attribute as LeRobot defines it

    def __post_init__(self):
        object.__setattr__(self, "stock", getattr(self.owner, self.attribute))

    @property
    def symbol(self) -> str:
        owner = self.owner
        prefix = owner.__name__ if isinstance(owner, types.ModuleType) else f"{owner.__module__}.{owner.__qualname__}"
        return f"{prefix}.{self.attribute}"

    def in_place(self) -> bool:
        return getattr(self.owner, self.attribute) is not self.stock


PATCHES: list[Patch] = []  # every replaced attribute; modules above this one add theirs with `register`


def register(*patches: Patch) -> None:
    PATCHES.extend(patches)


# what each fix replaces (the numbers are the module docstring's); the last column of the docs' table is `retire`
FORMATTER = ("columns formatted from NumPy", "a NumPy-backed torch formatter in `DatasetReader`")
ENCODER = ("video encoding keeps its thread's scheduling", "the thread's scheduling restored after opening SVT-AV1")
FORMATTER_PATCHES = (  # fix 1
    Patch(DatasetReader, "_query_hf_dataset", *FORMATTER),
    Patch(DatasetReader, "_load_hf_dataset", *FORMATTER),
)
# fix 3: LeRobot's video encoder under each name it is called by (each module holds its own)
ENCODER_PATCHES = tuple(Patch(m, "encode_video_frames", *ENCODER) for m in (video_utils, dataset_writer, dataset_tools))
PARSE = ("config refusals keep their reasons", "a parse error printed with its cause")
PARSE_PATCH = Patch(draccus, "parse", *PARSE)
RESUME = (
    "a resumed run trains what the uninterrupted run trains",
    "a resume that keeps the loader's epoch and makes its first iterator without drawing from the restored RNG",
)
RESUME_PATCHES = (Patch(lerobot_train, "compute_sampler_state", *RESUME), Patch(lerobot_train, "cycle", *RESUME))
register(
    *FORMATTER_PATCHES,
    *ENCODER_PATCHES,
    PARSE_PATCH,  # fix 4
    *RESUME_PATCHES,  # fix 5
    Patch(  # fix 2
        aggregate,
        "aggregate_data",
        "aggregation keeps array columns",
        "array (`Array3D`) columns copied without pandas",
        when="inside the plugin's own `aggregate_datasets` calls",
    ),
)
# LeRobot's own functions, as the records captured them
_STOCK = {"query": FORMATTER_PATCHES[0].stock, "load": FORMATTER_PATCHES[1].stock}
_STOCK_ENCODERS = {patch.owner: patch.stock for patch in ENCODER_PATCHES}
_STOCK_PARSE = PARSE_PATCH.stock
_STOCK_SAMPLER_STATE, _STOCK_CYCLE = (patch.stock for patch in RESUME_PATCHES)


class LeRobotTorchFormatter(TorchFormatter):
    """`hf_transform_to_torch`'s exact output, built from NumPy extraction instead of Python lists."""

    def _tensorize(self, value):
        if isinstance(value, PIL.Image.Image):
            return pil_to_chw_tensor(value)  # LeRobot's own: RGB (C,H,W) float in [0,1], 16-bit depth float32
        if isinstance(value, (np.ndarray, np.number)) and value.dtype.kind in "iuf":
            # TorchFormatter's own rules (integers -> int64, uint16/32 widened first; floats -> float32), without the
            # import attempts it makes for every value (a failing torchvision import: ~50 us each, per array)
            if value.dtype.kind == "f":
                return torch.tensor(value, dtype=torch.float32)
            if value.dtype in (np.uint16, np.uint32):
                value = value.astype(np.int64)
            return torch.tensor(value, dtype=torch.int64)
        return super()._tensorize(value)

    def _per_row(self, column):
        return [self._recursive_tensorize(value) for value in column]

    def format_column(self, pa_table):
        name = pa_table.column_names[0]
        if name in LANGUAGE_COLUMNS:  # LeRobot leaves them as Python objects
            return self.python_arrow_extractor().extract_column(pa_table)
        column = self.numpy_arrow_extractor().extract_column(pa_table)
        column = self.python_features_decoder.decode_column(column, name)
        return self._per_row(column)

    def format_batch(self, pa_table):
        batch = self.numpy_arrow_extractor().extract_batch(pa_table)
        batch = self.python_features_decoder.decode_batch(batch)
        out = {name: self._per_row(column) for name, column in batch.items() if name not in LANGUAGE_COLUMNS}
        language = [name for name in pa_table.column_names if name in LANGUAGE_COLUMNS]
        if language:
            out.update(self.python_arrow_extractor().extract_batch(pa_table.select(language)))
        return {name: out[name] for name in pa_table.column_names}


_register_formatter(LeRobotTorchFormatter, FORMAT_TYPE)


def load_hf_dataset_fast(self) -> datasets.Dataset:
    hf_dataset = _STOCK["load"](self)
    hf_dataset.set_format(FORMAT_TYPE)
    return hf_dataset


def query_hf_dataset_by_column(self, query_indices: dict[str, list[int]]) -> dict:
    """Same contract as `DatasetReader._query_hf_dataset`, but formats only the queried column."""
    result: dict = {}
    for key, q_idx in query_indices.items():
        if key in self._meta.video_keys:
            continue
        relative = (
            q_idx if self._absolute_to_relative_idx is None else [self._absolute_to_relative_idx[i] for i in q_idx]
        )
        result[key] = torch.stack(self.hf_dataset.select_columns([key])[relative][key])
    return result


def _set(query, load) -> None:
    DatasetReader._query_hf_dataset = query
    DatasetReader._load_hf_dataset = load


@contextlib.contextmanager
def thread_scheduling_kept():
    """Gives the calling thread back the scheduling policy and priority it had on entering (Linux only: elsewhere
    there is neither the call nor the encoder's switch)."""
    if not hasattr(os, "sched_getscheduler"):
        yield
        return
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        yield
    finally:
        if (os.sched_getscheduler(0), os.sched_getparam(0)) != (policy, param):
            os.sched_setscheduler(0, policy, param)


def keeping_scheduling(encode):
    """`encode` (a video encoding function) that leaves the calling thread's scheduling as it found it."""

    @functools.wraps(encode)
    def encode_keeping_scheduling(*args, **kwargs):
        with thread_scheduling_kept():
            return encode(*args, **kwargs)

    return encode_keeping_scheduling


def plugin_refusal(error: BaseException) -> ObsBenchError | None:
    """The plugin's own refusal behind `error` (followed through its causes), if there is one."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, ObsBenchError):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


@functools.wraps(_STOCK_PARSE)
def parse_with_reasons(*args, **kwargs):
    """`draccus.parse`, raising a plugin refusal's own message as the `DecodingError` LeRobot prints (fix 4)."""
    try:
        return _STOCK_PARSE(*args, **kwargs)
    except draccus.utils.ParsingError as error:
        refusal = plugin_refusal(error)
        if refusal is None:
            raise
        raise draccus.utils.DecodingError(getattr(error, "key_path", ()), str(refusal)) from refusal


class _Resume:
    """The sampler state `sampler_state_noting_resume` computed for this process's resumed run, until its first
    batch is fetched (fix 5)."""

    state: dict | None = None


@functools.wraps(_STOCK_SAMPLER_STATE)
def sampler_state_noting_resume(*args, **kwargs) -> dict:
    """LeRobot's `compute_sampler_state` (called only when a run resumes), noting the epoch and offset it resumes
    at (fix 5)."""
    _Resume.state = _STOCK_SAMPLER_STATE(*args, **kwargs)
    return _Resume.state


@functools.wraps(_STOCK_CYCLE)
def cycle_keeping_restored_rng(iterable):
    """LeRobot's `cycle`; in a resumed run, the loader is first set to the resumed epoch (accelerate's loader would
    set its sampler back to epoch 0) and, inside an epoch, the first batch (whose fetch makes the DataLoader's
    iterator, drawing its base seed) is fetched with torch's CPU RNG forked, as the uninterrupted run fetched it
    before its checkpoint saved that state (fix 5)."""
    state, _Resume.state = _Resume.state, None
    if state is not None and hasattr(iterable, "set_epoch"):
        iterable.set_epoch(state["epoch"])
    batches = _STOCK_CYCLE(iterable)
    if state is not None and state["start_index"] > 0:
        with torch.random.fork_rng(devices=[]):
            first = next(batches)
        yield first
    yield from batches


def one_line_refusal(error: BaseException) -> str | None:
    """The plugin's refusal behind `error`, as the one line it is written as (a DataLoader worker's refusal comes
    back with the worker's traceback in its message: its last line is the refusal's own)."""
    refusal = plugin_refusal(error)
    if refusal is None:
        return None
    text = str(refusal)
    if "Original Traceback" in text:
        text = text.strip().splitlines()[-1].split(": ", 1)[-1]
    return text


def refusals_in_one_line(program: str | None = None) -> None:
    """In a stock `lerobot-*` command (`program`: the command's name; None: this process's, when it is one), print
    an uncaught refusal of the plugin as `program: error: message` instead of its traceback, as `obsbench` does;
    every other error keeps Python's report. Processes that are no LeRobot command are left as they are."""
    program = program or os.path.basename(sys.argv[0] if sys.argv else "")
    if not program.startswith("lerobot-"):
        return
    previous = sys.excepthook

    def excepthook(kind, error, traceback):
        line = one_line_refusal(error)
        if line is None:
            previous(kind, error, traceback)
        else:
            print(f"{program}: error: {line}", file=sys.stderr)

    sys.excepthook = excepthook


def apply(lerobot_version: str | None = None) -> bool:
    """Patch LeRobot if it is the version the patches were written for; returns whether it patched."""
    version = lerobot_version or metadata.version("lerobot")
    if version != LEROBOT_VERSION:
        logger.warning(
            "lerobot_obsbench: LeRobot %s is installed, the plugin's fixes to LeRobot were written for %s; "
            "leaving LeRobot unpatched (loading depth datasets may be slow, a resumed run may train other weights "
            "than an uninterrupted one, and a refused policy config is printed without its reason).",
            version,
            LEROBOT_VERSION,
        )
        return False
    draccus.parse = parse_with_reasons
    lerobot_train.compute_sampler_state = sampler_state_noting_resume
    lerobot_train.cycle = cycle_keeping_restored_rng
    _set(query_hf_dataset_by_column, load_hf_dataset_fast)
    for module, encode in _STOCK_ENCODERS.items():  # wrapped from the stock one, so applying again wraps once
        module.encode_video_frames = keeping_scheduling(encode)
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
        arrays = [k for k in arrays if len(tuple(self._meta.features[k].get("shape") or ())) >= 2]
        return self._meta.image_keys or arrays


@contextlib.contextmanager
def array_safe_aggregation():
    """LeRobot's `aggregate_datasets`, made to keep array (depth) columns; see fix 2 of the module docstring."""
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
