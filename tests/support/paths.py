"""Where tests find the checkout and their support files, whatever folder the test module sits in."""

from __future__ import annotations

from pathlib import Path

SUPPORT = Path(__file__).resolve().parent
REPO_ROOT = SUPPORT.parents[1]
# the stand-in `rlbench` and `pyrep` packages (fake_rlbench/README.md)
FAKE_RLBENCH = SUPPORT / "fake_rlbench"
# checkpoints written by older versions of the plugin (data/lerobot044/make_fixtures.py)
DATA = SUPPORT / "data"
