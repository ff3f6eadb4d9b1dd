"""Committed results carry no paths of the machine that wrote them (benchmarks/portable.py): files are named
relative to the repository, the home folder as `~`, the temporary folder as `<tmp>`, packages as `<site-packages>`."""

from __future__ import annotations

import json
import re
import tempfile
from pathlib import Path

from benchmarks.portable import REPO, portable, portable_text

# an absolute folder of some machine: a user's or root's home, a temporary folder, a work or CI checkout
MACHINE_PATH = re.compile(r"(?:^|[\s\"'(=:])/(?:tmp|var/tmp|root|home|work|Users)/")


def strings(value):
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for item in value.values():
            yield from strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from strings(item)


def test_a_traceback_is_made_portable():
    home, tmp = Path.home(), Path(tempfile.gettempdir())
    text = (
        f'File "{REPO}/lerobot_obsbench/envs/vector.py", line 3\n'
        f'File "/opt/venv/lib/python3.12/site-packages/torch/nn/module.py", line 9\n'
        f"saved to {tmp}/run123/checkpoint; SAPIEN looks in {home}/.sapien/physx"
    )
    assert portable_text(text) == (
        'File "lerobot_obsbench/envs/vector.py", line 3\n'
        'File "<site-packages>/torch/nn/module.py", line 9\n'
        "saved to <tmp>/run123/checkpoint; SAPIEN looks in ~/.sapien/physx"
    )
    nested = {"rows": [{"code": f"{tmp}/x/lerobot_obsbench", "n": 3}], "ok": True}
    assert portable(nested) == {"rows": [{"code": "<tmp>/x/lerobot_obsbench", "n": 3}], "ok": True}


def test_committed_results_hold_no_machine_paths():
    files = [*(REPO / "benchmarks" / "results").glob("*.json"), *(REPO / "docs" / "results").rglob("*.json")]
    files += list((REPO / "docs" / "results").rglob("*.jsonl"))
    files = [path for path in files if not path.name.startswith(".")]  # a writer's own record, never committed
    assert len(files) > 10
    found = []
    for path in files:
        lines = path.read_text().splitlines() if path.suffix == ".jsonl" else [path.read_text()]
        for line in lines:
            found += [(path.name, s[:120]) for s in strings(json.loads(line)) if MACHINE_PATH.search(s)]
    assert not found, found
