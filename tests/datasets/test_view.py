"""`obsbench view`: a dataset frame's cameras, clouds, workspace box and world axes, saved to an .rrd file (no
display here) and read back with rerun's own reader (`rerun.experimental.RrdReader`, rerun-sdk 0.33)."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_obsbench.cli import main as obsbench
from lerobot_obsbench.datasets.view import clouds, dataset_frame

WORKSPACE = [-0.5, 0.5, -0.5, 0.5, 0.005, 0.5]


def read_rrd(path) -> dict[str, list]:
    """Every logged column of an .rrd file as "<entity>:<component>" -> its values over the rows."""
    from rerun.experimental import RrdReader

    columns: dict[str, list] = {}
    for chunk in RrdReader(str(path)).store().stream().to_chunks():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            columns.setdefault(f"{chunk.entity_path}:{name}", []).extend(batch.column(name).to_pylist())
    return columns


def column(table, name):
    values = [v for v in table[name] if v is not None]
    assert len(values) == 1, name
    return values[0]


def test_view_logs_what_the_policy_sees(tiny_dataset, tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    out = tmp_path / "frame.rrd"
    args = ["view", "--root", str(tiny_dataset), "--frame", "3", "--out", str(out), "--workspace"]
    assert obsbench([*args, *map(str, WORKSPACE)]) == 0
    table = read_rrd(out)

    frame = dataset_frame(tiny_dataset, 3)
    everything, xyz, _ = clouds(frame, ["base_camera"], WORKSPACE, 0.005)
    logged = np.array(column(table, "/world/points_policy:Points3D:positions"))
    np.testing.assert_allclose(np.sort(logged, axis=0), np.sort(xyz, axis=0), atol=1e-6)
    box = np.array(WORKSPACE).reshape(3, 2)
    assert ((logged >= box[:, 0] - 1e-6) & (logged <= box[:, 1] + 1e-6)).all()
    assert len(column(table, "/world/points_all:Points3D:positions")) == len(everything) > len(logged)
    pose = frame["observation.cam2world.base_camera"]
    translation = column(table, "/world/base_camera:Transform3D:translation")
    np.testing.assert_allclose(np.reshape(translation, 3), pose[:3, 3], atol=1e-6)
    centre = column(table, "/world/workspace:Boxes3D:centers")
    np.testing.assert_allclose(centre[0], box.mean(axis=1))
    assert any(name.startswith("/world/base_camera/image/depth:DepthImage") for name in table)


def test_view_refuses_a_frame_without_depth_cameras():
    from lerobot_obsbench.datasets.view import log_frame

    with pytest.raises(ValueError, match="no camera with depth, intrinsics and cam2world"):
        log_frame({"observation.state": np.zeros(3)}, WORKSPACE)
