"""Tool-tip displacement of a modal model driven by a measured force (part (b) of the comparison).

Each mode ``r`` is the oscillator ``q_r'' + 2 zeta_r w_r q_r' + w_r^2 q_r = w_r^2 (u_r . F) / k_r``
(unit static gain from ``u_r . F / k_r`` to ``q_r``); the tool tip moves ``sum_r u_r q_r +
residual_compliance @ F`` (formats.md, "Modal model"). Each mode is discretised with a first-order
hold, exact for an input piecewise linear between samples (Franklin, Powell & Workman, Digital
Control of Dynamic Systems, 3rd ed., 1998, sec. 6.3); a measured force is band-limited instead, so
the filter is driven by its samples equalised for the hold (:func:`oma.synthetic.hold_equalised`:
the hold alone answers ``sinc^2(f / fs)`` short, 26 % at a mode at 0.3 fs, session 20).

The modal parameters may change along the record (pose drift): they are then piecewise constant
over segments, and the state carries over from one segment to the next through the last two
samples of each mode's displacement.

Free-response columns (:func:`free_response_basis`) let a fit absorb the unknown initial state of
the structure at the start of a record without touching the model.

Modes above the record's band. Records are low-pass filtered before sampling (the simulator's
anti-alias filter, 8th order per pass at ``0.4 fs``): the sampled force is band-limited, and a
mode above ``0.4 fs`` (a spindle/tool mode at 720 Hz in a 1 kHz record) shows in the record only
through its response in the band, nearly its static compliance. Its first-order-hold filter would
instead put a resonance at its alias ``fs - f_n`` (720 Hz at 1 kHz: a threefold peak at 280 Hz,
where the true response is 1.18 times static): such modes (:func:`resolved_modes`) respond by
their frequency response over the band (:func:`band_limited_mode_response`), and the record
cannot tell their frequency, damping or direction (a diagnosis holds them as given).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import fft as spfft
from scipy import signal as sps

from oma.modal import ModalModel
from oma.synthetic import hold_equalised
from stability.simulate import ANTI_ALIAS_FRACTION

__all__ = ["mode_filter", "modal_response", "free_response_basis", "apply_delay", "unit_mode_response", "Delayer",
           "visible_band_hz", "resolved_modes", "views_band_hz", "band_limited_mode_response"]

#: Highest frequency a record shows, as a fraction of its sample rate: the cut-off of the
#: anti-alias filter records are taken through (the simulator's, ``ANTI_ALIAS_FRACTION``); the
#: Nyquist frequency is 0.5.
BAND_FRACTION = ANTI_ALIAS_FRACTION
#: Memory of a band-limited mode response, in time constants ``1 / (zeta w)`` (e^-8 = 3e-4).
_MEMORY_TIME_CONSTANTS = 8.0


def visible_band_hz(sample_rate_hz: float) -> float:
    """Highest frequency a record sampled at ``sample_rate_hz`` shows at all, Hz (``0.4 fs``, the
    anti-alias filter's cut-off).

    Above it the record's anti-alias filter has removed the signal (gain 0.5 at ``0.4 fs``,
    0.03 at the Nyquist frequency ``0.5 fs``): a mode whose resonance lies there cannot be
    identified, turned or drifted from the record. Not :func:`oma.timefit.resolved_band_hz`
    (``0.3 fs``, where the filter is flat to 1 %: the band identification fits modes in).
    """
    return BAND_FRACTION * float(sample_rate_hz)


def views_band_hz(views) -> float:
    """The band every one of ``views`` (objects with ``sample_rate_hz``) resolves, Hz: the smallest
    :func:`visible_band_hz` (``inf`` for none)."""
    return min((visible_band_hz(v.sample_rate_hz) for v in views), default=math.inf)


def resolved_modes(model: ModalModel, sample_rate_hz: float) -> np.ndarray:
    """Which modes of ``model`` lie inside the band a record resolves, shape (n_modes,) of bool."""
    return np.asarray(model.natural_frequency_hz, dtype=float) <= visible_band_hz(sample_rate_hz)


def band_limited_mode_response(p, natural_frequency_hz: float, damping_ratio: float, sample_rate_hz: float,
                               *, initial_value=0.0) -> np.ndarray:
    """``w^2 / (s^2 + 2 zeta w s + w^2)`` acting on a band-limited sampled input, by its frequency response.

    For a mode above the record's band (module notes): the input is taken as band-limited (filtered
    before sampling), so the sampled output is the input's DFT times the mode's frequency response
    up to the Nyquist frequency, with no alias of the resonance. The input is extended before its
    start by ``initial_value`` (the mode in static equilibrium with it) and after its end by its
    last sample, each over ``8`` time constants of the mode, so that the circular convolution of
    the DFT does not reach the record.

    Parameters
    ----------
    p : array_like, shape (..., n)
        Input (unit static gain), any unit.
    natural_frequency_hz, damping_ratio : float
    sample_rate_hz : float
    initial_value : float or array_like, shape (...)
        Input before the record start.

    Returns
    -------
    ndarray, shape (..., n)
    """
    p = np.asarray(p, dtype=float)
    n = p.shape[-1]
    fs = float(sample_rate_hz)
    fn, zeta = float(natural_frequency_hz), float(damping_ratio)
    tau = 1.0 / (max(zeta, 1e-3) * 2.0 * math.pi * fn)
    pad = int(min(max(math.ceil(_MEMORY_TIME_CONSTANTS * tau * fs), 16), 4 * max(n, 1)))
    left = np.broadcast_to(np.asarray(initial_value, dtype=float)[..., None], p.shape[:-1] + (pad,))
    right = np.broadcast_to(p[..., -1:], p.shape[:-1] + (pad,))
    x = np.concatenate([left, p, right], axis=-1)
    n_fft = spfft.next_fast_len(x.shape[-1], real=True)
    r = np.fft.rfftfreq(n_fft, 1.0 / fs) / fn
    g = 1.0 / (1.0 - r**2 + 2j * zeta * r)
    y = np.fft.irfft(np.fft.rfft(x, n=n_fft, axis=-1) * g, n=n_fft, axis=-1)
    return y[..., pad:pad + n]


def mode_filter(natural_frequency_hz, damping_ratio, sample_rate_hz: float):
    """Discrete filters ``(b, a)`` of ``w^2 / (s^2 + 2 zeta w s + w^2)`` with first-order hold.

    Unit static gain: a constant input ``p`` gives ``q = p``. Vectorised over the (broadcast)
    frequencies and damping ratios (``zeta >= 1``, an overdamped mode, by state-space discretisation). Closed form of the triangle-hold equivalent
    ``H(z) = (z - 1)^2 / (T z) Z{G(s) / s^2}`` (Franklin, Powell & Workman, sec. 6.3.2) with the
    partial fractions ``G / s^2 = 1/s^2 - (2 zeta / w) / s + ((2 zeta / w) s + 4 zeta^2 - 1) /
    (s^2 + 2 zeta w s + w^2)``.

    Returns
    -------
    b, a : ndarray, shape (..., 3)
        Numerator and denominator coefficients in powers of ``z^-1``.
    """
    w = 2.0 * np.pi * np.asarray(natural_frequency_hz, dtype=float)
    zeta = np.asarray(damping_ratio, dtype=float)
    w, zeta = np.broadcast_arrays(w, zeta)
    if np.any(zeta < 0.0):
        raise ValueError("mode_filter needs damping_ratio >= 0")
    if np.any(zeta >= 1.0):
        # an overdamped mode (a robot model's, from large joint damping): the same first-order-hold
        # filter by state-space discretisation, element by element (the closed form needs zeta < 1)
        from oma.synthetic import mode_filter as unit_mass_filter

        under = np.where(zeta < 1.0, zeta, 0.5)
        b, a = mode_filter(w / (2.0 * np.pi), under, sample_rate_hz)
        for idx in zip(*np.nonzero(zeta >= 1.0)):
            bo, ao = unit_mass_filter(w[idx] / (2.0 * np.pi), zeta[idx], sample_rate_hz)
            b[idx], a[idx] = w[idx] ** 2 * bo / ao[0], ao / ao[0]
        return b, a
    t = 1.0 / float(sample_rate_hz)
    wd = w * np.sqrt(1.0 - zeta**2)
    r = np.exp(-zeta * w * t)
    c, s = np.cos(wd * t), np.sin(wd * t)
    b_ = -2.0 * zeta / w
    c_ = 2.0 * zeta / w
    d_ = 4.0 * zeta**2 - 1.0
    e_ = (d_ - c_ * zeta * w) / wd
    k_ = -c_ * r * c + e_ * r * s
    n2 = 1.0 - b_ / t - 2.0 * r * c * b_ / t + (k_ - 2.0 * c_) / t
    n1 = -(1.0 - b_ / t) * 2.0 * r * c + b_ * r**2 / t + (c_ - 2.0 * k_) / t
    n0 = (1.0 - b_ / t) * r**2 + k_ / t
    b = np.stack([n2, n1, n0], axis=-1)
    a = np.stack([np.ones_like(r), -2.0 * r * c, r**2], axis=-1)
    return b, a


def _steady_state_zi(b, a, u0):
    """Direct-form-II-transposed state of a unit-gain 2nd-order filter at rest with input ``u0``."""
    z1 = (b[2] - a[2]) * u0
    return np.array([(b[1] - a[1]) * u0 + z1, z1])


def _continuation_zi(b, a, y_past, x_past):
    """State reproducing the past two outputs ``y[-1], y[-2]`` and inputs (as ``lfiltic``)."""
    return np.array([b[1] * x_past[0] + b[2] * x_past[1] - a[1] * y_past[0] - a[2] * y_past[1],
                     b[2] * x_past[0] - a[2] * y_past[0]])


def _mode_output(p, b_seg, a_seg, starts, q0):
    """One mode's displacement for input ``p`` (already divided by k), segment-wise filters."""
    n = p.size
    out = np.empty(n)
    bounds = list(starts) + [n]
    for s, (i0, i1) in enumerate(zip(bounds[:-1], bounds[1:])):
        if i1 <= i0:
            continue
        b, a = b_seg[s], a_seg[s]
        if i0 == 0:
            zi = _steady_state_zi(b, a, q0)
        elif i0 >= 2:
            zi = _continuation_zi(b, a, out[i0 - 1:i0 - 3:-1] if i0 >= 3 else out[[1, 0]], p[[i0 - 1, i0 - 2]])
        else:
            zi = _continuation_zi(b, a, [out[0], out[0]], [p[0], p[0]])
        out[i0:i1], _ = sps.lfilter(b, a, p[i0:i1], zi=zi)
    return out


def modal_response(model: ModalModel, force_N, sample_rate_hz: float, *, frequency_scale=None,
                   segment_starts=None, initial: str = "static", initial_samples: int | None = None) -> np.ndarray:
    """Displacement of ``model`` driven by ``force_N``.

    Parameters
    ----------
    model : ModalModel
    force_N : array_like, shape (3, n)
        Force on the tool along X, Y, Z, N.
    sample_rate_hz : float
    frequency_scale : array_like, shape (n_segments,), optional
        Every natural frequency inside the record's band is multiplied by ``frequency_scale[s]``
        in segment ``s`` (modal mass and damping ratio kept, so the stiffness scales with its
        square: pose drift). Modes above the band (:func:`resolved_modes`: spindle/tool modes,
        which do not move with the arm's pose) respond by their in-band frequency response
        (:func:`band_limited_mode_response`) and are held as given.
    segment_starts : array_like of int, shape (n_segments,), optional
        First sample of each segment (the first must be 0).
    initial : {'static', 'rest'}
        ``'static'``: start in static equilibrium with the mean force of the first
        ``initial_samples`` samples (default 0.2 s); ``'rest'``: start at rest.

    Returns
    -------
    ndarray, shape (3, n)
        Displacement, m.
    """
    f = np.asarray(force_N, dtype=float)
    if f.ndim != 2 or f.shape[0] != 3:
        raise ValueError(f"force_N has the wrong shape; expected (3, n_samples) instead of {f.shape}")
    if initial not in ("static", "rest"):
        raise ValueError(f"initial must be 'static' or 'rest', not {initial!r}")
    fs = float(sample_rate_hz)
    n = f.shape[1]
    if frequency_scale is None:
        scale = np.ones(1)
        starts = np.zeros(1, dtype=int)
    else:
        scale = np.atleast_1d(np.asarray(frequency_scale, dtype=float))
        starts = np.atleast_1d(np.asarray(segment_starts, dtype=int))
        if starts.shape != scale.shape or starts[0] != 0:
            raise ValueError("segment_starts must start at 0 and match frequency_scale")
    m0 = int(initial_samples) if initial_samples is not None else max(1, int(round(0.2 * fs)))
    f0 = f[:, :m0].mean(axis=1) if initial == "static" else np.zeros(3)
    x = np.asarray(model.residual_compliance_m_N) @ f
    inside = resolved_modes(model, fs)
    # the held filters are driven by the force equalised for their hold: the band-limited force's
    # response (a mode at 0.3 fs responded 26 % short at resonance; session 20). The force itself,
    # once for every mode, not the drift's steps in stiffness below
    held = hold_equalised(f, axis=-1) if np.any(inside) else None
    for fn, zeta, k, u, ok in zip(model.natural_frequency_hz, model.damping_ratio, model.stiffness_N_m,
                                  model.directions, inside):
        if not ok:
            # above the band: its in-band frequency response, never drifted (module notes)
            x += np.outer(u, band_limited_mode_response(u @ f / k, fn, zeta, fs, initial_value=float(u @ f0 / k)))
            continue
        p = u @ held / k
        if scale.size == 1:
            p = p / scale[0] ** 2
        else:
            # stiffness scales with the square of the frequency: k(t) = k s(t)^2
            seg = np.repeat(np.arange(scale.size), np.diff(np.append(starts, n)))
            p = p / scale[seg] ** 2
        b_seg, a_seg = mode_filter(fn * scale, zeta, fs)
        q = _mode_output(p, b_seg, a_seg, starts, float(u @ f0 / k) / scale[0] ** 2)
        x += np.outer(u, q)
    return x


def free_response_basis(model: ModalModel, n_samples: int, sample_rate_hz: float) -> np.ndarray:
    """Free responses of the modes inside the record's band from two initial states, m per unit.

    Shape (3, n_samples, 2 n_resolved). Columns ``2r`` and ``2r + 1`` are ``u_r e^{-zeta w t}
    cos(w_d t)`` and ``u_r e^{-zeta w t} sin(w_d t)``: any initial state of mode ``r`` decays as a
    combination of the two. A mode above the band (:func:`resolved_modes`) is left out: the
    record's anti-alias filter removes its free response, and sampled it would oscillate at its
    alias.
    """
    t = np.arange(int(n_samples)) / float(sample_rate_hz)
    cols = []
    keep = resolved_modes(model, sample_rate_hz)
    for fn, zeta, u in zip(model.natural_frequency_hz[keep], model.damping_ratio[keep], model.directions[keep]):
        w = 2.0 * np.pi * fn
        wd = w * np.sqrt(max(1.0 - zeta**2, 1e-12))
        env = np.exp(-zeta * w * t)
        cols.append(u[:, None] * (env * np.cos(wd * t))[None, :])
        cols.append(u[:, None] * (env * np.sin(wd * t))[None, :])
    if not cols:
        return np.zeros((3, int(n_samples), 0))
    return np.stack(cols, axis=-1)


def apply_delay(x, delay_s: float, sample_rate_hz: float) -> np.ndarray:
    """``x(t - delay)`` by cubic interpolation; samples before the start hold the first value.

    Parameters
    ----------
    x : array_like, shape (n_channels, n)
    delay_s : float
        Positive: the result lags ``x``.
    """
    from scipy.interpolate import CubicSpline

    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    t = np.arange(n) / sample_rate_hz
    spline = CubicSpline(t, x, axis=-1, extrapolate=False)
    tq = np.clip(t - delay_s, t[0], t[-1])
    return spline(tq)


def unit_mode_response(natural_frequency_hz: float, damping_ratio: float, force_N, sample_rate_hz: float, *,
                       initial_samples: int | None = None, held=None) -> np.ndarray:
    """Each force channel through one mode of unit static gain, shape (n_channels, n).

    ``y_j = H_r * F_j`` with ``H_r = w^2 / (s^2 + 2 zeta w s + w^2)``, started in static
    equilibrium with the mean of the first ``initial_samples`` samples (default 0.2 s), as
    :func:`modal_response` does (a mode above the record's band by its in-band frequency
    response, as there; inside it the held filter driven by the force equalised for its hold,
    :func:`oma.synthetic.hold_equalised`, which ``held`` gives when the caller has it). A mode of
    stiffness ``k`` and direction ``u`` then moves the tool tip by ``u (u . y) / k``.
    """
    f = np.array(force_N, dtype=float, ndmin=2)
    fs = float(sample_rate_hz)
    m0 = int(initial_samples) if initial_samples is not None else max(1, int(round(0.2 * fs)))
    if natural_frequency_hz > visible_band_hz(fs):
        return band_limited_mode_response(f, natural_frequency_hz, damping_ratio, fs,
                                          initial_value=f[:, :m0].mean(axis=1))
    b, a = mode_filter(natural_frequency_hz, damping_ratio, fs)
    zi = _steady_state_zi(b, a, f[:, :m0].mean(axis=1))  # (2, n_channels)
    held = hold_equalised(f, axis=-1) if held is None else np.array(held, dtype=float, ndmin=2)
    out, _ = sps.lfilter(b, a, held, axis=-1, zi=zi.T)
    return out


class Delayer:
    """``x(t - delay)`` of fixed signals for many delays (one spline, built once)."""

    def __init__(self, x, sample_rate_hz: float):
        from scipy.interpolate import CubicSpline

        self.x = np.asarray(x, dtype=float)
        self.t = np.arange(self.x.shape[-1]) / float(sample_rate_hz)
        self.spline = CubicSpline(self.t, self.x, axis=-1, extrapolate=False)

    def __call__(self, delay_s: float) -> np.ndarray:
        return self.spline(np.clip(self.t - delay_s, self.t[0], self.t[-1]))
