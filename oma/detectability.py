"""Detectability: is the background force strong enough for the displacement sensor to see the modes?

Nguyen & Melkote (2020, Fig. 7) simulate Gaussian white force of increasing variance through the
identified Y FRF over the record's duration and compare the peak-to-valley response with the laser
tracker's resolution; the smallest variance that reaches it (75 N^2 in their cut) must be below the
background variance measured in the force (278 N^2), otherwise the identified FRF rests on
responses the sensor could not resolve.

Generalised here to every axis: white force of variance ``s^2`` (at the record's sampling rate)
along axis ``a`` drives the model, the response along ``a`` is simulated for the record's duration
(after a run-in, so that it is stationary), and its peak-to-valley is collected over many
realisations. The system is linear, so the peak-to-valley scales with ``s``: one set of
unit-variance simulations gives the whole curve, and the minimum detectable variance is
``(resolution / median peak-to-valley at unit variance)^2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._arrays import readonly as _ro
from scipy import signal as sps

from .modal import ModalModel
from .synthetic import mode_filter

__all__ = ["Detectability", "peak_to_valley_unit", "detectability"]

AXES = ("X", "Y", "Z")


def peak_to_valley_unit(
    model: ModalModel, axis: int, duration_s: float, sample_rate_hz: float, *, n_trials: int = 200,
    run_in_s: float | None = None, rng=None
) -> np.ndarray:
    """Peak-to-valley displacement along ``axis`` for unit-variance white force along ``axis``.

    Parameters
    ----------
    model : ModalModel
    axis : int
        0, 1, 2 for X, Y, Z.
    duration_s : float
        Length of the simulated record, s.
    sample_rate_hz : float
        Sampling rate of the white force, Hz (the force variance is per sample at this rate).
    n_trials : int
        Independent realisations.
    run_in_s : float, optional
        Simulated time discarded first; five time constants of the slowest mode by default.
    rng : numpy.random.Generator or int, optional

    Returns
    -------
    ndarray, shape (n_trials,)
        ``max(x) - min(x)`` per realisation, m per N of force standard deviation.
    """
    rng = np.random.default_rng(rng)
    fs = float(sample_rate_hz)
    if run_in_s is None:
        decay = 1.0 / np.min(2 * np.pi * model.natural_frequency_hz * np.maximum(model.damping_ratio, 1e-3))
        run_in_s = min(5.0 * decay, 30.0)
    n = int(round(duration_s * fs))
    n_run = int(round(run_in_s * fs))
    force = rng.standard_normal((n_trials, n + n_run))
    x = model.residual_compliance_m_N[axis, axis] * force
    for fn, zeta, m, u in zip(model.natural_frequency_hz, model.damping_ratio, model.modal_mass_kg, model.directions):
        gain = u[axis] * u[axis] / m
        if gain == 0.0:
            continue
        b, a = mode_filter(fn, zeta, fs)
        x = x + gain * sps.lfilter(b, a, force, axis=-1)
    x = x[:, n_run:]
    return np.ptp(x, axis=-1)


@dataclass(frozen=True)
class Detectability:
    """The paper's Fig. 7 for every axis.

    Attributes
    ----------
    variance_N2 : ndarray, shape (n_var,)
        Force variances of the curve, N^2.
    peak_to_valley_m : ndarray, shape (3, n_var)
        Median peak-to-valley response per axis, m (NaN for axes not assessed).
    peak_to_valley_low_m, peak_to_valley_high_m : ndarray, shape (3, n_var)
        10th and 90th percentiles, m.
    resolution_m : float or None
        Displacement sensor resolution, m.
    duration_s : float
    min_variance_N2 : ndarray, shape (3,)
        Smallest variance whose median peak-to-valley reaches the resolution, N^2.
    background_variance_N2 : ndarray, shape (3,)
        Background variance measured in the force, N^2.
    sufficient : ndarray of bool, shape (3,)
        ``background >= min``; True where it cannot be assessed (no resolution, axis not measured).
    assessed : ndarray of bool, shape (3,)
    """

    variance_N2: np.ndarray
    peak_to_valley_m: np.ndarray
    peak_to_valley_low_m: np.ndarray
    peak_to_valley_high_m: np.ndarray
    resolution_m: float | None
    duration_s: float
    min_variance_N2: np.ndarray
    background_variance_N2: np.ndarray
    sufficient: np.ndarray
    assessed: np.ndarray

    def __post_init__(self):
        for name in ("variance_N2", "peak_to_valley_m", "peak_to_valley_low_m", "peak_to_valley_high_m",
                     "min_variance_N2", "background_variance_N2"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "sufficient", _ro(self.sufficient, bool))
        object.__setattr__(self, "assessed", _ro(self.assessed, bool))

    def to_dict(self) -> dict:
        def per_axis(v):
            return {a: (None if not np.isfinite(x) else float(x)) for a, x in zip(AXES, v)}

        return {
            "resolution_m": self.resolution_m,
            "duration_s": self.duration_s,
            "min_noise_variance_N2": per_axis(self.min_variance_N2),
            "noise_variance_N2": per_axis(self.background_variance_N2),
            "excitation_sufficient": {a: bool(s) for a, s in zip(AXES, self.sufficient)},
        }

    def plot(self, ax=None, **kwargs):
        """Peak-to-valley versus force variance with the resolution line (:func:`oma.plots.plot_detectability`)."""
        from .plots import plot_detectability

        return plot_detectability(self, ax=ax, **kwargs)


def detectability(
    model: ModalModel,
    duration_s: float,
    sample_rate_hz: float,
    resolution_m: float | None,
    background_variance_N2,
    *,
    axes=(0, 1, 2),
    n_trials: int = 200,
    variance_N2=None,
    rng=0,
) -> Detectability:
    """Minimum detectable background variance per axis and the verdict for a record.

    Parameters
    ----------
    model : ModalModel
        The identified model.
    duration_s : float
        Record (cut window) duration, s.
    sample_rate_hz : float
    resolution_m : float or None
        Displacement sensor resolution, m; None: not assessed (every verdict True).
    background_variance_N2 : array_like, shape (3,)
        Measured background variance per axis, N^2.
    axes : sequence of int
        Axes to assess (measured ones).
    n_trials : int
        Realisations of the white force.
    variance_N2 : array_like, optional
        Grid of the curve; 1 to 10^4 N^2 (log-spaced) by default.
    rng : numpy.random.Generator or int
        Random source of the simulation (seeded by default: the verdict is reproducible).

    Without a resolution nothing is simulated: there is nothing to compare the peak-to-valley
    with, and the curves stay NaN (session 32: on a 20 s accelerometer record at 5 kHz the
    simulations took 2 s of the force-based identification's 10 s, for a verdict of "not assessed").
    """
    rng = np.random.default_rng(rng)
    grid = np.logspace(0, 4, 41) if variance_N2 is None else np.asarray(variance_N2, dtype=float)
    bg = np.asarray(background_variance_N2, dtype=float).reshape(3)
    p2v = np.full((3, grid.size), np.nan)
    lo = np.full_like(p2v, np.nan)
    hi = np.full_like(p2v, np.nan)
    min_var = np.full(3, np.nan)
    assessed = np.zeros(3, dtype=bool)
    for a in axes if resolution_m is not None else ():
        unit = peak_to_valley_unit(model, a, duration_s, sample_rate_hz, n_trials=n_trials, rng=rng)
        s = np.sqrt(grid)
        p2v[a] = np.median(unit) * s
        lo[a] = np.quantile(unit, 0.1) * s
        hi[a] = np.quantile(unit, 0.9) * s
        if np.median(unit) > 0:
            min_var[a] = (resolution_m / np.median(unit)) ** 2
            assessed[a] = np.isfinite(bg[a])
    sufficient = np.where(assessed, bg >= np.where(np.isfinite(min_var), min_var, 0.0), True)
    return Detectability(
        variance_N2=grid, peak_to_valley_m=p2v, peak_to_valley_low_m=lo, peak_to_valley_high_m=hi,
        resolution_m=resolution_m, duration_s=float(duration_s), min_variance_N2=min_var,
        background_variance_N2=bg, sufficient=sufficient, assessed=assessed,
    )
