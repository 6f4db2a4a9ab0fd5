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
"""

from __future__ import annotations

import csv
import io
import math
import numbers
import os
import re
import reprlib
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

import numpy as np
import yaml

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


def format_float(x: float) -> str:
    """Shortest text that reads back as exactly ``x`` (Python's ``repr``)."""
    return repr(float(x))


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


# ------------------------------------------------------------------------------------- tables
def read_text(path, *, error: type[InputError] = InputError, missing: str = "an existing file") -> str:
    """The UTF-8 text of a file (a BOM is dropped), or the format's error naming the problem."""
    file = os.fspath(path)
    try:
        with open(file, "rb") as fh:
            raw = fh.read()
    except FileNotFoundError:
        raise error(file, "file", missing, "no such file") from None
    except IsADirectoryError:
        raise error(file, "file", "a file", "a directory") from None
    except OSError as exc:
        raise error(file, "file", "a readable file", exc.strerror or type(exc).__name__) from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise error(file, f"line {line}", "UTF-8 text", "bytes that are not UTF-8 text") from None
    if "\x00" in text:
        line = text[:text.index("\x00")].count("\n") + 1
        raise error(file, f"line {line}", "text", "a NUL byte (binary data)")
    return text


def read_csv_table(path, *, error: type[InputError] = InputError, missing: str = "an existing file",
                   text_columns: Sequence[str] = (), allowed: Sequence[str] | None = None,
                   allowed_text: str | None = None) -> dict[str, np.ndarray]:
    """Columns of a CSV file with a header row of names, comma separated.

    Parameters
    ----------
    path : str or path-like
    error : type
        The format's :class:`~oma.errors.InputError` subclass.
    missing : str
        What the message says was expected when the file does not exist.
    text_columns : sequence of str
        Columns kept as text (``str`` arrays); all others must be numbers (float arrays).
    allowed : sequence of str, optional
        The only column names accepted; another name is an error before any row is parsed.
    allowed_text : str, optional
        The ``expected ...`` text of that error (default: the list of allowed names).

    Returns
    -------
    dict
        ``{name: array}`` in header order; blank lines are skipped.

    Raises
    ------
    InputError (``error``)
        Missing/unreadable/non-UTF-8 file, an empty or repeated header name, a row with a number
        of values other than the header's (line named), a cell that is not a number (line and
        column named). Non-finite numbers (``nan``, ``inf``) are returned for the caller to judge.
    """
    file = os.fspath(path)
    text = read_text(path, error=error, missing=missing)
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise error(file, "header", "a header row of column names", "an empty first line")
    header = [h.strip() for h in next(csv.reader([lines[0]]))]
    for i, h in enumerate(header):
        if not h:
            raise error(file, f"header column {i + 1}", "a column name", "an empty name")
        if header.index(h) != i:
            raise error(file, f"header column {i + 1}", "each column name once", f"{h!r} repeated")
        if allowed is not None and h not in allowed:
            raise error(file, f"column {h}", allowed_text or "only the columns " + ",".join(allowed),
                        f"the unknown column {h!r}")
    ncol = len(header)
    numbered = [(k, line) for k, line in enumerate(lines[1:], start=2) if line.strip()]
    text_idx = [header.index(c) for c in text_columns if c in header]
    if not numbered:
        return {h: (np.empty(0, dtype=str) if i in text_idx else np.empty(0)) for i, h in enumerate(header)}
    values = None
    if not text_idx:
        try:  # fast C parser; on any problem the slow scan below names the line
            values = np.loadtxt(io.StringIO("\n".join(line for _, line in numbered)), delimiter=",",
                                dtype=float, ndmin=2, comments=None)
        except ValueError:
            values = None
        if values is not None and values.shape == (len(numbered), ncol):
            return {h: values[:, i].copy() for i, h in enumerate(header)}
    cells_by_row = []
    for lineno, line in numbered:
        cells = line.split(",")
        if len(cells) != ncol:
            raise error(file, f"line {lineno}", f"{ncol} values (one per header column)",
                        f"{len(cells)} values")
        row = []
        for j, cell in enumerate(cells):
            if j in text_idx:
                row.append(cell.strip())
                continue
            try:
                row.append(float(cell))
            except ValueError:
                raise error(file, f"line {lineno}, column {header[j]}", "a number",
                            describe(cell.strip())) from None
        cells_by_row.append(row)
    out = {}
    for j, h in enumerate(header):
        col = [row[j] for row in cells_by_row]
        out[h] = np.array(col, dtype=str) if j in text_idx else np.array(col, dtype=float)
    return out


def csv_text(columns: Mapping[str, Any]) -> str:
    """CSV text (header row, comma separated, ``\\n`` line ends) of equal-length columns.

    Float columns are written with ``repr`` (shortest text that reads back bit for bit); text
    columns (``str`` arrays or lists of ``str``) as they are.
    """
    names = list(columns)
    cols = []
    for name in names:
        col = columns[name]
        arr = np.asarray(col)
        if arr.dtype.kind in "US":
            cols.append([str(v) for v in arr.tolist()])
        else:
            cols.append(list(map(format_float, np.asarray(arr, dtype=float).tolist())))
    if len({len(c) for c in cols}) > 1:
        raise ValueError("CSV columns have different lengths")
    return ",".join(names) + "\n" + "".join(",".join(row) + "\n" for row in zip(*cols))


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
