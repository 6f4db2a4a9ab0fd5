"""The rate a record is analysed at: shop sensors sample far above what the analysis reads.

Everything ``identify --output-only`` looks at lies well under a few kHz: the modes' band (4-100 Hz
by default), the tooth-passing lines that scale them (up to 1.5 times the band's top), the lines
above them that tell of modes above the band (up to :func:`oma.timefit.resolved_band_hz`, 0.3 of
the rate), and the tooth line whose envelope finds the cut. Data acquisition sets for
accelerometers record at 10-51.2 kHz, where the milling lines up to Nyquist (hundreds of spindle
multiples) cost time in proportion to the rate squared (session 30, 20 s of the benchmark's tooth
case: 16 s of CPU at 25.6 kHz, 2.0 s decimated to 4.27 kHz; benchmarks/bench_oma_sample_rate.py).
Such records are decimated first, by the largest integer factor that keeps the rate at least
:data:`MIN_ANALYSIS_RATE_HZ`, :data:`BAND_FACTOR` times the band's top and :data:`TOOTH_FACTOR`
times the highest tooth-passing frequency (and the scaling lines' limit when one is given), with
SciPy's polyphase anti-aliasing filter (zero phase; Kaiser window, flat to 0.02 dB up to 0.4 of
the new rate, where the checks read at most 0.3).

Not decimated: records whose acquisition folded lines into the band (``alias_up_to`` above 0.5:
their folds are placed from the recorded rate), records with missing samples inside a channel,
and records of several rates.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy import signal as sps

__all__ = ["analysis_factor", "factor", "decimated", "decimate_rows", "white_power", "MIN_ANALYSIS_RATE_HZ",
           "BAND_FACTOR", "TOOTH_FACTOR"]

#: The lowest rate a record is decimated to, Hz: lines above the band are read to 0.3 of it
#: (1.2 kHz, where the example cell's tool modes, 720 / 735 Hz, load the lines).
MIN_ANALYSIS_RATE_HZ = 4000.0
#: The analysis rate is at least this many times the band's top (SSI decimates to 2.5 times it).
BAND_FACTOR = 10.0
#: ... and this many times the highest tooth-passing frequency (and the scaling lines' limit).
TOOTH_FACTOR = 2.5


def factor(sample_rate_hz: float, band_top_hz: float, tooth_hz=(), max_line_hz: float | None = None) -> int:
    """The largest integer factor that keeps ``sample_rate_hz`` at least :data:`MIN_ANALYSIS_RATE_HZ`,
    :data:`BAND_FACTOR` times ``band_top_hz`` and :data:`TOOTH_FACTOR` times each of ``tooth_hz``
    and ``max_line_hz`` (1: none)."""
    need = max([MIN_ANALYSIS_RATE_HZ, BAND_FACTOR * float(band_top_hz)]
               + [TOOTH_FACTOR * float(f) for f in tooth_hz]
               + ([TOOTH_FACTOR * float(max_line_hz)] if max_line_hz is not None else []))
    return max(int(math.floor(float(sample_rate_hz) / need)), 1)


def analysis_factor(records, band_hz, *, max_line_hz: float | None = None, alias_up_to: float = 0.5) -> int:
    """The integer factor the records are decimated by (1: none)."""
    rates = {float(r.sample_rate_hz) for r in records}
    if len(rates) != 1 or alias_up_to > 0.5:
        return 1
    tooth = [r.cut.spindle_rpm / 60.0 * max(int(r.tool.teeth), 1) for r in records
             if r.cut.spindle_rpm is not None and r.cut.spindle_rpm > 0]
    q = factor(rates.pop(), band_hz[1], tooth, max_line_hz)
    if q < 2 or any(not _whole_rows(r.data) for r in records):
        return 1
    return q


def _whole_rows(data) -> bool:
    """Whether every row is finite throughout or missing throughout (an axis not recorded)."""
    finite = np.isfinite(data)
    return bool(np.all(finite.all(axis=1) | ~finite.any(axis=1)))


def _filter(q: int) -> np.ndarray:
    """The anti-aliasing FIR of :func:`decimate_rows` at the recorded rate: SciPy's own default for
    ``resample_poly(x, 1, q)`` (cut-off at the new Nyquist, Kaiser window of beta 5, 10 q taps on
    each side), spelt out so that its power is known (:func:`white_power`)."""
    return sps.firwin(20 * q + 1, 1.0 / q, window=("kaiser", 5.0))


def white_power(q: int) -> float:
    """The share of a white noise's power up to the new Nyquist that the filter keeps: its
    variance after decimation by ``q`` is ``white_power(q) / q`` times its variance before
    (``q sum h^2``; 0.963 for every ``q`` from 2 to 12: the filter's roll-off below the new
    Nyquist). A white variance measured after decimation, divided by it, is the white level's."""
    return float(q * np.sum(_filter(q) ** 2)) if q > 1 else 1.0


def decimate_rows(data, q: int) -> np.ndarray:
    """The rows of ``data`` (k, n) at ``1 / q`` of their rate: low-passed and taken every ``q``-th
    sample (:func:`scipy.signal.resample_poly`, the ends extended along the line through the end
    samples, so that a displacement's absolute position does not ring there); constant rows (a dead
    sensor, which :func:`oma.output_only.identify.identify_output_only` names) and rows with a
    missing sample taken every ``q``-th as they are."""
    data = np.asarray(data, dtype=float)
    out = data[:, ::q].copy()
    rows = np.isfinite(data).all(axis=1) & (np.ptp(np.nan_to_num(data), axis=1) > 0)
    if rows.any():
        out[rows] = sps.resample_poly(data[rows], 1, q, axis=1, padtype="line", window=_filter(q))[:, :out.shape[1]]
    return out


def decimated(record, q: int):
    """``record`` at ``1 / q`` of its rate (:func:`decimate_rows`), the time column (if any) every
    ``q``-th."""
    if q == 1:
        return record
    time_s = None if record.time_s is None else np.asarray(record.time_s)[::q]
    return replace(record, data=decimate_rows(record.data, q), sample_rate_hz=float(record.sample_rate_hz) / q,
                   time_s=time_s)
