"""An RLBench grid end to end (slow), against the replaying stand-in for RLBench and PyRep in
tests/support/fake_rlbench: PerAct-format data imported as the demonstrations, stock lerobot-train, the evaluation
protocol on the test split (nominal and a camera-view change), the report beside the paper's RLBench rows;
killed and resumed."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from lerobot_obsbench.bench.results import by_kind
from lerobot_obsbench.cli import main
from tests.support import rlbench_fixtures
from tests.support.grid_cli import ENV, finish, quiet
from tests.support.paths import FAKE_RLBENCH

pytestmark = pytest.mark.slow
GRID = """
name: rlbench-tiny
tasks: [rlbench/open_drawer]
rlbench_data: {data}
obs_spaces: [pointcloud]
policies: [obs_act]
preset: tiny
seeds: [7]
learning_rates: [1.0e-3]
demos: [2]
batch_size: 4
steps: 3
checkpoints: 1
validation_episodes: 2
eval_episodes: 2
episode_length: 3
perturbations: [camera_yaw:5]
"""


@pytest.fixture(scope="module")
def rlbench_grid(
    tmp_path_factory,
) -> tuple[Path, dict]:
    """PerAct-style data (train: 3 episodes, val and test: 2), the grid file and the environment the stand-in needs."""
    from scripts import make_synthetic_dataset as synthetic

    root = tmp_path_factory.mktemp("rlbench_grid")
    rlbench_fixtures.write_task(root / "data" / "train" / "open_drawer", synthetic, "variations", episodes=3)
    rlbench_fixtures.write_task(root / "data" / "test" / "open_drawer", synthetic, "all_variations", episodes=2)
    rlbench_fixtures.write_task(root / "data" / "val" / "open_drawer", synthetic, "variations", episodes=2)
    (root / "coppeliasim").mkdir()
    (root / "grid.yaml").write_text(GRID.format(data=root / "data"))
    path = os.pathsep.join(p for p in (str(FAKE_RLBENCH), os.environ.get("PYTHONPATH")) if p)
    env = {**ENV, "PYTHONPATH": path, "COPPELIASIM_ROOT": str(root / "coppeliasim"), "DISPLAY": ":99"}
    return root, env


def test_an_rlbench_grid_imports_trains_evaluates_and_reports(rlbench_grid, tmp_path, capsys):
    root, env = rlbench_grid
    grid, plain = str(root / "grid.yaml"), tmp_path / "plain"
    finish("run", grid, "--out", str(plain), "--threads", "1", env=env)
    records = quiet(plain / "results.jsonl")
    (train,) = by_kind(records, "train")
    assert train["task"] == "rlbench/open_drawer" and train["config"]["cameras"] == ["front"]
    (validation,) = [r for r in by_kind(records, "eval") if r["split"] == "validation"]
    assert validation["checkpoint"] == "step:3" and validation["per_seed"]["seeds"] == [0, 1]  # the val split's
    evals = {
        r["perturbation"]: r for r in by_kind(records, "eval") if r["split"] == "test" and r["checkpoint"] == "last"
    }
    assert set(evals) == {"none", "camera_yaw:5"}
    for record in evals.values():
        assert record["episodes"] == 2 and record["max_steps"] == 3 and record["split"] == "test"
        assert record["per_seed"]["seeds"] == [0, 1]  # the test split's episodes, in order
        assert all(1 <= length <= 3 for length in record["per_seed"]["length"])
    dataset = next((plain / "demos").iterdir())
    assert (dataset / "obsbench_import.json").is_file()  # imported from the train split, not recorded

    # (a grid killed and resumed: tests/bench; it goes the same way for RLBench's tasks)
    assert main(["report", str(plain / "results.jsonl"), "--table", "table2_dp", "--out", str(tmp_path / "rep")]) == 0
    shown = capsys.readouterr().out
    assert "rlbench/open_drawer" in shown
    markdown = (tmp_path / "rep" / "report.md").read_text()
    assert "Side by side on the shared rows (open drawer)" in markdown and "PCD-PointNet (table2_dp)" in markdown
