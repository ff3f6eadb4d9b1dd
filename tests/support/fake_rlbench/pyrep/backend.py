"""Present so that `import pyrep.backend` (what tells PyRep from PyPI's unrelated `pyrep`) succeeds."""
