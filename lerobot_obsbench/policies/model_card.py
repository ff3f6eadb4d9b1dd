"""The model card of a pushed checkpoint: what a reader needs to judge and load it.

Written by `obsbench push` (with the grid's evaluation) and by stock `lerobot-train --policy.push_to_hub=true`
(the plugin's policies replace LeRobot's generic card). It names the observation space, encoder, policy, task,
dataset, training budget, the evaluation when known (success rate with its 95% Wilson interval, episodes, seeds,
perturbations), the plugin version, and the install line: LeRobot alone does not know the plugin's types.
"""

from __future__ import annotations

from importlib.metadata import version

DISTRIBUTION = "lerobot_policy_obsbench"


def install_line() -> str:
    return f'pip install "{DISTRIBUTION}=={version(DISTRIBUTION)}"  # brings lerobot=={version("lerobot")}'


def _row(name: str, value) -> str:
    return f"| {name} | {value} |"


def _evaluation_rows(evaluation: dict) -> list[str]:
    low, high = evaluation["ci95"]
    seeds = evaluation.get("seeds") or evaluation.get("per_seed", {}).get("seeds") or []
    seed_text = f"{seeds[0]}..{seeds[-1]}" if seeds else "unknown"
    rows = [
        _row(
            "success rate",
            f"{evaluation['successes']}/{evaluation['episodes']} = {evaluation['success_rate']:.2f} "
            f"(95% Wilson interval [{low:.2f}, {high:.2f}])",
        ),
        _row("evaluation episodes", f"{evaluation['episodes']} (seeds {seed_text})"),
    ]
    if evaluation.get("checkpoint"):
        rows.append(_row("evaluated checkpoint", evaluation["checkpoint"]))
    return rows


def model_card(
    config,
    dataset: str | None = None,
    task: str | None = None,
    training: dict | None = None,
    evaluations: list[dict] | None = None,
    repo_id: str | None = None,
):
    """A `huggingface_hub.ModelCard` for a plugin policy `config`.

    `training`: {"steps", "batch_size", "samples"?, "demos"?}; `evaluations`: the nominal evaluation first, then
    any perturbed ones (records as `obsbench eval` / `obsbench run` write them)."""
    from huggingface_hub import ModelCard, ModelCardData

    base = getattr(config, "base_type", config.type)  # the named types (act_pcd, ...) say what they preset
    data = ModelCardData(
        license="apache-2.0",
        library_name="lerobot",
        pipeline_tag="robotics",
        tags=sorted({"robotics", "lerobot", "obsbench", config.type, base, config.obs_space}),
        datasets=[dataset] if dataset and "/" in dataset and not dataset.startswith(("local/", "/", ".")) else None,
    )
    rows = _card_rows(config, base, dataset, task, training, evaluations or [])
    rows.append(_row("lerobot-obsbench", version(DISTRIBUTION)))
    name = repo_id or "ORG/NAME"
    env = f"--env.type=obsbench --env.task={task}" if task else "--env.type=obsbench --env.task=TASK"
    size = (getattr(config, "camera_resolution", None) or [None])[0]
    body = "\n".join(
        [
            "---",
            data.to_yaml(),
            "---",
            "",
            f"# {config.type} on `{config.obs_space}` observations",
            "",
            (f"`{config.type}` is `{base}` with its observation space fixed. " if base != config.type else "")
            + f'Trained with lerobot-obsbench ({DISTRIBUTION}: OBSBench, "Point Cloud Matters", as a LeRobot '
            "plugin): the observation space is one config field; the dataset and hyper-parameters are shared "
            "with the other spaces it is compared to.",
            "",
            "| | |",
            "|---|---|",
            *rows,
            "",
            "## Load it",
            "",
            "LeRobot alone does not know this policy type; install the plugin first:",
            "",
            "```bash",
            install_line(),
            f"lerobot-eval --policy.path={name} {env}" + (f" --env.image_size={size}" if size else ""),
            f"obsbench eval --policy.path={name} --env.task={task or 'TASK'} --episodes 50",
            "```",
            "",
        ]
    )
    return ModelCard(body)


def _card_rows(config, base: str, dataset, task, training: dict | None, evaluations: list[dict]) -> list[str]:
    """The card's table: what the policy sees and is, its data, its training budget and its evaluations."""
    rows = [
        _row("observation space", f"`{config.obs_space}`"),
        _row("encoder", f"`{config.encoder}`"),
        _row("policy", f"`{config.type}`" + (f" (`{base}`)" if base != config.type else "")),
        _row("cameras", ", ".join(getattr(config, "cameras", []) or []) or "none (blind control)"),
        _row("camera resolution", "x".join(str(v) for v in getattr(config, "camera_resolution", []) or []) or "-"),
        _row("task", task or "unknown"),
        _row("dataset", dataset or "unknown"),
    ]
    if training:
        budget = f"{training['steps']} steps x batch {training['batch_size']}"
        if training.get("samples"):
            budget += f" = {training['samples']} samples"
        if training.get("demos"):
            budget += f" on {training['demos']} demonstrations"
        rows.append(_row("training budget", budget))
    if not evaluations:
        return [*rows, _row("evaluation", "not recorded with this checkpoint")]
    rows += _evaluation_rows(evaluations[0])
    perturbed = [e for e in evaluations[1:] if e.get("perturbation", "none") != "none"]
    if perturbed:
        shown = "; ".join(f"{e['perturbation']}: {e['successes']}/{e['episodes']}" for e in perturbed)
        rows.append(_row("perturbations (evaluation only)", shown))
    return rows


class ModelCardMixin:
    """The plugin's card for stock `lerobot-train --policy.push_to_hub=true` (LeRobot's own card knows neither
    the observation space nor that the plugin must be installed). LeRobot's card also asks the Hub to validate
    it, a network call this card does not make. LeRobot 0.6 passes the training config and the dataset's
    metadata to `generate_model_card`: the card takes the task and budget from the first, the number of
    demonstrations from the second."""

    def generate_model_card(self, dataset_repo_id, model_type, license, tags, cfg=None, dataset_meta=None):
        training = None
        if cfg is not None:
            training = {"steps": cfg.steps, "batch_size": cfg.batch_size}
            if dataset_meta is not None:
                training["demos"] = dataset_meta.total_episodes
        task = getattr(getattr(cfg, "env", None), "task", None)
        return model_card(
            self.config, dataset=dataset_repo_id, task=task, training=training, repo_id=self.config.repo_id
        )
