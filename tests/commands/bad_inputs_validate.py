"""Rows of the bad-input table (`tests/commands/test_bad_inputs.py`) for validate: each `(setup, fragments)`, where
`setup(root) -> argv` builds its inputs in a fresh folder and `fragments` are what the one error line must hold."""

from __future__ import annotations

ROWS: list = []
