"""Text and CSV tables of robomill's file formats: a checked UTF-8 read, CSV columns with a
header row (errors naming line and column), and CSV text whose floats read back bit for bit.

Private module: every name is imported from :mod:`oma._fields`.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ._fields_checks import describe
from .errors import InputError

__all__ = ["format_float", "read_text", "read_csv_table", "csv_text"]


def format_float(x: float) -> str:
    """Shortest text that reads back as exactly ``x`` (Python's ``repr``)."""
    return repr(float(x))


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
                   allowed_text: str | None = None, extensions: bool = False) -> dict[str, np.ndarray]:
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
    extensions : bool
        Columns whose names start with ``x_`` and are not ``allowed`` are user extensions
        (formats.md): read as text, whatever they hold, and left out of the result.

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
        if allowed is not None and h not in allowed and not (extensions and h.startswith("x_")):
            raise error(file, f"column {h}", allowed_text or "only the columns " + ",".join(allowed),
                        f"the unknown column {h!r}")
    extra = [h for h in header if extensions and h.startswith("x_") and (allowed is None or h not in allowed)]
    text_columns = tuple(text_columns) + tuple(extra)
    ncol = len(header)
    numbered = [(k, line) for k, line in enumerate(lines[1:], start=2) if line.strip()]
    text_idx = [header.index(c) for c in text_columns if c in header]
    if not numbered:
        return {h: (np.empty(0, dtype=str) if i in text_idx else np.empty(0)) for i, h in enumerate(header)
                if h not in extra}
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
        if h in extra:
            continue
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
