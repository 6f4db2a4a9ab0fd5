"""Read and write cut-outcome tables (formats.md "Cut outcomes").

One row per cut: ``spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome`` and optionally
``feed_per_tooth_m``, ``record`` and ``x_...`` columns. ``outcome`` is ``stable``, ``chatter`` or
``uncertain``, or empty where ``record`` names the cut's record: the outcome is then detected with
the chatter detection of ``robomill diagnose`` (:func:`planner.diagnosis.chatter.detect_chatter`)
and its confidence becomes the label's weight.

A record shows chatter only below its band (0.45 of its sample rate; above, the anti-alias filter
removed the line or it folded). Given the prior model, the detection is told the chatter frequency
the model expects at the cut (the zero-order approximation at the cut's speed and engagement,
:func:`expected_chatter_frequency`, as ``diagnose`` does): where that lies above the band, a "no
chatter" says nothing and its weight is the bottom of the scale (0.1,
:data:`planner.diagnosis.chatter.OUT_OF_BAND_CONFIDENCE`), and the rows are named in a warning.
A 1 kHz record of a cut chattering at 740 Hz (a 720 Hz tool mode) read as a fairly sure "stable"
used to pull the posterior's limit up there.
"""

from __future__ import annotations

import codecs
import csv
import io
import math
import os
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from oma._fields import read_text, warn_user
from oma.errors import InputError
from oma.io import atomic_write

from .likelihood import CHATTER, STABLE, UNCERTAIN

__all__ = ["CutTable", "read_cuts", "write_cuts", "detect_outcome", "record_outcome", "record_detection",
           "expected_chatter_frequency", "CutsError", "OUTCOMES", "MIN_CUTS"]

OUTCOMES = {"stable": STABLE, "chatter": CHATTER, "uncertain": UNCERTAIN}
WORDS = {v: k for k, v in OUTCOMES.items()}
REQUIRED = ("spindle_rpm", "axial_depth_m", "radial_depth_m", "milling")
MIN_CUTS = 3
#: Deeper than this many tool diameters an axial depth is a unit error (mm written in a column of
#: m: 1000x too deep), not a cut: no end mill cuts ten diameters deep.
UNIT_ERROR_DIAMETERS = 10
#: Largest relative difference between a row's speed or depths and its record's own cut (two or
#: three significant digits typed in the table: 0.5-2 %; the next test cut is usually further off).
RECORD_TOLERANCE = 0.02


class CutsError(InputError):
    """A cut-outcomes table that cannot be read."""


@dataclass(frozen=True)
class CutTable:
    """Test cuts, SI. ``outcome`` holds STABLE/CHATTER/UNCERTAIN (-1: none, for cuts to predict);
    ``weight`` the label weight (1 for a mark, the detection confidence for a detected one)."""

    spindle_rpm: np.ndarray
    axial_depth_m: np.ndarray
    radial_depth_m: np.ndarray
    down: np.ndarray
    outcome: np.ndarray
    weight: np.ndarray
    feed_per_tooth_m: np.ndarray
    detected: np.ndarray

    @property
    def n_cuts(self) -> int:
        return int(self.spindle_rpm.size)

    def take(self, rows) -> "CutTable":
        """The cuts at ``rows`` (indices, a slice or a mask), in that order."""
        return CutTable(*(np.asarray(getattr(self, f.name))[rows] for f in fields(self)))

    def concat(self, other: "CutTable") -> "CutTable":
        """These cuts followed by ``other``'s."""
        return CutTable(*(np.concatenate([getattr(self, f.name), getattr(other, f.name)]) for f in fields(self)))

    def to_dict(self) -> dict:
        return {"rows": [self.row(i) for i in range(self.n_cuts)]}

    def row(self, i: int) -> dict:
        out = {"spindle_rpm": float(self.spindle_rpm[i]), "axial_depth_m": float(self.axial_depth_m[i]),
               "radial_depth_m": float(self.radial_depth_m[i]), "milling": "down" if self.down[i] else "up",
               "outcome": WORDS.get(int(self.outcome[i]), "")}
        if np.isfinite(self.feed_per_tooth_m[i]):
            out["feed_per_tooth_m"] = float(self.feed_per_tooth_m[i])
        return out


def _number(path, where, text, *, positive=True):
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise CutsError(path, where, "a number", repr(text)) from None
    if not math.isfinite(v) or (positive and v <= 0):
        raise CutsError(path, where, "a finite number > 0", repr(text))
    return v


def _text(p: Path) -> str:
    """The file's UTF-8 text (a BOM dropped); a UTF-16 file (byte-order mark) is named as such."""
    try:
        with open(p, "rb") as fh:
            head = fh.read(2)
    except OSError:
        head = b""  # read_text names the problem
    if head in (codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE):
        raise CutsError(p, "file", "UTF-8 text (save the table as CSV UTF-8)",
                        "UTF-16 text (a UTF-16 byte-order mark)")
    return read_text(p, error=CutsError, missing="an existing cut-outcomes CSV")


def _rows(p: Path, text: str) -> list[tuple[int, list[str]]]:
    """The rows that hold anything, each with its physical line (from 1; a quoted field may span
    lines: the row's first)."""
    reader = csv.reader(io.StringIO(text, newline=""))
    out, last = [], 0
    try:
        for r in reader:
            if any(c.strip() for c in r):
                out.append((last + 1, r))
            last = reader.line_num
    except csv.Error as exc:
        raise CutsError(p, f"line {reader.line_num}", "comma-separated fields", str(exc)) from None
    return out


def _check_record(p: Path, line: int, rec: Path, record, rpm: float, ap: float, ae: float, milling: str) -> None:
    """A record whose own cut is not the row's: the row and the record were mixed up."""
    cut = record.cut
    for name, row_value, rec_value in (("spindle_rpm", rpm, cut.spindle_rpm),
                                       ("axial_depth_m", ap, cut.axial_depth_m),
                                       ("radial_depth_m", ae, cut.radial_depth_m)):
        if rec_value and abs(row_value / float(rec_value) - 1.0) > RECORD_TOLERANCE:
            raise CutsError(p, f"line {line}: {name}", f"the cut of its record {rec} ({name} {float(rec_value):g}, "
                            f"within {RECORD_TOLERANCE:.0%})", f"{row_value:g}")
    if cut.milling != milling:
        raise CutsError(p, f"line {line}: milling", f"the cut of its record {rec} ({cut.milling})", repr(milling))


def read_cuts(path, *, tool, outcomes_required: bool = True, flute_length_m: float | None = None,
              max_depth_m: float | None = None, detect=None, chatter_frequency=None) -> CutTable:
    """Read a cut-outcomes CSV.

    Parameters
    ----------
    path : str or path-like
        UTF-8 text (a BOM is allowed), comma separated, a header row.
    tool : oma.cutting.Tool
        The setup's tool: radial depth must be in ``(0, D]``, axial depth at most
        ``UNIT_ERROR_DIAMETERS`` diameters (deeper is a depth in mm in a column of m).
    outcomes_required : bool
        ``False`` for a table of cuts to predict (outcome column optional; a word there must be
        one of the three, or empty: -1).
    flute_length_m : float, optional
        Axial depths above it are rejected (when known).
    max_depth_m : float, optional
        The setup's largest axial depth (``limits.axial_depth_m``): deeper cuts are kept (a test
        cut may go deeper than production), with a :class:`oma._fields.FileWarning` naming them.
    detect : callable, optional
        ``detect(record_path, row) -> (outcome, confidence[, out_of_band])`` for rows with an
        empty outcome and a ``record`` (``row``: ``spindle_rpm`` and ``expected_chatter_hz``, NaN
        when not known); default: the record is read, its own cut checked against the row (speed
        and depths within ``RECORD_TOLERANCE``, the same milling), and :func:`record_detection`.
    chatter_frequency : callable, optional
        ``chatter_frequency(spindle_rpm=, axial_depth_m=, radial_depth_m=, milling=) -> Hz``: the
        chatter frequency the prior model expects at a detected row's cut (``functools.partial``
        of :func:`expected_chatter_frequency`). Where it lies above the record's band, a "no
        chatter" gets weight 0.1 and the rows are named in a :class:`oma._fields.FileWarning`.
        Default: none (a "no" is taken at its detection confidence whatever the record's band).

    Raises
    ------
    CutsError
        Missing file, text that is not UTF-8, missing, unknown or repeated columns, a
        non-numeric or non-positive number, a milling other than up/down, an outcome other than
        the three words, a depth outside the tool, a record whose cut is not the row's, fewer than
        ``MIN_CUTS`` cuts (when outcomes are required). Lines are the file's physical lines.
    """
    p = Path(os.fspath(path))
    rows = _rows(p, _text(p))
    if not rows:
        raise CutsError(p, "header", "spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome", "an empty file")
    header = [h.strip() for h in rows[0][1]]
    need = REQUIRED + (("outcome",) if outcomes_required else ())
    for name in need:
        if name not in header:
            raise CutsError(p, "header", f"a column {name!r}", ",".join(header))
    known = set(REQUIRED) | {"outcome", "feed_per_tooth_m", "record"}
    for name in header:
        if name not in known and not name.startswith("x_"):
            raise CutsError(p, "header", "known columns or x_ extensions", f"the unknown column {name!r}")
        if not name.startswith("x_") and header.count(name) > 1:
            raise CutsError(p, "header", "each column once", f"{name!r} {header.count(name)} times")
    col = {h: i for i, h in enumerate(header)}
    data = rows[1:]
    if outcomes_required and len(data) < MIN_CUTS:
        raise CutsError(p, "rows", f"at least {MIN_CUTS} cuts", f"{len(data)}")
    if not data:
        raise CutsError(p, "rows", "at least 1 cut", "0")
    deepest = UNIT_ERROR_DIAMETERS * tool.diameter_m
    cols = {k: [] for k in ("rpm", "ap", "ae", "down", "out", "w", "fz", "det")}
    deep, unseen = [], []
    for n, r in data:
        if len(r) != len(header):
            raise CutsError(p, f"line {n}", f"{len(header)} fields", f"{len(r)}")
        get = lambda name: r[col[name]].strip() if name in col else ""  # noqa: E731
        rpm = _number(p, f"line {n}: spindle_rpm", get("spindle_rpm"))
        ap = _number(p, f"line {n}: axial_depth_m", get("axial_depth_m"))
        ae = _number(p, f"line {n}: radial_depth_m", get("radial_depth_m"))
        if ae > tool.diameter_m * (1 + 1e-9):
            raise CutsError(p, f"line {n}: radial_depth_m", f"at most the tool diameter {tool.diameter_m:g} m",
                            f"{ae:g}")
        if ap > deepest:
            raise CutsError(p, f"line {n}: axial_depth_m", f"at most {UNIT_ERROR_DIAMETERS} tool diameters, "
                            f"{deepest:g} m (a depth in mm in a column of m?)", f"{ap:g}")
        if flute_length_m is not None and ap > flute_length_m * (1 + 1e-9):
            raise CutsError(p, f"line {n}: axial_depth_m", f"at most the flute length {flute_length_m:g} m",
                            f"{ap:g}")
        if max_depth_m is not None and ap > max_depth_m * (1 + 1e-9):
            deep.append(n)
        milling = get("milling").lower()
        if milling not in ("up", "down"):
            raise CutsError(p, f"line {n}: milling", "'up' or 'down'", repr(get("milling")))
        fz = _number(p, f"line {n}: feed_per_tooth_m", get("feed_per_tooth_m")) if get("feed_per_tooth_m") \
            else np.nan
        word = get("outcome").lower()
        weight, detected = 1.0, False
        if not outcomes_required:
            if word not in OUTCOMES and word != "":
                raise CutsError(p, f"line {n}: outcome", "stable, chatter, uncertain or empty",
                                repr(get("outcome")))
            code = OUTCOMES.get(word, -1)
        elif word in OUTCOMES:
            code = OUTCOMES[word]
        elif word == "" and get("record"):
            rec = Path(get("record"))
            rec = rec if rec.is_absolute() else p.parent / rec
            fc = float("nan") if chatter_frequency is None else float(
                chatter_frequency(spindle_rpm=rpm, axial_depth_m=ap, radial_depth_m=ae, milling=milling))
            if detect is None:
                from oma.record_io import read_record

                record = read_record(rec)
                _check_record(p, n, rec, record, rpm, ap, ae, milling)
                res = record_detection(record, rpm, expected_chatter_hz=fc)
                code, weight, out_of_band = (CHATTER if res.chatter else STABLE), res.confidence, res.out_of_band
                rate = record.sample_rate_hz
            else:
                code, weight, *rest = detect(rec, {"spindle_rpm": rpm, "expected_chatter_hz": fc})
                out_of_band, rate = bool(rest[0]) if rest else False, float("nan")
            if out_of_band and code == STABLE:
                unseen.append((n, fc, rate))
            detected = True
        else:
            raise CutsError(p, f"line {n}: outcome", "stable, chatter or uncertain (or empty with a record)",
                            repr(get("outcome")))
        for k, v in zip(("rpm", "ap", "ae", "down", "out", "w", "fz", "det"),
                        (rpm, ap, ae, milling == "down", code, weight, fz, detected)):
            cols[k].append(v)
    if deep:
        lines = ", ".join(str(n) for n in deep[:10]) + (" ..." if len(deep) > 10 else "")
        warn_user(f"{p}: {len(deep)} cut(s) deeper than the setup's largest axial depth {max_depth_m:g} m "
                  f"(line {lines}): kept, as test cuts may go deeper than production; check the units")
    if unseen:
        warn_user(_unseen_message(p, unseen))
    arr = lambda k, dt=float: np.array(cols[k], dtype=dt)  # noqa: E731
    return CutTable(arr("rpm"), arr("ap"), arr("ae"), arr("down", bool), arr("out", int), arr("w"), arr("fz"),
                    arr("det", bool))


def _unseen_message(p: Path, unseen: list) -> str:
    """The warning naming detected rows whose "stable" could not see the expected chatter."""
    from planner.diagnosis.chatter import OUT_OF_BAND_CONFIDENCE

    lines = ", ".join(str(n) for n, _, _ in unseen[:10]) + (" ..." if len(unseen) > 10 else "")
    fc = [f for _, f, _ in unseen]
    freq = f"{min(fc):.0f} Hz" if max(fc) - min(fc) < 0.5 else f"{min(fc):.0f}-{max(fc):.0f} Hz"
    rates = sorted({r for _, _, r in unseen if np.isfinite(r)})
    sampled = f", records sampled at {', '.join(f'{r:g}' for r in rates)} Hz" if rates else ""
    return (f"{p}: {len(unseen)} cut(s) detected as stable from records that cannot show the chatter the prior "
            f"model expects (line {lines}: chatter at {freq}, above the band the detection searches{sampled}): "
            f"a 'stable' read there says nothing, and counts with weight {OUT_OF_BAND_CONFIDENCE:g}; record such "
            "cuts at more than 2.2 times the chatter frequency, or mark their outcome")


def expected_chatter_frequency(model, setup, *, spindle_rpm: float, axial_depth_m: float, radial_depth_m: float,
                               milling: str) -> float:
    """The chatter frequency a model predicts for a cut, Hz: the zero-order approximation's at the
    cut's speed and engagement (:func:`stability.lobes.predict_point`, as ``diagnose`` gives
    :func:`planner.diagnosis.chatter.detect_chatter` its ``expected_chatter_hz``), with the
    setup's tool, cutting frame and cutting coefficients. NaN when the ZOA cannot solve the model.
    """
    from dataclasses import replace

    from stability.lobes import predict_point

    cut = replace(setup.cut, radial_depth_m=float(radial_depth_m), milling=milling, spindle_rpm=float(spindle_rpm),
                  axial_depth_m=float(axial_depth_m))
    try:
        op = predict_point(model, setup.tool, cut, setup.material.cutting_coefficients, spindle_rpm=float(spindle_rpm),
                           axial_depth_m=float(axial_depth_m), method="zoa", n_freq=4000)
    except (ValueError, ArithmeticError):  # pragma: no cover - a model the ZOA cannot handle
        return float("nan")
    return float(op.chatter_frequency_hz)


def detect_outcome(record_path, row) -> tuple[int, float]:
    """Outcome and confidence of a cut from its record file (:func:`record_outcome`; ``row``:
    ``spindle_rpm`` and optionally ``expected_chatter_hz``)."""
    from oma.record_io import read_record

    return record_outcome(read_record(record_path), row["spindle_rpm"],
                          expected_chatter_hz=row.get("expected_chatter_hz"))


def record_detection(record, spindle_rpm: float | None = None, *, expected_chatter_hz: float | None = None):
    """``diagnose``'s chatter detection of a cut's record
    (:class:`planner.diagnosis.chatter.ChatterResult`).

    All the record's channels are analysed, at the record's spindle speed (``spindle_rpm`` when
    the record has none). ``expected_chatter_hz`` (Hz, :func:`expected_chatter_frequency`): above
    the band searched, a "no" gets confidence 0.1 and ``out_of_band`` is set.
    """
    from planner.diagnosis.chatter import detect_chatter

    rpm = record.cut.spindle_rpm if record.cut.spindle_rpm else spindle_rpm
    return detect_chatter(record.data, record.sample_rate_hz, float(rpm) / 60.0, record.tool.teeth,
                          expected_chatter_hz=expected_chatter_hz)


def record_outcome(record, spindle_rpm: float | None = None, *,
                   expected_chatter_hz: float | None = None) -> tuple[int, float]:
    """Outcome and confidence of a cut from its record, by ``diagnose``'s chatter detection
    (:func:`record_detection`).

    The confidence (:attr:`planner.diagnosis.chatter.ChatterResult.confidence`) is how far the
    decisive statistics are from their thresholds, one decade: sure; clipped to ``[0.1, 1]``; 0.1
    for a "no" when ``expected_chatter_hz`` lies above the record's band.
    """
    res = record_detection(record, spindle_rpm, expected_chatter_hz=expected_chatter_hz)
    return (CHATTER if res.chatter else STABLE), res.confidence


def write_cuts(table: CutTable, path) -> Path:
    """Write a cut table as CSV (atomically); the outcome column is left empty where unknown."""
    target = Path(os.fspath(path))
    lines = ["spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome"]
    for i in range(table.n_cuts):
        r = table.row(i)
        lines.append(f"{r['spindle_rpm']!r},{r['axial_depth_m']!r},{r['radial_depth_m']!r},{r['milling']},"
                     f"{r['outcome']}")
    with atomic_write(target) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return target
