"""The paper's tables shipped with the plugin (typed from its LaTeX source) reproduce the paper's summary rows
through `obsbench report --table`, in the paper's own column order."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from lerobot_obsbench.bench.report import published_tables, read_published, resolve_table, summarize
from lerobot_obsbench.cli import main
from tests.support.paths import REPO_ROOT

# The project's reference folder (the paper's LaTeX source and tables): OBSBENCH_SHARED names it, and then it must
# be there (CI sets it, so this comparison never skips there); else ../shared beside the checkout, if present.
SHARED_DIR = Path(os.environ.get("OBSBENCH_SHARED") or REPO_ROOT.parent / "shared")
SHARED = SHARED_DIR / "paper" / "table2_dp.csv"
TABLE2_DP = {  # published Mean S.R. and Mean Rank (Table 2, Diffusion Policy, trained from scratch)
    "RGB-ResNet": (0.13, 3.37),
    "RGB-ViT": (0.08, 4.47),
    "RGBD-ResNet": (0.23, 2.37),
    "RGBD-ViT": (0.13, 4.00),
    "RGBD-MultiViT": (0.06, 4.21),
    "PCD-SpUNet": (0.20, 2.42),
    "PCD-PointNet": (0.23, 1.89),
}


def test_table2_dp_mean_sr_exactly_and_mean_rank_as_close_as_the_rounding_allows(tmp_path, capsys):
    assert main(["report", "--table", "table2_dp", "--json", str(tmp_path / "s.json"), "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "s.json").read_text())["published"]
    assert list(summary) == list(TABLE2_DP)  # the published column order, not re-sorted
    for method, (mean_sr, mean_rank) in TABLE2_DP.items():
        assert round(summary[method]["mean_sr"], 2) == mean_sr, method
        # ranks from the rounded rates: ties the rounding created (e.g. 0.01 on PegInsert) share a rank that the
        # paper's unrounded rates split, so our Mean Rank is lower by up to 0.21 (PCD-SpUNet), never higher
        assert mean_rank - 0.22 < summary[method]["mean_rank"] <= mean_rank + 0.005, method
    md = (tmp_path / "report.md").read_text()
    assert "| task | RGB-ResNet | RGB-ViT | RGBD-ResNet | RGBD-ViT | RGBD-MultiViT | PCD-SpUNet | PCD-PointNet |" in md


def test_packaged_table2_is_the_shared_one():
    if not SHARED.is_file():
        assert "OBSBENCH_SHARED" not in os.environ, f"OBSBENCH_SHARED is set but {SHARED} does not exist"
        pytest.skip("../shared/paper is not beside this checkout (set OBSBENCH_SHARED to require it)")
    assert Path(resolve_table("table2_dp")).read_text() == SHARED.read_text()


# Printed summaries against the mean of the printed (rounded) rows: within 0.01, except Table 3, whose printed
# Mean S.R. for R3M / VC-1 / MultiMAE (0.32 / 0.34 / 0.33) lie 0.01-0.02 below the mean of its own rows
# (0.336 / 0.348 / 0.345).
PRINTED = [
    ("table3_pvr_act", 0.02, {"R3M": 0.32, "VC-1": 0.34, "MultiMAE": 0.33, "PonderV2": 0.43}),
    (
        "table4_camera_view",
        0.01,
        {
            "ResNet": 0.18,
            "ViT-B": 0.09,
            "MultiViT": 0.10,
            "SpUNet": 0.21,
            "PointNet": 0.40,
            "R3M": 0.16,
            "VC-1": 0.14,
            "MultiMAE": 0.19,
            "PonderV2": 0.25,
        },
    ),
    (
        "table_design_decisions",
        0.01,
        {
            "ACT SpUNet pre xyz": 0.25,
            "ACT SpUNet post rgb+xyz": 0.41,
            "ACT PointNet post rgb+xyz": 0.45,
            "ACT pointmap ResNet": 0.43,
            "DP PointNet pre rgb": 0.16,
            "DP PointNet post rgb+xyz": 0.45,
            "DP pointmap ViT": 0.17,
        },
    ),
]


@pytest.mark.parametrize("name,tolerance,expected", PRINTED)
def test_paper_tables_reproduce_their_published_means(name, tolerance, expected):
    summary = summarize(read_published(resolve_table(name)))
    for method, mean_sr in expected.items():
        assert abs(summary[method]["mean_sr"] - mean_sr) <= tolerance + 1e-9, method


def test_every_packaged_table_reads():
    assert set(published_tables()) == {
        "table2_dp",
        "table3_pvr_act",
        "table4_camera_view",
        "table5_sample_efficiency",
        "table_design_decisions",
        "table_visual_changes",
    }
    for name in published_tables():
        table = read_published(resolve_table(name))
        assert table and all(0 <= v <= 1 for row in table.values() for v in row.values())
    # the camera and visual-change rows are named like the grids' perturbations
    assert list(read_published(resolve_table("table4_camera_view"))) == [
        "camera_pitch:5",
        "camera_pitch:10",
        "camera_yaw:5",
        "camera_yaw:10",
    ]
    assert "background:0.2,0,0" in read_published(resolve_table("table_visual_changes"))
