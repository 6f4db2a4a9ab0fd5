"""Signal preparation for OMA: cut window, detrending, displacement from velocity or acceleration.

Signals are ``(n_channels, n_samples)``, time last, SI units; frequency in Hz.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import signal as sps

from .errors import RecordError
from .record import Record

__all__ = [
    "PreparedSignals",
    "window_slice",
    "detrend",
    "integrate_frequency_domain",
    "prepare_record",
]

Detrend = Literal["constant", "linear", "none"]


@dataclass(frozen=True)
class PreparedSignals:
    """Force and tool-tip displacement of one record inside its cut window.

    Attributes
    ----------
    force_N : ndarray, shape (3, n)
        Force on the tool, N (NaN rows for axes not recorded).
    displacement_m : ndarray, shape (3, n)
        Tool-tip displacement, m (NaN rows for axes not recorded).
    sample_rate_hz : float
    start_s : float
        Time of the first sample relative to the record start, s.
    motion_quantity : str
        What the record carried (``displacement``, ``velocity`` or ``acceleration``).
    quantisation_step_m : float or None
        Grid step of the displacement samples when they are quantised (a tracker); ``None`` when
        the displacement was integrated or is not on a grid.
    motion : ndarray, shape (3, n), or None
        The measured velocity (m/s) or acceleration (m/s^2) itself when the record carried one
        (``displacement_m`` is then its frequency-domain integral); None for displacement records.
    """

    force_N: np.ndarray
    displacement_m: np.ndarray
    sample_rate_hz: float
    start_s: float
    motion_quantity: str
    quantisation_step_m: float | None
    motion: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        return int(self.force_N.shape[1])

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.sample_rate_hz

    @property
    def force_axes(self) -> np.ndarray:
        """Boolean (3,): which force axes were recorded."""
        return ~np.all(np.isnan(self.force_N), axis=1)

    @property
    def displacement_axes(self) -> np.ndarray:
        """Boolean (3,): which motion axes were recorded."""
        return ~np.all(np.isnan(self.displacement_m), axis=1)


def window_slice(record: Record) -> slice:
    """Samples of ``record`` inside ``record.cut.window_s`` (the whole record when it is None).

    Raises
    ------
    RecordError
        When the window is empty or lies outside the record.
    """
    window = record.cut.window_s
    n = record.n_samples
    if window is None:
        return slice(0, n)
    t = record.time
    t0 = t[0]
    lo, hi = float(window[0]), float(window[1])
    if not (hi > lo):
        raise RecordError(record.path, "cut.window_s", "an increasing pair [start, end]", f"{list(window)}")
    i0 = int(np.searchsorted(t - t0, lo - 1e-9, side="left"))
    i1 = int(np.searchsorted(t - t0, hi + 1e-9, side="right"))
    if i0 >= n or i1 - i0 < 16:
        raise RecordError(
            record.path,
            "cut.window_s",
            f"a span inside the record (0 .. {record.duration_s:.3f} s) of at least 16 samples",
            f"{list(window)}",
        )
    return slice(i0, min(i1, n))


def detrend(x, *, kind: Detrend = "linear") -> np.ndarray:
    """Remove the mean (``constant``) or a least-squares line (``linear``) along the last axis.

    Rows that are entirely NaN (axes not recorded) stay NaN.
    """
    if kind not in ("constant", "linear", "none"):
        raise ValueError(f"kind must be 'constant', 'linear' or 'none', not {kind!r}")
    x = np.array(x, dtype=float, ndmin=2)
    if kind == "none":
        return x
    out = np.full_like(x, np.nan)
    ok = ~np.any(np.isnan(x), axis=-1)
    if np.any(ok):
        out[ok] = sps.detrend(x[ok], axis=-1, type=kind)
    return out


def integrate_frequency_domain(x, sample_rate_hz: float, *, order: int = 1, highpass_hz: float = 0.0,
                               detrend_kind: Detrend = "linear") -> np.ndarray:
    """Integrate a signal ``order`` times by dividing its spectrum by ``(i 2 pi f)^order``.

    The signal is detrended first (``detrend_kind``; a linear trend, e.g. a sensor offset drift,
    would otherwise wrap around the periodic FFT); the DC line and every line below
    ``highpass_hz`` are set to zero, so the result has zero mean and no drift below
    ``highpass_hz`` (an unknown constant and trend are lost, which an FRF estimate does not need).
    The record is treated as periodic: with ``detrend_kind='constant'`` a tone with a whole number
    of cycles is integrated exactly (a linear detrend also removes the small part of any tone
    that correlates with a line).

    Parameters
    ----------
    x : array_like, shape (..., n_samples)
        Velocity (order 1) or acceleration (order 2), SI.
    sample_rate_hz : float
        Sampling rate, Hz.
    order : {1, 2}
        Number of integrations.
    highpass_hz : float
        Lines below this frequency are removed, Hz.
    detrend_kind : {'linear', 'constant', 'none'}

    Returns
    -------
    ndarray, same shape as ``x``
    """
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, not {order!r}")
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    xd = x if detrend_kind == "none" else sps.detrend(x, axis=-1, type=detrend_kind)
    spec = np.fft.rfft(xd, axis=-1)
    f = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    keep = (f > 0) & (f >= highpass_hz)
    factor = np.zeros(f.size, dtype=complex)
    factor[keep] = (1.0 / (2j * np.pi * f[keep])) ** order
    return np.fft.irfft(spec * factor, n=n, axis=-1)


def _grid_step(x: np.ndarray, nominal: float | None) -> float | None:
    """The quantisation step of samples ``x`` when they lie on a regular grid, else None."""
    x = x[np.isfinite(x)]
    if x.size < 16:
        return None
    vals = np.unique(x)
    if vals.size < 2:
        return nominal
    steps = np.diff(vals)
    step = float(np.min(steps)) if nominal is None else float(nominal)
    if step <= 0:
        return None
    scale = max(float(np.max(np.abs(vals))), step)
    tol = 1e-9 * scale  # float rounding of values read from a file
    if step < 1e3 * tol:
        return None  # no grid coarser than the numbers' own rounding
    ratio = (vals - vals[0]) / step
    if np.max(np.abs(ratio - np.round(ratio))) * step <= tol + 1e-3 * step:
        return step
    return None


def _signals_field(record: Record) -> str:
    """How an error names a record's signals: by field when its file is known, by its name otherwise."""
    return "signals" if record.path is not None else f"record {record.name or ''}".strip() + " signals"


def constant_rows(y) -> np.ndarray:
    """Which rows of ``y`` (channels, samples) are recorded (not all NaN) and never change: a motion
    channel that reads the same throughout (a dead sensor, a cable off), shape (channels,)."""
    y = np.asarray(y, dtype=float)
    out = ~np.all(np.isnan(y), axis=1)
    out[out] = np.ptp(y[out], axis=1) == 0
    return out


def prepare_record(record: Record, *, highpass_hz: float = 1.0) -> PreparedSignals:
    """Force and displacement of a record inside its cut window, SI.

    Displacement comes from the displacement channels if the record has them, else velocity
    (integrated once) or acceleration (integrated twice) in the frequency domain, with lines below
    ``highpass_hz`` removed. Displacement channels are returned as recorded (no detrending), so that
    a tracker's quantisation grid is kept; its step is detected and reported.

    Raises
    ------
    RecordError
        When the record has no force channel or no motion channel.
    """
    sl = window_slice(record)
    force = np.array(record.force[:, sl])
    if np.all(np.isnan(force)):
        raise RecordError(record.path, _signals_field(record), "force channels", "none")
    fs = float(record.sample_rate_hz)
    step_hint = record.sensors.displacement_resolution_m if record.sensors is not None else None
    for quantity in ("displacement", "velocity", "acceleration"):
        if record.has(quantity):
            motion = np.array(record.vector(quantity)[:, sl])
            break
    else:
        raise RecordError(record.path, _signals_field(record), "displacement, velocity or acceleration channels",
                          "none")
    step = None
    measured = None
    if quantity == "displacement":
        steps = [_grid_step(row, step_hint) for row in motion if not np.all(np.isnan(row))]
        if steps and all(s is not None for s in steps):
            step = float(max(steps))
    else:
        order = 1 if quantity == "velocity" else 2
        # a velocity or acceleration channel that never moves is a dead sensor (a cable off), not a
        # tool at rest: as not recorded (session 23: an all-zero Z accelerometer had been read as a
        # sensor of enormous noise). A constant displacement is a tracker's rounding: kept
        motion[constant_rows(motion)] = np.nan
        ok = ~np.all(np.isnan(motion), axis=1)
        integrated = np.full_like(motion, np.nan)
        integrated[ok] = integrate_frequency_domain(motion[ok], fs, order=order, highpass_hz=highpass_hz)
        measured, motion = motion, integrated
    return PreparedSignals(
        force_N=force,
        displacement_m=motion,
        sample_rate_hz=fs,
        start_s=sl.start / fs,
        motion_quantity=quantity,
        quantisation_step_m=step,
        motion=measured,
    )
