"""The Hub round trip, offline: push a grid run's checkpoint (obsbench push) and a policy through LeRobot's own
push (the plugin's model card), push a dataset, then pull each in a new process through huggingface_hub's offline
cache resolution; a missing repo with the Hub off is a clear error, not a hang."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from lerobot_obsbench.cli import main
from lerobot_obsbench.stats import per_seed
from tests.support.helpers import first_batch, training_setup
from tests.support.hub_standin import LocalHub
from tests.support.paths import REPO_ROOT

RUN_ID = "0123456789abcdef"
PULL = """
import sys, torch
from lerobot_obsbench.policies.loading import load_policy
policy, pre, post = load_policy(sys.argv[1])
batch = torch.load(sys.argv[2])
torch.manual_seed(0)
torch.save({"type": policy.config.type, "action": policy.select_action(batch)}, sys.argv[3])
"""


def _run(code: str, *args, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code, *map(str, args)],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        cwd=REPO_ROOT,
        timeout=300,
    )


@pytest.fixture(scope="module")
def grid_run(tiny_dataset, tmp_path_factory):
    """A grid output with one trained run (a tiny act_pcd policy saved as lerobot-train saves it) and its test
    evaluations, recorded as `obsbench run` records them; plus a batch and the policy's action on it."""
    out = tmp_path_factory.mktemp("grid")
    policy, pre, post, dataset = training_setup("obs_act", "pointcloud", tiny_dataset, named="act_pcd")
    policy.eval()
    checkpoint = out / "runs" / RUN_ID / "train" / "checkpoints" / "000004" / "pretrained_model"
    policy.save_pretrained(checkpoint)
    pre.save_pretrained(checkpoint)
    post.save_pretrained(checkpoint)
    config = {
        "task": "PushCube-v1",
        "obs_space": "pointcloud",
        "encoder": "pointnet",
        "policy": "act_pcd",
        "batch_size": 4,
        "demos": 6,
        "seed": 1000,
    }
    train = {
        "kind": "train",
        "run_id": RUN_ID,
        "config": config,
        "method": "act_pcd/pointcloud/pointnet",
        "task": "PushCube-v1",
        "train_steps": 4,
        "samples": 16,
        "checkpoint": str(checkpoint),
        "checkpoints": {"4": str(checkpoint)},
    }
    evals = [
        {
            "kind": "eval",
            "eval_id": f"eval{i}",
            "run_id": RUN_ID,
            "split": "test",
            "checkpoint": "last",
            "checkpoint_step": 4,
            "perturbation": p,
            "episodes": 30,
            "successes": s,
            "success_rate": round(s / 30, 4),
            "ci95": ci,
            "per_seed": per_seed(list(range(30)), [i < s for i in range(30)], [50] * 30),
        }
        for i, (p, s, ci) in enumerate((("none", 10, [0.1923, 0.5122]), ("camera_yaw:10", 8, [0.1418, 0.4445])))
    ]
    (out / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in (train, *evals)))
    batch = {k: v for k, v in first_batch(dataset, pre, batch_size=2).items() if k.startswith("observation.")}
    torch.save(batch, out / "batch.pt")
    torch.manual_seed(0)
    with torch.inference_mode():
        action = policy.select_action(batch)
    return SimpleNamespace(out=out, run=out / "runs" / RUN_ID, batch=out / "batch.pt", action=action)


def test_push_a_grid_run_and_pull_it_in_a_new_process(grid_run, tmp_path, monkeypatch, capsys):
    hub = LocalHub(tmp_path / "hub").install(monkeypatch)
    assert main(["push", str(grid_run.run), "me/act-pcd-pushcube"]) == 0
    assert "--policy.path=me/act-pcd-pushcube" in capsys.readouterr().out
    uploaded = hub.uploads[-1]["files"]
    assert sorted(uploaded) == [
        "README.md",
        "config.json",
        "model.safetensors",
        "obsbench_eval.json",
        "policy_postprocessor.json",
        "policy_postprocessor_step_0_unnormalizer_processor.safetensors",
        "policy_preprocessor.json",
        "policy_preprocessor_step_3_normalizer_processor.safetensors",
    ]
    card = (hub.remote("me/act-pcd-pushcube") / "README.md").read_text()
    print(card)  # the closing note quotes it
    for field in (
        "| observation space | `pointcloud` |",
        "| encoder | `pointnet` |",
        "| policy | `act_pcd` (`obs_act`) |",
        "| task | PushCube-v1 |",
        "| dataset | 6 scripted PushCube-v1 demonstrations from `obsbench demos` (not on the Hub) |",
        "| training budget | 4 steps x batch 4 = 16 samples on 6 demonstrations |",
        "| success rate | 10/30 = 0.33 (95% Wilson interval [0.19, 0.51]) |",
        "| evaluation episodes | 30 (seeds 0..29) |",
        "| perturbations (evaluation only) | camera_yaw:10: 8/30 |",
        'pip install "lerobot_policy_obsbench==',
        "lerobot-eval --policy.path=me/act-pcd-pushcube --env.type=obsbench --env.task=PushCube-v1",
        "library_name: lerobot",
    ):
        assert field in card, field
    pulled = _run(PULL, "me/act-pcd-pushcube", grid_run.batch, tmp_path / "pulled.pt", env=hub.env())
    assert pulled.returncode == 0, pulled.stderr[-3000:]
    result = torch.load(tmp_path / "pulled.pt")
    assert result["type"] == "act_pcd"
    assert torch.equal(result["action"], grid_run.action)


def test_lerobot_train_push_writes_the_plugin_card(grid_run, tiny_dataset, tmp_path, monkeypatch):
    """Stock `--policy.push_to_hub=true` calls push_model_to_hub as lerobot-train 0.6.1 does (with the state
    dict and the dataset's metadata): the card is the plugin's and counts the dataset's demonstrations."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    from lerobot_obsbench.policies.loading import load_policy

    hub = LocalHub(tmp_path / "hub").install(monkeypatch)
    policy, _, _ = load_policy(grid_run.run / "train" / "checkpoints" / "000004" / "pretrained_model")
    policy.config.repo_id = "me/from-train"
    train_cfg = SimpleNamespace(
        dataset=SimpleNamespace(repo_id="me/pushcube-demos"),
        env=SimpleNamespace(task="PushCube-v1"),
        steps=4,
        batch_size=4,
        save_pretrained=lambda path: (Path(path) / "train_config.json").write_text("{}"),
    )
    meta = LeRobotDatasetMetadata("local/test", root=tiny_dataset)
    policy.push_model_to_hub(train_cfg, state_dict=policy.state_dict(), dataset_meta=meta)
    card = (hub.remote("me/from-train") / "README.md").read_text()
    budget = f"| training budget | 4 steps x batch 4 on {meta.total_episodes} demonstrations |"
    assert "| observation space | `pointcloud` |" in card and budget in card
    assert "| dataset | me/pushcube-demos |" in card and "datasets:\n- me/pushcube-demos" in card
    assert 'pip install "lerobot_policy_obsbench==' in card


def test_pulling_a_missing_repo_offline_is_a_clear_error(tmp_path):
    hub = LocalHub(tmp_path / "hub")
    pulled = _run(PULL, "me/never-pushed", tmp_path / "b.pt", tmp_path / "a.pt", env=hub.env())
    assert pulled.returncode != 0
    assert "policy me/never-pushed: no local directory of that name, not in the Hugging Face cache" in pulled.stderr
    assert "HF_HUB_OFFLINE=1" in pulled.stderr


def test_push_a_dataset_and_load_it_in_a_new_process(tiny_dataset, tmp_path, monkeypatch):
    import shutil

    root = tmp_path / "demos"
    shutil.copytree(tiny_dataset, root)
    (root / ".obsbench.lock").write_text("obsbench demos (pid 1)\n")  # what a recorder leaves: not uploaded
    hub = LocalHub(tmp_path / "hub").install(monkeypatch)
    assert main(["push-dataset", str(root), "me/tiny-demos"]) == 0
    remote = hub.remote("me/tiny-demos", "dataset")
    files = sorted(str(p.relative_to(remote)) for p in remote.rglob("*") if p.is_file())
    assert "meta/info.json" in files and "README.md" in files
    assert any(f.startswith("data/") for f in files) and any(f.startswith("videos/") for f in files)
    assert ".obsbench.lock" not in files
    load = (
        "import sys\nimport lerobot_obsbench\nfrom huggingface_hub import snapshot_download\n"
        "from lerobot.datasets.lerobot_dataset import LeRobotDataset\n"
        "root = snapshot_download(sys.argv[1], repo_type='dataset')\n"
        "ds = LeRobotDataset(sys.argv[1], root=root)\n"
        "print(ds.meta.total_episodes, ds.meta.total_frames, tuple(ds[0]['observation.depth.base_camera'].shape))\n"
    )
    pulled = _run(load, "me/tiny-demos", env=hub.env())
    assert pulled.returncode == 0, pulled.stderr[-3000:]
    assert pulled.stdout.split() == ["6", "72", "(40,", "40,", "1)"]
