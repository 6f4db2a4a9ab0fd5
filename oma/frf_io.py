"""Read and write measured FRFs: robomill CSV, UFF dataset 58, CutPro-style ``.frf`` (formats.md).

- CSV: header ``freq_hz,XX_re,XX_im,YY_re,YY_im,...``, one pair of columns per measured entry
  (output axis, then input axis), receptance in m/N.
- UFF58 (``.uff``/``.unv``, ASCII or binary, via pyuff): receptance, mobility or accelerance FRFs
  (dataset 58 with function type 4), converted to receptance in m/N:
  ``G = Y / (i w)`` for mobility, ``G = A / (-w^2)`` for accelerance, ``w = 2 pi f``. A units
  dataset 164 before the functions is applied (SI = file value * force factor / length factor,
  UFF 164 factors being "file units per SI unit"); without one, SI is assumed.
- ``.frf``: one direct FRF, a header line, then whitespace-separated columns frequency (Hz),
  real and imaginary part (m/N). The file does not say its axis; the caller does.

How UFF functions map onto the 3x3 machine-frame table (UFF does not say which node is the tool
tip, and node numbering is test-specific): a table is built from the functions measured at one
node, response node = reference node (the tool tip's driving-point and cross FRFs), with UFF
direction codes 1, 2, 3 read as machine axes X, Y, Z (negative codes flip the sign). A file with a
single such node is read as it is; a file with several nodes (e.g. a roving-hammer test) needs
``node=`` to pick the tool tip, and functions between different nodes are left out of the table.
:func:`read_uff58_functions` returns every FRF of a file for code that wants them all (fitting).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ._fields import csv_text, describe, format_float, read_csv_table, read_text, warn_user
from .errors import FRFError
from .frf_table import AXES, FRFTable
from .io import atomic_write

__all__ = [
    "read_frf",
    "write_frf_csv",
    "write_frf_uff",
    "write_frf_text",
    "read_uff58_functions",
    "UFFFunction",
]

FRFKind = Literal["receptance", "mobility", "accelerance"]
#: UFF58 ordinate (numerator) specific data types and the FRF kind they make (force denominator).
_UFF_NUMERATOR_KIND = {8: "receptance", 11: "mobility", 12: "accelerance"}
_UFF_KIND_NUMERATOR = {v: k for k, v in _UFF_NUMERATOR_KIND.items()}
#: UFF58 denominator specific data types accepted as force (9 reaction force, 13 excitation force;
#: 0 "unknown" is taken as force, as many exporters leave it unset).
_UFF_FORCE_DENOMINATORS = (0, 9, 13)
_UFF_FRF_FUNCTION = 4


# ------------------------------------------------------------------------------------ dispatch
def read_frf(path, *, axis: str | None = None, node: int | None = None) -> FRFTable:
    """Read a measured receptance FRF table, in m/N, machine frame.

    Parameters
    ----------
    path : str or path-like
        ``.csv`` (robomill FRF table), ``.uff``/``.unv`` (UFF dataset 58) or ``.frf``
        (CutPro-style text, one direct FRF).
    axis : {'X', 'Y', 'Z'}, optional
        Required for ``.frf``: the machine axis of its direct FRF (entry ``XX``, ``YY`` or ``ZZ``).
        Must be left out for the other formats, whose entries name their axes.
    node : int, optional
        UFF only: the node taken as the tool tip (see the module notes). Needed when the file
        holds FRFs of more than one node.

    Returns
    -------
    FRFTable
        ``meta`` holds ``source`` (the path) and ``format`` (``csv``, ``uff58`` or ``frf``); for
        UFF also ``kinds`` (the file's FRF kind per entry) and ``node``.

    Raises
    ------
    FRFError
        Missing or invalid file (message: file, field, expected, found), unknown suffix, a
        missing or misused ``axis``/``node``.
    """
    file = os.fspath(path)
    suffix = Path(file).suffix.lower()
    if suffix == ".frf":
        if axis is None or not isinstance(axis, str) or axis.upper() not in AXES:
            raise FRFError(file, "axis", "the axis X, Y or Z of this direct FRF (a .frf file does "
                           "not say it; give it with the file)", describe(axis))
        if node is not None:
            raise FRFError(file, "node", "no node for a .frf file", describe(node))
        return _read_frf_text(file, axis.upper())
    if axis is not None:
        raise FRFError(file, "axis", f"no axis for a {suffix or 'suffix-less'} file (its entries "
                       "name their axes; axis is for .frf files)", describe(axis))
    if suffix == ".csv":
        if node is not None:
            raise FRFError(file, "node", "no node for a .csv FRF table", describe(node))
        return _read_frf_csv(file)
    if suffix in (".uff", ".unv"):
        return _table_from_uff(file, read_uff58_functions(file), node)
    raise FRFError(file, "file", "an FRF file ending in .csv, .uff, .unv or .frf",
                   f"the suffix {suffix!r}" if suffix else "no suffix")


# ----------------------------------------------------------------------------------------- CSV
def _read_frf_csv(file: str) -> FRFTable:
    columns = read_csv_table(file, error=FRFError)
    names = list(columns)
    if names[0] != "freq_hz":
        raise FRFError(file, "header column 1", "freq_hz", repr(names[0]))
    parts: dict[str, dict[str, np.ndarray]] = {}
    for name in names[1:]:
        entry, _, part = name.partition("_")
        if (len(entry) != 2 or entry[0] not in AXES or entry[1] not in AXES
                or part not in ("re", "im")):
            raise FRFError(file, f"column {name}", "freq_hz then pairs <out><in>_re, <out><in>_im "
                           "with out, in in X, Y, Z (e.g. XX_re, XX_im)", f"the column {name!r}")
        parts.setdefault(entry, {})[part] = columns[name]
    if not parts:
        raise FRFError(file, "header", "at least one entry (e.g. XX_re, XX_im)", "only freq_hz")
    for entry, p in parts.items():
        for part in ("re", "im"):
            if part not in p:
                raise FRFError(file, f"column {entry}_{part}",
                               f"both {entry}_re and {entry}_im", f"no {entry}_{part} column")
    freq = columns["freq_hz"]
    _check_frequencies(freq, file, "column freq_hz")
    entries = {}
    for entry, p in parts.items():
        for part in ("re", "im"):
            bad = np.flatnonzero(~np.isfinite(p[part]))
            if bad.size:
                raise FRFError(file, f"column {entry}_{part}, row {bad[0] + 1}", "finite numbers",
                               repr(float(p[part][bad[0]])))
        entries[entry] = p["re"] + 1j * p["im"]
    return FRFTable.from_entries(freq, entries, meta={"source": file, "format": "csv"})


def _check_frequencies(freq: np.ndarray, file: str, field: str) -> None:
    if freq.size < 2:
        # one line is a value, not a response: the zero-order lobes from it found no chatter at any
        # speed ("limit inf") and predict called every cut stable
        raise FRFError(file, field, "at least two frequency lines (a response over a band)",
                       "no rows" if freq.size == 0 else "one line")
    bad = np.flatnonzero(~np.isfinite(freq) | (freq < 0))
    if bad.size:
        raise FRFError(file, f"{field}, row {bad[0] + 1}", "finite frequencies >= 0 Hz",
                       repr(float(freq[bad[0]])))
    step = np.flatnonzero(np.diff(freq) <= 0)
    if step.size:
        k = step[0]
        raise FRFError(file, f"{field}, row {k + 2}", "increasing frequencies",
                       f"{float(freq[k + 1])!r} after {float(freq[k])!r}")


def write_frf_csv(table: FRFTable, path) -> Path:
    """Write the measured entries of a table as a robomill FRF CSV (receptance, m/N).

    Columns ``freq_hz`` then ``<out><in>_re, <out><in>_im`` for each measured entry in row-major
    order; numbers with ``repr`` precision, so the file reads back bit for bit. Coherence and
    ``meta`` are not part of the format and are not written.

    Returns
    -------
    pathlib.Path
    """
    cols: dict[str, np.ndarray] = {"freq_hz": np.asarray(table.freq_hz, dtype=float)}
    for name in table.entry_names:
        g = table.entry(name)
        cols[f"{name}_re"] = g.real
        cols[f"{name}_im"] = g.imag
    if len(cols) == 1:
        raise ValueError("the FRF table has no measured entry to write")
    target = Path(os.fspath(path))
    with atomic_write(target) as tmp:
        tmp.write_text(csv_text(cols), encoding="utf-8", newline="")
    return target


# ---------------------------------------------------------------------------------------- .frf
def _read_frf_text(file: str, axis: str) -> FRFTable:
    text = read_text(file, error=FRFError)
    lines = text.splitlines()
    rows, first = [], True
    for lineno, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        cells = line.split()
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if first:  # the header line
                first = False
                continue
            raise FRFError(file, f"line {lineno}", "three numbers: frequency (Hz), real, imaginary "
                           "(m/N)", describe(line.strip())) from None
        first = False
        if len(values) != 3:
            raise FRFError(file, f"line {lineno}", "three numbers: frequency (Hz), real, imaginary "
                           "(m/N)", f"{len(values)} numbers")
        rows.append(values)
    if not rows:
        raise FRFError(file, "data", "lines of frequency (Hz), real, imaginary (m/N)", "no data lines")
    data = np.array(rows)
    _check_frequencies(data[:, 0], file, "frequency")
    bad = np.flatnonzero(~np.all(np.isfinite(data[:, 1:]), axis=1))
    if bad.size:
        raise FRFError(file, f"data row {bad[0] + 1}", "finite real and imaginary parts",
                       describe(data[bad[0], 1:].tolist()))
    return FRFTable.from_entries(data[:, 0], {axis + axis: data[:, 1] + 1j * data[:, 2]},
                                 meta={"source": file, "format": "frf"})


def write_frf_text(table: FRFTable, path, *, axis: str) -> Path:
    """Write one direct entry (``axis``+``axis``) as a CutPro-style ``.frf`` text file.

    A header line, then ``frequency_Hz real_m_N imag_m_N`` per line (``repr`` precision).
    """
    axis = axis.upper()
    g = table.entry(axis + axis)
    lines = ["Frequency(Hz) Real(m/N) Imag(m/N)"]
    lines += [f"{format_float(f)} {format_float(z.real)} {format_float(z.imag)}"
              for f, z in zip(table.freq_hz.tolist(), g.tolist())]
    target = Path(os.fspath(path))
    with atomic_write(target) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="")
    return target


# ---------------------------------------------------------------------------------------- UFF58
@dataclass(frozen=True)
class UFFFunction:
    """One FRF of a UFF file (dataset 58, function type 4), SI units.

    Parameters
    ----------
    freq_hz : ndarray, shape (n,)
        Frequencies, Hz. For a mobility or accelerance the 0 Hz line (where the receptance is
        undefined) is left out.
    receptance_m_N : ndarray of complex, shape (n,)
        The FRF as receptance, m/N.
    measured : ndarray of complex, shape (n,)
        The FRF as the file gave it, in SI: m/N, (m/s)/N or (m/s^2)/N by ``kind``.
    kind : {'receptance', 'mobility', 'accelerance'}
        What the file stored (UFF ordinate data type 8, 11 or 12 over force).
    response_node, response_direction, reference_node, reference_direction : int
        UFF node numbers and direction codes (1, 2, 3 = +X, +Y, +Z; negative = opposite).
    description : str
        The dataset's first ID line.
    """

    freq_hz: np.ndarray
    receptance_m_N: np.ndarray
    measured: np.ndarray
    kind: FRFKind
    response_node: int
    response_direction: int
    reference_node: int
    reference_direction: int
    description: str = ""

    def __post_init__(self):
        for name, dtype in (("freq_hz", float), ("receptance_m_N", complex), ("measured", complex)):
            a = np.array(getattr(self, name), dtype=dtype)
            a.setflags(write=False)
            object.__setattr__(self, name, a)


def read_uff58_functions(path) -> list[UFFFunction]:
    """Every FRF (dataset 58, function type 4) of a UFF file, converted to receptance, SI.

    Parameters
    ----------
    path : str or path-like
        ``.uff`` or ``.unv``, ASCII or binary dataset 58.

    Returns
    -------
    list of UFFFunction
        In file order. Datasets of other types and functions that are not FRFs (coherence,
        spectra ...) are skipped.

    Raises
    ------
    FRFError
        Missing or unreadable file, no FRF in it, an FRF whose numerator is not displacement,
        velocity or acceleration or whose denominator is not force, real-valued FRF data,
        frequencies not increasing, non-finite values.

    Notes
    -----
    ``G = H`` (displacement), ``G = H / (i w)`` (velocity), ``G = H / (-w^2)`` (acceleration),
    ``w = 2 pi f`` rad/s (e.g. Ewins, *Modal Testing*, 2000, sec. 2.7).
    """
    import pyuff  # an optional-weight import kept local: only UFF users pay for it

    file = os.fspath(path)
    if not os.path.exists(file):
        raise FRFError(file, "file", "an existing UFF file", "no such file")
    if os.path.isdir(file):
        raise FRFError(file, "file", "a UFF file", "a directory")
    try:
        uff = pyuff.UFF(file)
        types = list(np.atleast_1d(uff.get_set_types()))
        sets = uff.read_sets() if types else []
    except Exception as exc:  # noqa: BLE001 - pyuff raises bare Exception for any damage
        raise FRFError(file, "file", "a readable universal file (UFF)",
                       f"{type(exc).__name__}: {str(exc)[:100]}") from None
    if isinstance(sets, dict):
        sets = [sets]
    length_factor, force_factor = 1.0, 1.0  # file units per SI unit (UFF dataset 164)
    out: list[UFFFunction] = []
    for index, dset in enumerate(sets):
        where = f"dataset {index + 1}"
        if not isinstance(dset, dict):
            continue
        if dset.get("type") == 164:
            try:
                length_factor, force_factor = float(dset["length"]), float(dset["force"])
            except (KeyError, TypeError, ValueError):
                raise FRFError(file, f"{where} (units)", "length and force factors",
                               "none readable") from None
            if not (math.isfinite(length_factor) and length_factor > 0 and math.isfinite(force_factor)
                    and force_factor > 0):
                raise FRFError(file, f"{where} (units)", "length and force factors > 0",
                               f"{length_factor!r}, {force_factor!r}")
            continue
        if dset.get("type") != 58 or dset.get("func_type") != _UFF_FRF_FUNCTION:
            continue
        out.append(_uff_function(dset, file, where, length_factor, force_factor))
    if not out:
        raise FRFError(file, "datasets", "at least one FRF (dataset 58, function type 4)",
                       f"dataset types {sorted({int(t) for t in types})}" if types else "no datasets")
    return out


def _uff_function(dset: dict, file: str, where: str, length_factor: float,
                  force_factor: float) -> UFFFunction:
    num = int(dset.get("ordinate_spec_data_type", 0))
    den = int(dset.get("orddenom_spec_data_type", 0))
    if num not in _UFF_NUMERATOR_KIND:
        raise FRFError(file, f"{where} ordinate data type", "8, 11 or 12 (displacement, velocity, "
                       "acceleration)", repr(num))
    if den not in _UFF_FORCE_DENOMINATORS:
        raise FRFError(file, f"{where} denominator data type", "13 or 9 (force)", repr(den))
    kind = _UFF_NUMERATOR_KIND[num]
    data = np.asarray(dset.get("data"))
    freq = np.asarray(dset.get("x"), dtype=float)
    if not np.iscomplexobj(data):
        raise FRFError(file, f"{where} data", "complex FRF values (ordinate data type 5 or 6)",
                       f"real values (type {dset.get('ord_data_type')})")
    if data.shape != freq.shape or data.ndim != 1:
        raise FRFError(file, f"{where} data", f"{freq.size} values, one per frequency",
                       f"{data.size} values")
    _check_frequencies(freq, file, f"{where} frequencies")
    if not np.all(np.isfinite(data)):
        k = int(np.flatnonzero(~np.isfinite(data))[0])
        raise FRFError(file, f"{where} value {k + 1}", "finite numbers", repr(complex(data[k])))
    measured = data * (force_factor / length_factor)  # SI = file * F / L for (length)/(force)
    if kind != "receptance" and freq[0] == 0.0:
        freq, measured = freq[1:], measured[1:]
    w = 2.0 * np.pi * freq
    if kind == "receptance":
        receptance = measured
    elif kind == "mobility":
        receptance = measured / (1j * w)
    else:
        receptance = measured / (-(w**2))
    return UFFFunction(
        freq_hz=freq, receptance_m_N=receptance, measured=measured, kind=kind,
        response_node=int(dset.get("rsp_node", 0)), response_direction=int(dset.get("rsp_dir", 0)),
        reference_node=int(dset.get("ref_node", 0)), reference_direction=int(dset.get("ref_dir", 0)),
        description=str(dset.get("id1", "")).strip(),
    )


def _table_from_uff(file: str, functions: list[UFFFunction], node: int | None) -> FRFTable:
    pairs = sorted({(f.response_node, f.reference_node) for f in functions})
    if node is None:
        driving = sorted({a for a, b in pairs if a == b})
        if len(driving) != 1:
            raise FRFError(file, "nodes", "FRFs at one tool-tip node (response node = reference "
                           "node), or node= to pick the tool tip",
                           "response/reference nodes " + ", ".join(f"{a}/{b}" for a, b in pairs))
        node = driving[0]
        if len(pairs) > 1:
            # a roving-hammer set (the shared real file: response node 1, hammer at 1, 2, 3): the
            # tool tip's FRF is the driving point's, the only one a stability model uses
            warn_user(f"{file}: the FRFs between other nodes (" + ", ".join(
                f"{a}/{b}" for a, b in pairs if (a, b) != (node, node)) + f") left out: node {node}, the "
                "only one with a driving-point FRF, taken for the tool tip")
    chosen = [f for f in functions if f.response_node == node and f.reference_node == node]
    if not chosen:
        raise FRFError(file, "node", "a node with FRFs measured at it (response node = reference "
                       "node)", f"node {node}; the file has response/reference nodes "
                       + ", ".join(f"{a}/{b}" for a, b in pairs))
    freq = chosen[0].freq_hz
    entries: dict[str, np.ndarray] = {}
    kinds: dict[str, str] = {}
    for f in chosen:
        dirs = (f.response_direction, f.reference_direction)
        if not all(1 <= abs(d) <= 3 for d in dirs):
            raise FRFError(file, f"node {node} FRF {f.response_direction}/{f.reference_direction}",
                           "translational direction codes 1, 2, 3 (or -1, -2, -3)",
                           f"directions {dirs[0]}, {dirs[1]}")
        name = AXES[abs(dirs[0]) - 1] + AXES[abs(dirs[1]) - 1]
        if name in entries:
            raise FRFError(file, f"node {node} FRF {name}", "one FRF per direction pair",
                           "a second one")
        if f.freq_hz.shape != freq.shape or not np.array_equal(f.freq_hz, freq):
            raise FRFError(file, f"node {node} FRF {name}",
                           "the same frequency lines as the other FRFs of the node",
                           f"{f.freq_hz.size} lines from {float(f.freq_hz[0])!r} Hz")
        sign = np.sign(dirs[0]) * np.sign(dirs[1])
        entries[name] = sign * f.receptance_m_N
        kinds[name] = f.kind
    return FRFTable.from_entries(freq, entries, meta={"source": file, "format": "uff58",
                                                      "node": int(node), "kinds": kinds})


def write_frf_uff(table: FRFTable, path, *, binary: bool = True, node: int = 1) -> Path:
    """Write the measured entries as UFF: a units dataset 164 (SI) and one dataset 58 per entry.

    Each entry ``<out><in>`` becomes a receptance FRF (function type 4, ordinate displacement over
    excitation force, m/N) from reference ``node`` direction ``in`` to response ``node``
    direction ``out`` (1, 2, 3 = X, Y, Z), frequencies stored as an uneven abscissa.

    Parameters
    ----------
    table : FRFTable
    path : str or path-like
        ``.uff`` or ``.unv``.
    binary : bool, optional
        ``True`` (default): binary dataset 58, every double kept exactly (reads back bit for bit).
        ``False``: ASCII dataset 58, readable by every UFF tool but rounded by the format to 12
        significant digits for values and 6 for frequencies.
    node : int, optional
        Node number of the tool tip in the file.

    Returns
    -------
    pathlib.Path
    """
    import pyuff

    names = table.entry_names
    if not names:
        raise ValueError("the FRF table has no measured entry to write")
    if table.freq_hz.size < 2:
        raise ValueError("UFF58 needs at least two frequency lines")
    dsets = [pyuff.prepare_164(units_code=1, units_description="SI", temp_mode=1, length=1.0,
                               force=1.0, temp=1.0, temp_offset=273.15)]
    for name in names:
        dsets.append(pyuff.prepare_58(
            binary=1 if binary else 0, func_type=_UFF_FRF_FUNCTION, rsp_node=int(node),
            rsp_dir=AXES.index(name[0]) + 1, ref_node=int(node), ref_dir=AXES.index(name[1]) + 1,
            data=np.array(table.entry(name), dtype=complex), x=np.array(table.freq_hz, dtype=float),
            id1=f"robomill receptance {name}", rsp_ent_name="robomill", ref_ent_name="robomill",
            abscissa_spacing=0, abscissa_spec_data_type=18,
            ordinate_spec_data_type=_UFF_KIND_NUMERATOR["receptance"], orddenom_spec_data_type=13,
        ))
    target = Path(os.fspath(path))
    with atomic_write(target) as tmp:
        # the temporary file is new and empty: "add" (pyuff's binary "overwrite" of a first
        # dataset 58 truncates the header it has just written, pyuff 2.5)
        pyuff.UFF(os.fspath(tmp)).write_sets(dsets, mode="add")
    return target
