"""Rules of the code that a linter does not check: a function reads on one screen (80 lines at most), so a longer
one is split where its steps are."""

from __future__ import annotations

import ast

from tests.support.paths import REPO_ROOT

MAX_FUNCTION_LINES = 80


def test_no_function_of_the_package_is_longer_than_a_screen():
    long = []
    for path in sorted((REPO_ROOT / "lerobot_obsbench").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(REPO_ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, long
