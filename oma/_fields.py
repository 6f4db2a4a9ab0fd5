"""Validation helpers shared by every robomill file reader and writer (formats.md).

One idea, used by the record, modal-model, setup and toolpath formats:

- :func:`load_yaml` reads a YAML file with a safe loader (no language-specific tags, no duplicate
  keys, YAML 1.2 numbers so that ``1.2e8`` is a number) and returns a :class:`Fields` cursor over
  the top-level mapping;
- a :class:`Fields` cursor knows its file, the dotted path of its mapping (``cut``,
  ``modes[1]``, ``signals.columns.Fx``) and the error class of the format, so every typed getter
  (:meth:`Fields.number`, :meth:`Fields.integer`, :meth:`Fields.direction` ...) fails with one
  message ``file: field: expected ..., found ...``; :meth:`Fields.done` rejects keys nobody asked
  for unless they start with ``x_`` (user extensions);
- the ``tool``, ``cut``, ``material``, ``sensors`` and ``limits`` sections, read and dumped the
  same way wherever they occur, are in :mod:`oma._sections`;
- :class:`UnitScale`, the one place where file units become SI and back, chosen so that a value
  read from a file is written back as the same number (see :meth:`UnitScale.from_si`).

YAML and units are here; the cursor and value checks are in :mod:`oma._fields_checks`, text and CSV
tables in :mod:`oma._fields_tables`, and every name is imported from this module.
"""

from __future__ import annotations

import math
import numbers
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml

from ._fields_checks import DIRECTION_LENGTH_TOLERANCE, PERPENDICULAR_TOLERANCE  # noqa: F401 (re-exported)
from ._fields_checks import Fields, FileWarning, check_direction, check_number, check_vector, describe, warn_user
from ._fields_tables import csv_text, format_float, read_csv_table, read_text
from .errors import InputError

__all__ = [
    "DEG_TO_RAD",
    "STANDARD_GRAVITY_M_S2",
    "FileWarning",
    "Fields",
    "UnitScale",
    "describe",
    "load_yaml",
    "dump_yaml",
    "plain",
    "format_float",
    "read_text",
    "read_csv_table",
    "csv_text",
    "check_number",
    "check_vector",
    "check_direction",
    "warn_user",
]

#: Degrees to radians: ``rad = deg * DEG_TO_RAD`` (the one conversion used by every reader).
DEG_TO_RAD = math.pi / 180.0
#: Standard acceleration of gravity (3rd CGPM, 1901), m/s^2: the file unit ``g``.
STANDARD_GRAVITY_M_S2 = 9.80665


# ----------------------------------------------------------------------------------------- YAML
class _TagRejected(Exception):
    def __init__(self, tag: str, mark):
        super().__init__(tag)
        self.tag, self.mark = tag, mark


class _DuplicateKey(Exception):
    def __init__(self, key, mark):
        super().__init__(key)
        self.key, self.mark = key, mark


# YAML 1.2 core-schema numbers: ``1.2e8`` and ``2e8`` are floats (YAML 1.1, PyYAML's default,
# reads them as strings), ``010`` is ten (not octal eight), ``yes``/``no``/dates stay text.
_FLOAT_RE = re.compile(
    r"""^(?:[-+]?[0-9][0-9_]*\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
    |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""",
    re.X,
)
_INT_RE = re.compile(r"^[-+]?[0-9][0-9_]*$")
_BOOL_RE = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$")
_NULL_RE = re.compile(r"^(?:~|null|Null|NULL|)$")


class _Loader(yaml.SafeLoader):
    """``yaml.SafeLoader`` with YAML 1.2 scalars, no unknown tags and no duplicate keys."""

    yaml_implicit_resolvers: dict = {}

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                if key in seen:
                    raise _DuplicateKey(key, key_node.start_mark)
                seen.add(key)
            except TypeError:  # unhashable key: the base class reports it
                pass
        return super().construct_mapping(node, deep=deep)

    def _construct_int(self, node):
        return int(self.construct_scalar(node).replace("_", ""), 10)

    def _construct_float(self, node):
        text = self.construct_scalar(node).replace("_", "").lower()
        if text.endswith("nan"):
            return math.nan
        if text.endswith("inf"):
            return -math.inf if text.startswith("-") else math.inf
        return float(text)

    def _reject_tag(self, node):
        raise _TagRejected(node.tag, node.start_mark)


for _first, _regex, _tag in (
    ("-+0123456789.", _FLOAT_RE, "tag:yaml.org,2002:float"),
    ("-+0123456789", _INT_RE, "tag:yaml.org,2002:int"),
    ("tTfF", _BOOL_RE, "tag:yaml.org,2002:bool"),
    (["~", "n", "N", ""], _NULL_RE, "tag:yaml.org,2002:null"),
    ("<", re.compile(r"^(?:<<)$"), "tag:yaml.org,2002:merge"),
):
    _Loader.add_implicit_resolver(_tag, _regex, list(_first))
_Loader.add_constructor("tag:yaml.org,2002:int", _Loader._construct_int)
_Loader.add_constructor("tag:yaml.org,2002:float", _Loader._construct_float)
_Loader.add_constructor(None, _Loader._reject_tag)


def _line(mark) -> str:
    return f"line {mark.line + 1}" if mark is not None else "YAML"


def load_yaml(path, *, error: type[InputError] = InputError) -> "Fields":
    """Read a YAML file safely and return a cursor over its top-level mapping.

    Parameters
    ----------
    path : str or path-like
        The YAML file.
    error : type
        The :class:`~oma.errors.InputError` subclass of the format (``RecordError`` ...).

    Returns
    -------
    Fields

    Raises
    ------
    InputError (the given subclass)
        The file is missing or unreadable, is not valid YAML, uses a tag other than the standard
        ones (``!!python/object...`` and any other language-specific or local tag are refused,
        never constructed), repeats a key, or is not a mapping.
    """
    file = os.fspath(path)
    try:
        with open(file, "rb") as fh:
            raw = fh.read()
    except FileNotFoundError:
        raise error(file, "file", "an existing file", "no such file") from None
    except IsADirectoryError:
        raise error(file, "file", "a YAML file", "a directory") from None
    except OSError as exc:
        raise error(file, "file", "a readable file", exc.strerror or type(exc).__name__) from None
    try:
        doc = yaml.load(raw, Loader=_Loader)  # noqa: S506 - _Loader is a SafeLoader subclass
    except _TagRejected as exc:
        raise error(file, _line(exc.mark), "plain YAML without language-specific tags",
                    f"the tag {exc.tag} (not allowed)") from None
    except _DuplicateKey as exc:
        raise error(file, _line(exc.mark), "each key once per mapping",
                    f"the key {exc.key!r} repeated") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = str(exc.problem or exc.context).strip()
        raise error(file, _line(mark), "valid YAML", problem.removeprefix("found ")) from None
    except yaml.YAMLError as exc:  # ReaderError (bad bytes) and the like
        raise error(file, "YAML", "valid UTF-8 YAML text", str(exc).splitlines()[0][:120]) from None
    except RecursionError:
        raise error(file, "YAML", "valid YAML", "nesting too deep to read") from None
    except ValueError as exc:  # e.g. an integer with more digits than Python converts
        raise error(file, "YAML", "valid YAML", str(exc)[:120]) from None
    if doc is None:
        raise error(file, "document", "a YAML mapping", "an empty document")
    if not isinstance(doc, dict):
        raise error(file, "document", "a YAML mapping (key: value lines)", describe(doc))
    return Fields(doc, file=file, error=error)


class _Dumper(yaml.SafeDumper):
    """``yaml.SafeDumper`` that never writes aliases (plain, readable output)."""

    def ignore_aliases(self, data):
        return True


def plain(obj: Any) -> Any:
    """``obj`` with NumPy arrays/scalars and tuples turned into plain lists, floats and ints."""
    if isinstance(obj, Mapping):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, numbers.Integral):
        return int(obj)
    if isinstance(obj, numbers.Real):
        return float(obj)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def dump_yaml(mapping: Mapping) -> str:
    """YAML text of a mapping: keys in the given order, short lists inline, floats with full
    precision (``repr``, so every float reads back bit for bit)."""
    return yaml.dump(plain(mapping), Dumper=_Dumper, sort_keys=False, default_flow_style=None,
                     allow_unicode=True, width=100)



# -------------------------------------------------------------------------------------- units
@dataclass(frozen=True)
class UnitScale:
    """Conversion of one file unit to SI: ``si = value * multiplier`` or ``si = value / divisor``.

    At most one of the two differs from 1, so each conversion rounds once; ``um`` divides by the
    exact ``1e6`` rather than multiplying by the inexact ``1e-6``.
    """

    multiplier: float = 1.0
    divisor: float = 1.0

    def __post_init__(self):
        if self.multiplier != 1.0 and self.divisor != 1.0:
            raise ValueError("a UnitScale has a multiplier or a divisor, not both")

    def to_si(self, values):
        """File values to SI (array or float)."""
        v = np.asarray(values, dtype=float)
        if self.divisor != 1.0:
            return v / self.divisor
        if self.multiplier != 1.0:
            return v * self.multiplier
        return v

    def from_si(self, si):
        """SI values to file values that :meth:`to_si` maps back onto exactly the same doubles.

        Floating-point scaling does not invert exactly (``(x / s) * s != x`` for a few per cent of
        doubles), so for each value this tries, in order, the 15- and 16-significant-digit
        rounding of ``x / s`` (which recovers the file's own number when the file gave it with up
        to 15 digits, so a read-then-written file is textually unchanged), ``x / s`` itself and
        the doubles up to two units in the last place either side, and keeps the first that maps
        back to ``x``. A value read from a file always has such a preimage (the file's number);
        an arbitrary double may have none (about 4 % for um, 13 % for g), and then gets ``x / s``,
        which reads back one unit in the last place away.
        """
        x = np.asarray(si, dtype=float)
        if self.multiplier == 1.0 and self.divisor == 1.0:
            return x.copy()
        w = x * self.divisor if self.divisor != 1.0 else x / self.multiplier
        flat_x, flat_w = x.ravel(), w.ravel()
        out = flat_w.copy()
        done = ~np.isfinite(flat_x)
        for make in (
            lambda v: np.array([float(f"{t:.15g}") for t in v]),
            lambda v: np.array([float(f"{t:.16g}") for t in v]),
            lambda v: v,
            lambda v: np.nextafter(v, np.inf),
            lambda v: np.nextafter(v, -np.inf),
            lambda v: np.nextafter(np.nextafter(v, np.inf), np.inf),
            lambda v: np.nextafter(np.nextafter(v, -np.inf), -np.inf),
        ):
            todo = np.flatnonzero(~done)
            if todo.size == 0:
                break
            cand = make(flat_w[todo])
            ok = self.to_si(cand) == flat_x[todo]
            out[todo[ok]] = cand[ok]
            done[todo[ok]] = True
        return out.reshape(x.shape)
