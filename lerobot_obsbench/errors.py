"""The one base of the plugin's own errors.

Every error the plugin raises on purpose (a bad grid, a dataset of another schema, a camera that cannot be
calibrated, ...) subclasses `ObsBenchError` beside the built-in type it always had (ValueError, RuntimeError), so
code catching those keeps working; its message names the field or file and the fix, and `obsbench` prints it as
one line instead of a traceback.
"""

from __future__ import annotations


class ObsBenchError(Exception):
    """An error raised on purpose, with a message that says what is wrong and how to fix it."""


class UsageError(ObsBenchError, ValueError):
    """Command-line arguments that do not fit together (each is valid alone)."""


class ConfigError(ObsBenchError, ValueError):
    """A setting (a config field, a command-line value, a task or encoder declaration) that cannot be used as given."""


class MissingFileError(ObsBenchError, FileNotFoundError):
    """A file or folder the command needs is not there; the message says which command makes it."""


class OutputExistsError(ObsBenchError, FileExistsError):
    """An output folder already holds something this command would overwrite or mix with."""


class MissingDependencyError(ObsBenchError, ImportError):
    """An optional package a feature needs is not installed; the message gives the install command."""


class UnsupportedError(ObsBenchError, NotImplementedError):
    """A combination the plugin does not implement (yet), as opposed to one that is wrong."""
