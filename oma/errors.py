"""Errors robomill raises on bad input.

Every error about a user's file is an :class:`InputError` (a ``ValueError``) whose message is one
line naming the file, the field, what was expected and what was found. The CLI turns these into
exit code 2 without a traceback.
"""

from __future__ import annotations

import os

__all__ = [
    "InputError",
    "RecordError",
    "ModelError",
    "FRFError",
    "SetupError",
    "ToolpathError",
]


class InputError(ValueError):
    """Bad user input: ``file: field: expected ..., found ...``.

    Parameters
    ----------
    file : str or path-like or None
        The file the problem is in (``None`` for input given in memory).
    field : str
        Dotted path of the offending field, e.g. ``cut.feed_direction`` or ``column Fx``.
    expected : str
        What a valid file has there.
    found : str
        What this file has there.
    """

    def __init__(self, file, field: str, expected: str, found: str):
        self.file = None if file is None else os.fspath(file)
        self.field = field
        self.expected = expected
        self.found = found
        where = self.file if self.file is not None else "<input>"
        super().__init__(f"{where}: {field}: expected {expected}, found {found}")


class RecordError(InputError):
    """A ``robomill-record/1`` directory that cannot be read."""


class ModelError(InputError):
    """A ``robomill-modal/1`` file that cannot be read."""


class FRFError(InputError):
    """An FRF table (CSV, UFF58, ``.frf``) that cannot be read."""


class SetupError(InputError):
    """A ``robomill-setup/1`` file that cannot be read."""


class ToolpathError(InputError):
    """A ``robomill-toolpath/1`` file that cannot be read."""
