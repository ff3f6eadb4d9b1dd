"""Results without the paths of the machine that wrote them: a committed JSON names files relative to the
repository, the home folder as `~`, the temporary folder as `<tmp>` and installed packages as `<site-packages>`
(standard library only: the GPU check imports it before anything is installed)."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# an installed package's folder, from any interpreter (a venv's, the system's, a --target install's)
SITE_PACKAGES = re.compile(r"/[^\s\"']*/(?:site|dist)-packages/")


def portable_text(text: str) -> str:
    """`text` with this machine's absolute folders replaced by the names above (the most specific first)."""
    text = SITE_PACKAGES.sub("<site-packages>/", text)
    for folder, name in ((REPO, ""), (Path(tempfile.gettempdir()), "<tmp>/"), (Path.home(), "~/")):
        text = text.replace(f"{folder}/", name)
    return text


def portable(value):
    """`value` (JSON-like: dicts, lists, strings, numbers) with every string made portable."""
    if isinstance(value, str):
        return portable_text(value)
    if isinstance(value, dict):
        return {key: portable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [portable(item) for item in value]
    return value
