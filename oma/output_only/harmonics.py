"""Milling harmonics in the response: found from the record's speed and teeth, and regressed out.

Stable milling drives the structure at every multiple of the spindle frequency; in the response
these lines are forced vibration, not modes. Stochastic subspace identification takes a sinusoid
for an undamped mode, and one inside a mode's half-power band for the mode itself (Brincker &
Ventura, Introduction to OMA, 2015, sec. 11.7). Here they are removed in the time domain before
SSI: the spindle frequency is refined from the response's own harmonic comb
(:func:`oma.harmonics.refine_spindle_frequency`), then a constant, a line and a sinusoid at every
spindle multiple below the Nyquist frequency are fitted by least squares
(:func:`oma.harmonics.fit_harmonic_signal`) and subtracted. The regression takes out only what is
coherent with a fixed sinusoid over the whole record, a notch about ``1/T`` wide (0.05 Hz for 20 s),
so a 24.0 Hz line is removed from a 24.8 Hz mode whose half-power band is 2 Hz wide without
touching the mode. The complex amplitudes of the lines are kept: they are what scales the modes
(:mod:`oma.output_only.scaling`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal as sps

from .._arrays import readonly as _ro
from ..harmonics import harmonic_basis, harmonic_frequencies, refine_spindle_frequency
from .._linalg import lstsq_normal

__all__ = ["ResponseHarmonics", "remove_response_harmonics", "at_milling_line"]

#: A pole within this relative distance of a milling line and less damped than
#: :data:`HARMONIC_MAX_DAMPING` is taken for the line (:func:`at_milling_line`).
HARMONIC_TOLERANCE = 0.005
HARMONIC_MAX_DAMPING = 0.01


def at_milling_line(freq_hz, damping, lines_hz) -> np.ndarray:
    """Whether each pole (``freq_hz``, ``damping``) is a milling line's remainder rather than a
    mode: within :data:`HARMONIC_TOLERANCE` of a line of ``lines_hz`` and damped less than
    :data:`HARMONIC_MAX_DAMPING` (a sinusoid the regression left behind, e.g. a wandering spindle,
    reads as an undamped pole)."""
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    z = np.atleast_1d(np.asarray(damping, dtype=float))
    lines = np.asarray(lines_hz, dtype=float).ravel()
    if lines.size == 0:
        return np.zeros(f.size, dtype=bool)
    near = np.min(np.abs(lines[None, :] / f[:, None] - 1.0), axis=1) < HARMONIC_TOLERANCE
    return near & (z < HARMONIC_MAX_DAMPING)


@dataclass(frozen=True)
class ResponseHarmonics:
    """The milling lines of a response record and what is left without them.

    Attributes
    ----------
    spindle_hz : float
        Refined spindle frequency, Hz.
    nominal_spindle_hz : float
    teeth : int
    freq_hz : ndarray, shape (n_h,)
        Spindle multiples below the Nyquist frequency, Hz.
    tooth_passing : ndarray of bool, shape (n_h,)
    amplitude : ndarray of complex, shape (n_channels, n_h)
        Complex amplitude ``a`` of each line (the signal is ``Re(a exp(2 pi i f t))``, ``t`` from
        the first sample), in the signal's unit.
    noise_amplitude : ndarray, shape (n_channels, n_h)
        Standard deviation of ``|a|`` due to the broadband response at the line:
        ``sqrt(2 G(f) / T)`` with ``G`` the one-sided PSD of the residual near the line.
    significant : ndarray of bool, shape (n_h,)
        Lines standing ``threshold_db`` above the broadband response in some channel.
    residual : ndarray, shape (n_channels, n_samples)
        The signal with the lines, its mean and a linear trend removed.
    aliased : ndarray of bool, shape (n_h,)
        Lines folded back from above the Nyquist frequency (``freq_hz`` is then where they land).
    """

    spindle_hz: float
    nominal_spindle_hz: float
    teeth: int
    freq_hz: np.ndarray
    tooth_passing: np.ndarray
    amplitude: np.ndarray
    noise_amplitude: np.ndarray
    significant: np.ndarray
    residual: np.ndarray = field(repr=False)
    aliased: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def __post_init__(self):
        object.__setattr__(self, "freq_hz", _ro(self.freq_hz))
        object.__setattr__(self, "tooth_passing", _ro(self.tooth_passing, bool))
        object.__setattr__(self, "amplitude", _ro(self.amplitude, complex))
        object.__setattr__(self, "noise_amplitude", _ro(self.noise_amplitude))
        object.__setattr__(self, "significant", _ro(self.significant, bool))
        object.__setattr__(self, "residual", _ro(self.residual))
        object.__setattr__(self, "aliased", _ro(self.aliased, bool))

    @property
    def found_hz(self) -> np.ndarray:
        return self.freq_hz[self.significant]

    def to_dict(self) -> dict:
        return {"spindle_hz": float(self.spindle_hz), "nominal_spindle_hz": float(self.nominal_spindle_hz),
                "teeth": int(self.teeth), "found_hz": [float(f) for f in self.found_hz]}


def remove_response_harmonics(y, sample_rate_hz: float, spindle_rpm: float | None, teeth: int, *,
                              refine: bool = True, search: float = 0.05, threshold_db: float = 10.0,
                              nperseg: int | None = None, alias_up_to: float = 0.5) -> ResponseHarmonics:
    """Find the milling lines of a response and regress them out.

    Parameters
    ----------
    y : array_like, shape (n_channels, n_samples)
        Response (displacement, velocity or acceleration), SI.
    sample_rate_hz : float
    spindle_rpm : float or None
        Nominal spindle speed, rev/min; None or <= 0: nothing is removed but mean and trend.
    teeth : int
    refine : bool
        Refine the spindle frequency from the response's harmonic comb (+-``search``).
    threshold_db : float
        Significance of a line over the broadband response at it.
    nperseg : int, optional
        Welch segment of the broadband level (about 0.5 Hz lines by default).
    alias_up_to : float
        Also remove the spindle multiples up to this many times the sampling rate, folded into
        the band (for acquisitions without an anti-aliasing filter); 0.5: none (the default, for
        properly filtered records).
    """
    y = np.array(y, dtype=float, ndmin=2)
    fs = float(sample_rate_hz)
    l, n = y.shape
    t = np.arange(n) / fs
    if spindle_rpm is None or not spindle_rpm > 0:
        res = sps.detrend(y, axis=-1, type="linear")
        z = np.zeros((l, 0))
        return ResponseHarmonics(0.0, 0.0, int(teeth), np.zeros(0), np.zeros(0, bool), z, z, np.zeros(0, bool), res,
                                 np.zeros(0, bool))
    nominal = float(spindle_rpm) / 60.0
    f0 = refine_spindle_frequency(y, fs, nominal, search=search) if refine else nominal
    freqs, tooth = harmonic_frequencies(f0, teeth, 0.5 * fs)
    aliased = np.zeros(freqs.size, dtype=bool)
    if alias_up_to > 0.5:
        # spindle multiples above Nyquist fold back when the acquisition has no anti-aliasing filter
        # (the Hurco files: 1650 Hz sampling, 600 Hz tooth lines, so their multiples land on every
        # 50 Hz); fold them and keep those not within 1/T of a line already there
        high, high_tooth = harmonic_frequencies(f0, teeth, alias_up_to * fs)
        high, high_tooth = high[freqs.size:], high_tooth[freqs.size:]
        folded = np.abs(high - fs * np.round(high / fs))
        tol = 1.0 / (n / fs)
        extra = []
        for fa, tp in zip(folded, high_tooth):
            taken = np.concatenate([freqs, [e[0] for e in extra]])
            if tol < fa < 0.5 * fs - tol and np.min(np.abs(taken - fa)) > tol:
                extra.append((fa, tp))
        if extra:
            freqs = np.concatenate([freqs, [e[0] for e in extra]])
            tooth = np.concatenate([tooth, [e[1] for e in extra]])
            aliased = np.concatenate([aliased, np.ones(len(extra), dtype=bool)])
    basis = harmonic_basis(t, freqs, trend=True)
    coef = lstsq_normal(basis, y.T)  # (n_cols, l)
    res = y - (basis @ coef).T
    amp = (coef[2::2] - 1j * coef[3::2]).T  # (l, n_h)
    nperseg = int(nperseg or min(n, int(2 ** np.round(np.log2(2.0 * fs)))))
    f, p = sps.welch(res, fs=fs, nperseg=nperseg, axis=-1)
    df = f[1] - f[0]
    noise = np.zeros((l, freqs.size))
    for k, fh in enumerate(freqs):
        ring = (np.abs(f - fh) > 1.5 * df) & (np.abs(f - fh) <= 6.5 * df) & (f > 1.5 * df)
        level = np.median(p[:, ring], axis=1) if np.any(ring) else np.interp(fh, f, p[0]) * np.ones(l)
        noise[:, k] = np.sqrt(2.0 * level / (n / fs))
    snr = np.abs(amp) / np.maximum(noise, np.finfo(float).tiny)
    significant = np.any(snr ** 2 > 10.0 ** (threshold_db / 10.0), axis=0)
    return ResponseHarmonics(f0, nominal, int(teeth), freqs, tooth, amp, noise, significant, res, aliased)
