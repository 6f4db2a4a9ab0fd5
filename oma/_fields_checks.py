"""The :class:`Fields` cursor over one YAML mapping of a file and the value checks behind its
getters, with the ``file: field: expected ..., found ...`` message text (:func:`describe`) and
:class:`FileWarning` (formats.md).

Private module: every name is imported from :mod:`oma._fields`.
"""

from __future__ import annotations

import math
import numbers
import os
import reprlib
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NoReturn

import numpy as np

from .errors import InputError

__all__ = [
    "DIRECTION_LENGTH_TOLERANCE",
    "PERPENDICULAR_TOLERANCE",
    "FileWarning",
    "Fields",
    "describe",
    "check_number",
    "check_vector",
    "check_direction",
    "warn_user",
]

#: Tolerance on a direction vector's length before normalising it warns (formats.md: 1 %).
DIRECTION_LENGTH_TOLERANCE = 0.01
#: Largest ``|f . n|`` of the normalised feed and normal directions (formats.md).
PERPENDICULAR_TOLERANCE = 1e-3


class FileWarning(UserWarning):
    """A file was read, but something in it was adjusted (e.g. a direction normalised)."""


# ------------------------------------------------------------------------------------ messages
# Bounded repr: a hostile file (YAML aliases nest lists exponentially) never makes a message big.
_REPR = reprlib.Repr()
_REPR.maxlist, _REPR.maxlevel, _REPR.maxstring, _REPR.maxother = 6, 3, 30, 30

def describe(value: Any, *, limit: int = 60) -> str:
    """Short text for the ``found ...`` part of a message: the value and, if unclear, its type."""
    if isinstance(value, np.generic):
        value = value.item()
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"{str(value).lower()} (a boolean)"
    if isinstance(value, str):
        text = repr(value)
        return f"the text {text[:limit] + '...' if len(text) > limit else text}"
    if isinstance(value, numbers.Number):
        return repr(value)
    if isinstance(value, Mapping):
        keys = ", ".join(str(k) for k in list(value)[:5])
        return f"a mapping ({keys}{', ...' if len(value) > 5 else ''})"
    if isinstance(value, (list, tuple, np.ndarray)):
        text = _REPR.repr(value.tolist() if isinstance(value, np.ndarray) else list(value))
        text = text[:limit] + "..." if len(text) > limit else text
        return f"a list of {len(value)} {text}"
    return f"a {type(value).__name__}"


# ------------------------------------------------------------------------------------- cursor
_MISSING = object()


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _bounds_text(gt=None, ge=None, lt=None, le=None) -> str:
    parts = []
    if gt is not None:
        parts.append(f"> {gt:g}")
    if ge is not None:
        parts.append(f">= {ge:g}")
    if lt is not None:
        parts.append(f"< {lt:g}")
    if le is not None:
        parts.append(f"<= {le:g}")
    return " and ".join(parts)


def check_number(value, fail: Callable[[str, str], NoReturn], *, gt=None, ge=None, lt=None,
                 le=None, what: str = "a number") -> float:
    """``value`` as a finite float within the bounds, else ``fail(expected, found)``."""
    bounds = _bounds_text(gt, ge, lt, le)
    expected = f"{what} {bounds}".strip()
    if not _is_number(value):
        fail(expected, describe(value))
    try:
        x = float(value)
    except OverflowError:  # an integer too large for a double
        x = math.inf
    if not math.isfinite(x):
        fail(f"a finite {what.removeprefix('a ')} {bounds}".strip(), repr(x))
    if (gt is not None and not x > gt) or (ge is not None and not x >= ge) or (
            lt is not None and not x < lt) or (le is not None and not x <= le):
        fail(expected, describe(value))
    return x


class Fields:
    """A cursor over one YAML mapping of a file.

    Parameters
    ----------
    mapping : dict
        The mapping.
    file : str or None
        The file it came from (``None`` for a mapping given in memory).
    error : type
        The :class:`~oma.errors.InputError` subclass raised on a bad value.
    path : str, optional
        Dotted path of this mapping in the file (``""`` for the top level).

    Notes
    -----
    Every getter records the key it was asked for; :meth:`done` then rejects any other key that
    does not start with ``x_`` (formats.md: a misspelt key never passes silently).
    """

    def __init__(self, mapping: Mapping, *, file, error: type[InputError] = InputError, path: str = ""):
        self.mapping = mapping
        self.file = None if file is None else os.fspath(file)
        self.error = error
        self.path = path
        self._asked: list[str] = []

    # ------------------------------------------------------------------------- basics
    def where(self, key: str | int | None = None) -> str:
        """Dotted path of ``key`` in this mapping (``cut.milling``, ``modes[0]``)."""
        if key is None:
            return self.path or "document"
        if isinstance(key, int):
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else str(key)

    def fail(self, key, expected: str, found: str) -> NoReturn:
        """Raise the format's error for ``key``."""
        raise self.error(self.file, self.where(key), expected, found)

    def failer(self, key) -> Callable[[str, str], NoReturn]:
        """A ``fail(expected, found)`` callable bound to ``key``."""
        return lambda expected, found: self.fail(key, expected, found)

    def has(self, key: str) -> bool:
        return key in self.mapping

    def raw(self, key: str, *, required: bool = True, expected: str = "a value"):
        """The value at ``key`` as loaded (``_MISSING`` sentinel handled by callers via ``has``)."""
        if key not in self._asked:
            self._asked.append(key)
        if key not in self.mapping:
            if required:
                self.fail(key, expected, "nothing (the key is missing)")
            return _MISSING
        return self.mapping[key]

    def child(self, value, path: str) -> "Fields":
        """A cursor over a nested mapping ``value`` found at ``path`` (already checked)."""
        return Fields(value, file=self.file, error=self.error, path=path)

    def done(self) -> None:
        """Reject keys no getter asked for, unless they start with ``x_`` (user extensions)."""
        for key in self.mapping:
            if isinstance(key, str) and (key in self._asked or key.startswith("x_")):
                continue
            known = ", ".join(self._asked)
            self.fail(str(key), f"one of the keys {known} or an x_ extension" if known else
                      "no keys here (or x_ extensions)", f"the unknown key {str(key)!r}")

    # ------------------------------------------------------------------------- typed getters
    def format(self, expected: str) -> None:
        """Check the ``format:`` string (``robomill-record/1`` ...)."""
        value = self.raw("format", expected=f"format: {expected}")
        if value != expected:
            self.fail("format", f"'{expected}'", describe(value))

    def number(self, key: str, *, required: bool = True, default=None, gt=None, ge=None, lt=None,
               le=None) -> float | None:
        """A finite number within the given bounds."""
        bounds = _bounds_text(gt, ge, lt, le)
        value = self.raw(key, required=required, expected=f"a number {bounds}".strip())
        if value is _MISSING:
            return default
        return check_number(value, self.failer(key), gt=gt, ge=ge, lt=lt, le=le)

    def positive(self, key: str, *, required: bool = True, default=None) -> float | None:
        """A finite number > 0 (a physical size, rate, stiffness ...)."""
        return self.number(key, required=required, default=default, gt=0)

    def integer(self, key: str, *, required: bool = True, default=None, ge=None) -> int | None:
        """An integer (an integral float such as ``2.0`` is accepted, ``2.5`` is not)."""
        expected = f"an integer {_bounds_text(ge=ge)}".strip()
        value = self.raw(key, required=required, expected=expected)
        if value is _MISSING:
            return default
        if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)):
            n = int(value)
        elif _is_number(value) and math.isfinite(float(value)) and float(value).is_integer():
            n = int(value)
        else:
            self.fail(key, expected, describe(value))
        if ge is not None and n < ge:
            self.fail(key, expected, describe(value))
        return n

    def text(self, key: str, *, required: bool = False, default=None) -> str | None:
        """A string."""
        value = self.raw(key, required=required, expected="a text")
        if value is _MISSING:
            return default
        if not isinstance(value, str):
            self.fail(key, "a text", describe(value))
        return value

    def choice(self, key: str, choices: Sequence[str], *, required: bool = True, default=None):
        """One of the strings ``choices``."""
        expected = "one of " + ", ".join(choices)
        value = self.raw(key, required=required, expected=expected)
        if value is _MISSING:
            return default
        if not isinstance(value, str) or value not in choices:
            self.fail(key, expected, describe(value))
        return value

    def vector(self, key: str, n: int, *, required: bool = True, default=None, what: str = "numbers"):
        """A list of ``n`` finite numbers, as a float array."""
        expected = f"a list of {n} {what}"
        value = self.raw(key, required=required, expected=expected)
        if value is _MISSING:
            return default
        return check_vector(value, n, self.failer(key), what=what)

    def direction(self, key: str, *, required: bool = True):
        """A non-zero 3-vector, normalised; warns (:class:`FileWarning`) when its length is off
        1 by more than 1 %."""
        value = self.vector(key, 3, required=required)
        if value is None:
            return None
        return check_direction(value, self.failer(key), where=self._where_text(key))

    def matrix(self, key: str, shape: tuple[int, int], *, required: bool = True, default=None):
        """A list of ``shape[0]`` lists of ``shape[1]`` finite numbers."""
        rows, cols = shape
        expected = f"a {rows}x{cols} matrix (a list of {rows} lists of {cols} numbers)"
        value = self.raw(key, required=required, expected=expected)
        if value is _MISSING:
            return default
        if isinstance(value, np.ndarray):
            value = value.tolist()
        if not isinstance(value, (list, tuple)) or len(value) != rows or any(
                not isinstance(r, (list, tuple, np.ndarray)) or len(r) != cols for r in value):
            self.fail(key, expected, describe(value))
        out = np.empty(shape)
        for i, row in enumerate(value):
            for j, x in enumerate(row):
                out[i, j] = check_number(x, lambda e, f, i=i, j=j: self.fail(
                    key, f"{expected} with finite entries", f"{f} at row {i + 1}, column {j + 1}"))
        return out

    def span(self, key: str, *, required: bool = False, gt=None, ge=None):
        """A ``[low, high]`` pair of finite numbers with ``low <= high`` (a range of a limit)."""
        value = self.vector(key, 2, required=required)
        if value is None:
            return None
        bounds = _bounds_text(gt=gt, ge=ge)
        for x in value:
            check_number(float(x), lambda e, f: self.fail(key, f"[low, high] with both {bounds}", f),
                         gt=gt, ge=ge)
        if not value[0] <= value[1]:
            self.fail(key, "[low, high] with low <= high", describe(value.tolist()))
        return float(value[0]), float(value[1])

    def mapping_at(self, key: str, *, required: bool = False) -> "Fields | None":
        """A cursor over the nested mapping at ``key`` (``None`` when absent and optional)."""
        value = self.raw(key, required=required, expected="a mapping")
        if value is _MISSING:
            return None
        if not isinstance(value, Mapping):
            self.fail(key, "a mapping (key: value pairs)", describe(value))
        return self.child(value, self.where(key))

    def sequence(self, key: str, *, required: bool = True, min_len: int = 0) -> list | None:
        """A list (items returned as loaded)."""
        expected = "a list" if min_len == 0 else f"a list of at least {min_len}"
        value = self.raw(key, required=required, expected=expected)
        if value is _MISSING:
            return None
        if not isinstance(value, (list, tuple)) or len(value) < min_len:
            self.fail(key, expected, describe(value))
        return list(value)

    def _where_text(self, key) -> str:
        return f"{self.file or '<input>'}: {self.where(key)}"


def check_vector(value, n: int, fail: Callable[[str, str], NoReturn], *, what: str = "numbers"):
    """``value`` as an array of ``n`` finite floats, else ``fail(expected, found)``."""
    expected = f"a list of {n} {what}"
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or len(value) != n:
        fail(expected, describe(value))
    out = np.empty(n)
    for i, x in enumerate(value):
        out[i] = check_number(x, lambda e, f: fail(f"a list of {n} finite numbers", describe(value)))
    return out


_OWN_PACKAGES = ("oma", "stability", "planner")


def warn_user(message: str, category: type[Warning] = None) -> None:
    """``warnings.warn`` attributed to the first caller outside robomill's packages (the line of
    user code that called the reader), whatever the depth of the reader's helpers."""
    level, frame = 2, sys._getframe(1)  # stacklevel 2 is the caller of warn_user
    while frame is not None and frame.f_globals.get("__name__", "").split(".")[0] in _OWN_PACKAGES:
        frame = frame.f_back
        level += 1
    warnings.warn(message, category or FileWarning, stacklevel=level)


def check_direction(vector, fail: Callable[[str, str], NoReturn], *, where: str) -> np.ndarray:
    """A non-zero 3-vector made unit length; :class:`FileWarning` when it was off by > 1 %."""
    length = float(np.linalg.norm(vector))
    if length == 0.0 or not math.isfinite(length):
        fail("a non-zero direction vector", describe(np.asarray(vector).tolist()))
    if abs(length - 1.0) > DIRECTION_LENGTH_TOLERANCE:
        warn_user(f"{where}: direction has length {length:.6g}, normalised to 1")
    if abs(length - 1.0) <= 4 * np.finfo(float).eps:
        return np.array(vector, dtype=float)  # already unit: keep the exact numbers
    return np.asarray(vector, dtype=float) / length
