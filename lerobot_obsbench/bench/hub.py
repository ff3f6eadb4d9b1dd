"""`obsbench push`: a trained checkpoint (a grid run, or any `pretrained_model` directory) to the Hugging Face Hub,
with a model card that carries its evaluation; `obsbench push-dataset`: a recorded dataset.

A grid run's card takes the task, dataset, budget and test evaluations (nominal and perturbed) from the grid's
`results.jsonl`; the evaluation records themselves ride along as `obsbench_eval.json`.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

from lerobot_obsbench.bench.results import RESULTS_FILE, by_kind, read_results
from lerobot_obsbench.bench.units import PRETRAINED
from lerobot_obsbench.errors import ObsBenchError

# What a checkpoint upload carries (LeRobot's own push uploads the same kinds of files).
CHECKPOINT_PATTERNS = ["*.safetensors", "*.json", "*.md"]
DATASET_PATTERNS = ["meta/*", "data/*", "videos/*", "images/*", "obsbench_*.json", "README.md"]


class PushError(ObsBenchError, ValueError):
    """The thing to push is not where or what the command expects."""


def _grid_run(run_dir: Path, checkpoint: str) -> tuple[Path, dict, list[dict], str]:
    """(pretrained_model dir, train record, test evaluations of that checkpoint, dataset) of `OUT/runs/<id>`."""
    run_dir = run_dir.resolve()
    out, run_id = run_dir.parent.parent, run_dir.name
    records = read_results(out / RESULTS_FILE)
    trained = {r["run_id"]: r for r in by_kind(records, "train")}
    if run_id not in trained:
        raise PushError(f"{out / RESULTS_FILE} has no finished training of run {run_id}: train it with obsbench run")
    train = trained[run_id]
    tests = [r for r in by_kind(records, "eval") if r["run_id"] == run_id and r["split"] == "test"]
    chosen = checkpoint if any(r["checkpoint"] == checkpoint for r in tests) else "last"
    tests = [r for r in tests if r["checkpoint"] == chosen]
    tests.sort(key=lambda r: r["perturbation"] != "none")  # the nominal evaluation first
    step = next((r.get("checkpoint_step") for r in tests if r.get("checkpoint_step")), None)
    path = Path(train["checkpoints"][str(step)]) if step is not None else Path(train["checkpoint"])
    if not path.is_absolute():
        path = Path.cwd() / path
    config = train["config"]
    dataset = f"{config['demos']} scripted {config['task']} demonstrations from `obsbench demos` (not on the Hub)"
    return path, train, tests, dataset


def push_checkpoint(
    path: Path, repo_id: str, checkpoint: str = "best", private: bool = False, evaluation: Path | None = None
) -> str:
    """Upload a grid run (`OUT/runs/<run_id>`) or a `pretrained_model` directory to `repo_id`; returns its URL."""
    from huggingface_hub import HfApi
    from lerobot.configs.policies import PreTrainedConfig

    from lerobot_obsbench.policies.model_card import model_card

    path = Path(path)
    train, tests, dataset, task, training = None, [], None, None, None
    if (path / "config.json").is_file():
        model_dir = path
        train_config = path / "train_config.json"
        if train_config.is_file():
            saved = json.loads(train_config.read_text())
            dataset = saved.get("dataset", {}).get("repo_id")
            task = (saved.get("env") or {}).get("task")
            training = {"steps": saved.get("steps"), "batch_size": saved.get("batch_size")}
        if evaluation is not None:
            tests = [json.loads(Path(evaluation).read_text())]
            task = task or tests[0].get("task")
    elif (path / "train").is_dir():
        model_dir, train, tests, dataset = _grid_run(path, checkpoint)
        config = train["config"]
        task = config["task"]
        training = {
            "steps": train["train_steps"],
            "batch_size": config["batch_size"],
            "samples": train.get("samples"),
            "demos": config["demos"],
        }
    else:
        raise PushError(
            f"{path} is neither a grid run (OUT/runs/<run_id>) nor a checkpoint (a {PRETRAINED} directory with "
            "config.json)"
        )
    if not (model_dir / "model.safetensors").is_file():
        raise PushError(f"{model_dir} has no model.safetensors: not a finished checkpoint")
    config = PreTrainedConfig.from_pretrained(model_dir)
    api = HfApi()
    repo_id = api.create_repo(repo_id=repo_id, private=private, exist_ok=True).repo_id
    with tempfile.TemporaryDirectory() as tmp:
        staged = Path(tmp) / "checkpoint"
        shutil.copytree(model_dir, staged)
        card = model_card(config, dataset=dataset, task=task, training=training, evaluations=tests, repo_id=repo_id)
        card.save(str(staged / "README.md"))
        if tests:
            (staged / "obsbench_eval.json").write_text(json.dumps(tests, indent=2) + "\n")
        info = api.upload_folder(
            repo_id=repo_id,
            repo_type="model",
            folder_path=staged,
            commit_message=f"Upload {config.type} ({config.obs_space}) checkpoint with its model card",
            allow_patterns=CHECKPOINT_PATTERNS,
        )
    return str(getattr(info, "repo_url", repo_id))


def push_dataset(root: Path, repo_id: str, private: bool = False) -> str:
    """Upload a LeRobotDataset (e.g. recorded by `obsbench demos`) as `repo_id`, with LeRobot's own push."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not (Path(root) / "meta" / "info.json").is_file():
        raise PushError(f"{root} is not a LeRobot dataset (no meta/info.json)")
    dataset = LeRobotDataset(repo_id, root=root)
    # the dataset itself and the recorder's summary; not the output lock or staging leftovers
    dataset.push_to_hub(private=private, allow_patterns=DATASET_PATTERNS)
    return repo_id
