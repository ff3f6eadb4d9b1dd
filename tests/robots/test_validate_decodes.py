"""`obsbench validate` decodes what training reads: LeRobot's own depth maps (`observation.images.<cam>_depth`, 16-bit
images or LeRobot's depth video) and colour videos, every frame, with LeRobot's decoders. Depth that holds nothing or
is not in millimetres, and a file that cannot be decoded, are refused in one line naming the camera, the file and
the fix; training on the same data fails naming the same check."""

from __future__ import annotations

import re

import pytest
import torch

from lerobot_obsbench.cli import main
from lerobot_obsbench.schema import SchemaError
from tests.commands.bad_inputs_validate import (
    CAMERA,
    COLOUR_KEY,
    DEPTH_KEY,
    FIRST_DATA_FILE,
    calibrated_stock_dataset,
    depth_in_metres,
    first_video,
    truncate,
    zero_depth,
)
from tests.support.helpers import training_setup

WORKSPACE = [-0.3, 0.3, -0.3, 0.3, -0.02, 0.3]  # the stock-depth scene's table top and sphere
DEPTH_CHANGES = {"zero": zero_depth, "metres": depth_in_metres}


@pytest.fixture(scope="module", params=["image", "video"])
def storage(request) -> str:
    return request.param


@pytest.fixture(scope="module")
def good(storage, tmp_path_factory):
    return calibrated_stock_dataset(tmp_path_factory.mktemp("good") / "koch", video=storage == "video")


def _depth_file(storage: str) -> str:
    return first_video(DEPTH_KEY) if storage == "video" else FIRST_DATA_FILE


def _refusal(root, capsys, *args) -> str:
    assert main(["validate", "--root", str(root), *args]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len([line for line in err.splitlines() if "error:" in line]) == 1, err
    return err


@pytest.mark.parametrize("change", DEPTH_CHANGES)
def test_depth_without_millimetres_is_refused_naming_the_camera_the_file_and_the_fix(storage, change, tmp_path, capsys):
    """All-zero depth, or metres rounded into LeRobot's uint16 millimetres, used to pass as "ok … checked every
    frame's depth" (stock cameras were left out of the frame scan)."""
    root = calibrated_stock_dataset(tmp_path / "koch", video=storage == "video", depth=DEPTH_CHANGES[change])
    err = _refusal(root, capsys)
    assert f"camera {CAMERA}: {DEPTH_KEY}" in err and _depth_file(storage) in err
    if change == "metres" and storage == "image":  # images keep the 1s: their median is 1 mm
        assert "median valid depth is 1 mm" in err and "not in millimetres" in err and "depth_unit_mm" in err
    else:  # 0 mm, and in a video 1 mm too, is a hole
        assert "no frame holds valid depth" in err and "record again" in err
    # the colour stream alone is not refused: rgb reads no depth
    assert main(["validate", "--root", str(root), "--obs-space", "rgb"]) == 0


def test_a_truncated_colour_video_is_refused_naming_the_file(tmp_path, capsys):
    root = calibrated_stock_dataset(tmp_path / "koch", video=True)
    truncate(root / first_video(COLOUR_KEY))
    for space in ("rgb", "pointcloud"):
        err = _refusal(root, capsys, "--obs-space", space)
        assert f"{root / first_video(COLOUR_KEY)}: the {COLOUR_KEY} frames of episode 0 cannot be decoded" in err
        assert "copy it again" in err


def test_a_depth_image_that_cannot_be_decoded_is_refused_naming_the_file(tmp_path, capsys):
    """A damaged 16-bit depth image inside the parquet file (16 bytes of its TIFF kept)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    root = calibrated_stock_dataset(tmp_path / "koch", video=False)
    path = root / FIRST_DATA_FILE
    table = pq.read_table(path)
    images = table.column(DEPTH_KEY).to_pylist()
    images[13] = {**images[13], "bytes": images[13]["bytes"][:16]}
    column = table.column_names.index(DEPTH_KEY)
    pq.write_table(table.set_column(column, DEPTH_KEY, pa.array(images, table.schema.field(DEPTH_KEY).type)), path)
    err = _refusal(root, capsys, "--obs-space", "depth")
    assert f"{path}: the {DEPTH_KEY} image of episode 1 cannot be decoded" in err and "copy the file again" in err


def test_a_good_dataset_passes_and_the_output_lists_what_was_read(good, storage, capsys):
    assert main(["validate", "--root", str(good)]) == 0
    out = capsys.readouterr().out
    assert "ok      pointcloud" in out and "ok      rgb" in out
    stored = "video, 1 file" if storage == "video" else "images in parquet, 1 file"
    assert f"read    {COLOUR_KEY}: 24 of 24 frames decoded ({stored})" in out
    assert f"read    {DEPTH_KEY} (camera {CAMERA}, LeRobot's depth): 24 of 24 frames decoded ({stored})" in out
    median = re.search(r"24 with valid depth, median valid depth (\d+) mm", out)
    assert median and 500 <= int(median.group(1)) <= 700, out  # the scene lies 0.4-1.3 m away, mostly ~0.6 m
    assert "every frame's depth" not in out and "checked the metadata and every frame of the keys read above" in out
    # rgb reads no depth: none is decoded
    assert main(["validate", "--root", str(good), "--obs-space", "rgb"]) == 0
    out = capsys.readouterr().out
    assert f"read    {COLOUR_KEY}: 24 of 24 frames decoded" in out and DEPTH_KEY not in out
    assert main(["validate", "--root", str(good), "--quick"]) == 0
    out = capsys.readouterr().out
    assert "read    " not in out and "checked the metadata only (--quick): no frame was read" in out


def test_the_schemas_own_dataset_lists_its_scanned_arrays_and_decoded_videos(tiny_dataset, capsys):
    assert main(["validate", "--root", str(tiny_dataset)]) == 0
    out = capsys.readouterr().out
    arrays = "observation.depth.base_camera, observation.intrinsics.base_camera, observation.cam2world.base_camera"
    assert f"read    {arrays}: 72 of 72 frames, every value (arrays in parquet)" in out
    assert "read    observation.images.base_camera: 72 of 72 frames decoded (video, 1 file)" in out


def test_training_on_depth_without_millimetres_names_the_validate_check(storage, tmp_path, capsys, monkeypatch):
    """Depth without a reading is refused as the dataset loads (the default reader holds every frame), naming the
    check that finds the same data before training; read frame by frame, the empty-cloud stop in training points at
    the same check."""
    from lerobot_obsbench import dataset_reads

    root = calibrated_stock_dataset(tmp_path / "koch", video=storage == "video", depth=zero_depth, frames=4)
    with pytest.raises(
        SchemaError, match=r"_depth: every frame's depth is .* no depth was recorded.*obsbench validate"
    ):
        training_setup("obs_act", "pointcloud", root, named="act_pcd", workspace=WORKSPACE)
    monkeypatch.setenv(dataset_reads.READER_ENV, "filtered")
    policy, _, _, dataset = training_setup("obs_act", "pointcloud", root, named="act_pcd", workspace=WORKSPACE)
    adapter = policy.model.observation.adapter.train()  # the policy's observations, as its forward makes them
    batch = policy.calibrated_depth(next(iter(torch.utils.data.DataLoader(dataset, batch_size=len(dataset)))))
    with pytest.raises(SchemaError) as stopped:
        for _ in range(8):  # the stop waits for 64 frames; the dataset has 8
            adapter(batch)
    message = str(stopped.value)
    assert "observation.images.<cam>_depth" in message and "obsbench validate --root DATASET" in message
    assert "refuses depth in which no frame holds valid depth" in message
    assert "no frame holds valid depth" in _refusal(root, capsys)


@pytest.mark.parametrize(("obs_space", "reader"), [("rgb", "memory"), ("rgb", "filtered"), ("pointcloud", "memory")])
def test_training_on_a_truncated_colour_video_names_the_file_and_validate(tmp_path, monkeypatch, obs_space, reader):
    """The plugin's reader decodes the videos once (memory) or per sample (filtered): either way the error names the
    file and `obsbench validate`, not torchcodec's traceback; pointcloud reads the intact depth video beside it."""
    from lerobot.datasets import factory
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    from lerobot_obsbench import dataset_reads
    from lerobot_obsbench.policies import ObsACTConfig

    root = calibrated_stock_dataset(tmp_path / "koch", video=True, episodes=1, frames=8)
    truncate(root / first_video(COLOUR_KEY))
    monkeypatch.setenv(dataset_reads.READER_ENV, reader)
    meta = LeRobotDatasetMetadata("local/stock_depth", root=root)
    query = factory.resolve_delta_timestamps(ObsACTConfig(obs_space=obs_space, device="cpu"), meta)
    with pytest.raises(SchemaError) as refused:
        LeRobotDataset("local/stock_depth", root=root, delta_timestamps=query)[0]
    message = str(refused.value)
    assert "\n" not in message and str(root / first_video(COLOUR_KEY)) in message
    assert f"`obsbench validate --root {root}` decodes every frame" in message
