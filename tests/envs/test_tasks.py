"""The task registry: one module per task, each documented in ManiSkill's style (no simulator needed)."""

from __future__ import annotations

import re
import sys

import pytest

from lerobot_obsbench.envs.base_task import TASKS, Task, TaskError, register_task, task_spec
from tests.support.paths import REPO_ROOT

SECTIONS = ("**Task Description:**", "**Randomizations:**", "**Success Conditions:**", "**Expert:**")
TASK_TABLE = (REPO_ROOT / "docs" / "simulation.md").read_text().splitlines()


@pytest.mark.parametrize("name", sorted(TASKS))
def test_every_task_is_one_documented_module(name):
    spec = task_spec(name)
    module = sys.modules[type(spec).__module__]
    assert module.__name__.startswith("lerobot_obsbench.envs.tasks."), "a task lives in its own module"
    doc = module.__doc__ or ""
    # a variant (one Task subclass) lives with its base task and is named on the docstring's first line
    assert re.search(rf"(^|\s){re.escape(name)}[\s.]", doc.partition("\n")[0] + " "), doc[:60]
    for section in SECTIONS:
        assert section in doc, f"{name}: no {section} section"
    if spec.expert is not None:
        assert spec.expert.__module__ == module.__name__, "the expert lives with its task"
        # a measurement, so it lives in the docs' task table, which the docstring points to
        assert "docs/simulation.md#tasks" in doc, f"{name}: the docstring does not point to the expert's success rate"
        row = next((line for line in TASK_TABLE if line.startswith(f"| {name}")), "")
        assert re.search(r"\d+/\d+", row), f"{name}: docs/simulation.md's task table lacks the expert's success rate"
    assert spec.max_steps > 0 and spec.description
    assert all(isinstance(size, int) and size > 0 for size in spec.goal.values())


def test_registry_refuses_duplicates_and_unknown_names():
    class Again(Task):
        name, max_steps, description = "PushCube-v1", 50, "a second PushCube"

    with pytest.raises(ValueError, match="'PushCube-v1' is registered twice"):
        register_task(Again)

    class Loose(Task):
        name, max_steps, description, sub_success = "Loose-v1", 10, "grasps nothing", ("grasp",)

    with pytest.raises(ValueError, match=r"milestones \[.grasp.\] but names no grasped object"):
        register_task(Loose)
    assert "Loose-v1" not in TASKS
    with pytest.raises(TaskError, match="Unknown task 'PickSphere-v1'.*PickCube-v1"):
        task_spec("PickSphere-v1")
    with pytest.raises(NotImplementedError, match="No scripted expert for TurnFaucet-v1.*obsbench import-h5"):
        task_spec("TurnFaucet-v1").make_expert(None)
