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

A spindle under load does not turn at a perfectly constant speed: a 0.5 % ramp over 20 s moves the
90 Hz tooth line by 0.45 Hz, nine times the notch, and a fixed sinusoid then captures a fraction of
the line (audit of session 15: every stiffness 2-3 times too high, "trusted"). So each record's
strongest tooth line is first checked for steadiness (:func:`line_steadiness`: its complex
amplitude fitted on :data:`STEADY_SEGMENTS` segments must agree within their noise). When it is
not, the spindle phase is tracked (computed order tracking: the line is demodulated in a
``+-TRACK_HALF_BAND_HZ`` band, its phase unwrapped and smoothed by a spline with knots every
:data:`TRACK_KNOT_S`) and all lines are fitted as orders ``k theta(t)`` of the tracked angle; the
tracked fit is kept when it makes the line steady (or steadier). Records whose lines are steady at
a fixed frequency are fitted exactly as before. What stays unsteady (a cut over part of the record,
a line whose amplitude changes) is reported in ``ResponseHarmonics.steady``; the cutting part of a
record is found from the tooth line's envelope by :func:`cutting_window`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import interpolate
from scipy import signal as sps
from scipy import stats

from .._arrays import readonly as _ro
from ..harmonics import fit_angle_orders, harmonic_frequencies, refine_spindle_frequency

__all__ = ["ResponseHarmonics", "remove_response_harmonics", "at_milling_line", "line_steadiness", "cutting_window",
           "strongest_line_hz"]

#: A pole within this relative distance of a milling line and less damped than
#: :data:`HARMONIC_MAX_DAMPING` is taken for the line (:func:`at_milling_line`).
HARMONIC_TOLERANCE = 0.005
HARMONIC_MAX_DAMPING = 0.01
#: Segments of the steadiness check of the strongest tooth line (:func:`line_steadiness`).
STEADY_SEGMENTS = 8
#: The segments' amplitudes are unsteady when their chi-square about the mean (``2 (S - 1)``
#: degrees of freedom) has a p-value below this AND they differ materially: the whole-record
#: amplitude is below the mean segment magnitude by more than :data:`STEADY_MAX_LOSS`, or the
#: magnitudes spread by more than :data:`STEADY_MAX_SPREAD` (relative sd). Constant-speed records
#: of the benchmark: loss < 0.5 %, spread < 3 %; a 0.5 % ramp: loss 50-70 %.
STEADY_P_VALUE = 1e-3
STEADY_MAX_LOSS = 0.03
STEADY_MAX_SPREAD = 0.10
#: Half-width of the demodulation band of the tracked line, Hz, and the knot spacing of the
#: spline that smooths its phase, s.
TRACK_HALF_BAND_HZ = 1.0
TRACK_KNOT_S = 1.0
#: :func:`cutting_window` looks for the cut only where the tooth line's envelope (its 90th
#: percentile) stands this many times over the noise's beside it (midway between the spindle's
#: harmonics): under that the noise alone crosses half the line's level. Session 23: displacement
#: records of the benchmark's cell, cutting throughout, stood 2.5 times over and were cut to 27-73 %
#: of their length in 6 of 8; their accelerations stand 25 times over.
WINDOW_LINE_TO_NOISE = 5.0


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
    tracked : bool
        The lines were fitted as orders of a tracked spindle angle (the speed varied); ``freq_hz``
        are then the mean frequencies.
    steady : bool
        The strongest tooth line's amplitude is steady over the record (:func:`line_steadiness`).
    steadiness : dict
        What :func:`line_steadiness` found for that line (``line_hz``, ``chi2``, ``p_value``,
        ``loss``, ``spread``; empty without lines).
    speed_variation : float
        Peak-to-peak relative variation of the tracked spindle speed (0 when not tracked).
    orders, signs : ndarray, shape (n_h,)
        Each line as an order of the spindle angle (a folded line's order is that of the multiple
        that folded) and the sign of its fold (-1 where ``h f0 - k fs`` is negative).
    angle_deviation_rad : ndarray, shape (n,), or None
        The tracked spindle angle's deviation from ``2 pi f0 t`` over the record; None when not
        tracked. With ``orders`` and ``signs`` it is the basis the lines were fitted in
        (:meth:`line_amplitudes`).
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
    tracked: bool = False
    steady: bool = True
    steadiness: dict = field(default_factory=dict, repr=False)
    speed_variation: float = 0.0
    orders: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    signs: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    angle_deviation_rad: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "freq_hz", _ro(self.freq_hz))
        object.__setattr__(self, "tooth_passing", _ro(self.tooth_passing, bool))
        object.__setattr__(self, "amplitude", _ro(self.amplitude, complex))
        object.__setattr__(self, "noise_amplitude", _ro(self.noise_amplitude))
        object.__setattr__(self, "significant", _ro(self.significant, bool))
        object.__setattr__(self, "residual", _ro(self.residual))
        object.__setattr__(self, "aliased", _ro(self.aliased, bool))
        object.__setattr__(self, "orders", _ro(self.orders, int))
        object.__setattr__(self, "signs", _ro(self.signs))
        if self.angle_deviation_rad is not None:
            object.__setattr__(self, "angle_deviation_rad", _ro(self.angle_deviation_rad))

    @property
    def found_hz(self) -> np.ndarray:
        return self.freq_hz[self.significant]

    def line_amplitudes(self, x, sample_rate_hz: float) -> np.ndarray:
        """Complex amplitudes (l, n_h) of these lines in another signal ``x`` (l, n) of the same
        record and span (a measured force): fitted in the basis the response's lines were, with the
        trend (:func:`oma.harmonics.fit_angle_orders`)."""
        x = np.array(x, dtype=float, ndmin=2)
        t = np.arange(x.shape[1]) / float(sample_rate_hz)
        coef, _ = fit_angle_orders(x, t, _angle(t, self.spindle_hz, self.angle_deviation_rad), self.orders,
                                   self.signs, with_fit=False)
        return (coef[2::2] - 1j * coef[3::2]).T

    def to_dict(self) -> dict:
        return {"spindle_hz": float(self.spindle_hz), "nominal_spindle_hz": float(self.nominal_spindle_hz),
                "teeth": int(self.teeth), "found_hz": [float(f) for f in self.found_hz],
                "tracked": bool(self.tracked), "steady": bool(self.steady),
                "speed_variation": float(self.speed_variation)}


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
    f0 = refine_spindle_frequency(y, fs, nominal, search=search, lines_only=True) if refine else nominal
    freqs, tooth, aliased, orders, sign = _line_set(f0, teeth, fs, n, alias_up_to)
    nperseg = int(nperseg or min(n, int(2 ** np.round(np.log2(2.0 * fs)))))
    fit = _fit_lines(y, t, fs, freqs, f0, None, orders, sign, nperseg)
    strongest = _strongest_tooth(fit, tooth, aliased)
    if strongest is not None and not np.any(np.abs(fit[1][:, strongest]) ** 2
                                            > 10.0 ** (threshold_db / 10.0) * fit[2][:, strongest] ** 2):
        strongest = None  # no tooth line stands out (a wrong nominal speed): nothing to check or track
    steadiness = line_steadiness(y, t, freqs, None, orders, sign, strongest, fit[2][:, strongest], spindle_hz=f0) \
        if strongest is not None else {}
    tracked, variation, dphi = False, 0.0, None
    if steadiness and not steadiness["steady"] and steadiness["loss"] > STEADY_MAX_LOSS:
        # the phase wanders (a constant amplitude that changes over the record is not helped by it)
        got = _track_phase(y, fs, f0 * orders[strongest], int(orders[strongest]))
        if got is not None:
            df0, dphi_t = got
            f0_t = f0 + df0
            lines_t = _line_set(f0_t, teeth, fs, n, alias_up_to)
            if lines_t[0].size == freqs.size:
                fit_t = _fit_lines(y, t, fs, lines_t[0], f0_t, dphi_t, lines_t[3], lines_t[4], nperseg)
                steady_t = line_steadiness(y, t, lines_t[0], dphi_t, lines_t[3], lines_t[4], strongest,
                                           fit_t[2][:, strongest], spindle_hz=f0_t)
                if steady_t["loss"] < steadiness["loss"] and (steady_t["steady"] or steady_t["chi2"] < steadiness["chi2"]):
                    fit, steadiness, tracked, dphi = fit_t, steady_t, True, dphi_t
                    f0, (freqs, tooth, aliased, orders, sign) = f0_t, lines_t
                    rate = f0 + np.gradient(dphi, t) / (2.0 * np.pi)
                    variation = float(np.ptp(rate) / f0)
    res, amp, noise = fit
    snr = np.abs(amp) / np.maximum(noise, np.finfo(float).tiny)
    significant = np.any(snr ** 2 > 10.0 ** (threshold_db / 10.0), axis=0)
    return ResponseHarmonics(f0, nominal, int(teeth), freqs, tooth, amp, noise, significant, res, aliased,
                             tracked=tracked, steady=bool(steadiness.get("steady", True)), steadiness=steadiness,
                             speed_variation=variation, orders=orders, signs=sign, angle_deviation_rad=dphi)


def _angle(t, f0, dphi):
    """The spindle angle ``2 pi f0 t + dphi`` (rad) whose orders the lines are; ``dphi`` (the
    tracked angle's deviation) None: 0."""
    return 2.0 * np.pi * f0 * np.asarray(t) + (0.0 if dphi is None else dphi)


def _fit_lines(y, t, fs, freqs, f0, dphi, orders, sign, nperseg):
    """Residual, complex amplitudes (l, n_h) and their noise sd (l, n_h) of the lines ``freqs``,
    orders ``orders`` with signs ``sign`` of the spindle angle of frequency ``f0``
    (:func:`oma.harmonics.fit_angle_orders`: :func:`oma.harmonics.harmonic_basis`'s columns at the
    lines' frequencies, without forming them)."""
    l, n = y.shape
    coef, fitted = fit_angle_orders(y, t, _angle(t, f0, dphi), orders, sign)
    res = y - fitted
    amp = (coef[2::2] - 1j * coef[3::2]).T  # (l, n_h)
    f, p = sps.welch(res, fs=fs, nperseg=nperseg, axis=-1)
    df = f[1] - f[0]
    noise = np.zeros((l, freqs.size))
    for k, fh in enumerate(freqs):
        ring = (np.abs(f - fh) > 1.5 * df) & (np.abs(f - fh) <= 6.5 * df) & (f > 1.5 * df)
        level = np.median(p[:, ring], axis=1) if np.any(ring) else np.interp(fh, f, p[0]) * np.ones(l)
        noise[:, k] = np.sqrt(2.0 * level / (n / fs))
    return res, amp, noise


def _strongest_tooth(fit, tooth, aliased):
    """Index of the tooth line with the largest signal-to-noise ratio over the channels (None: none)."""
    _, amp, noise = fit
    cand = np.flatnonzero(tooth & ~aliased)
    if cand.size == 0:
        return None
    snr = np.sum(np.abs(amp[:, cand]) ** 2 / np.maximum(noise[:, cand], np.finfo(float).tiny) ** 2, axis=0)
    return int(cand[np.argmax(snr)])


def line_steadiness(y, t, freqs, dphi, orders, sign, line: int, noise_sd, *, spindle_hz: float,
                    segments: int = STEADY_SEGMENTS) -> dict:
    """Whether line ``line``'s complex amplitude is the same on ``segments`` parts of the record.

    All lines are refitted on each segment (the basis of :func:`remove_response_harmonics`: orders
    ``orders`` and signs ``sign`` of the angle of frequency ``spindle_hz``, tracked when ``dphi`` is
    given). With ``a_s`` the segment amplitudes (per channel) and ``sigma_s`` their
    noise (the whole record's noise ``noise_sd`` times ``sqrt(S)``), ``chi2 = sum |a_s - mean|^2 /
    (sigma_s^2 / 2)`` has ``2 (S - 1)`` degrees of freedom per channel for a steady line. ``loss``:
    1 - |whole-record amplitude| / mean |a_s| (phase wander: the coherent fit captures less than the
    line); ``spread``: relative sd of ``|a_s|`` (the amplitude changes: a cut over part of the
    record). Channels weighted by their line power.

    Returns
    -------
    dict
        ``line_hz``, ``chi2``, ``dof``, ``p_value``, ``loss``, ``spread``, ``steady`` (see
        :data:`STEADY_P_VALUE`, :data:`STEADY_MAX_LOSS`, :data:`STEADY_MAX_SPREAD`).
    """
    l, n = y.shape
    edges = np.linspace(0, n, segments + 1).astype(int)
    seg_amp = np.zeros((l, segments), dtype=complex)
    for s in range(segments):
        sl = slice(edges[s], edges[s + 1])
        coef, _ = fit_angle_orders(y[:, sl], t[sl], _angle(t[sl], spindle_hz, None if dphi is None else dphi[sl]),
                                   orders, sign, with_fit=False)
        seg_amp[:, s] = coef[2 + 2 * line] - 1j * coef[3 + 2 * line]
    sigma = np.maximum(np.asarray(noise_sd, float), np.finfo(float).tiny) * np.sqrt(segments)
    mean = seg_amp.mean(axis=1)
    chi2 = float(np.sum(np.abs(seg_amp - mean[:, None]) ** 2 / (sigma[:, None] ** 2 / 2.0)))
    dof = 2 * (segments - 1) * l
    p = float(stats.chi2.sf(chi2, dof))
    power = np.sum(np.abs(seg_amp) ** 2, axis=1)
    wgt = power / max(power.sum(), np.finfo(float).tiny)
    mag = np.abs(seg_amp)
    loss = float(np.sum(wgt * (1.0 - np.abs(mean) / np.maximum(mag.mean(axis=1), np.finfo(float).tiny))))
    spread = float(np.sum(wgt * mag.std(axis=1) / np.maximum(mag.mean(axis=1), np.finfo(float).tiny)))
    steady = not (p < STEADY_P_VALUE and (loss > STEADY_MAX_LOSS or spread > STEADY_MAX_SPREAD))
    return {"line_hz": float(freqs[line]), "chi2": chi2, "dof": dof, "p_value": p, "loss": loss, "spread": spread,
            "steady": bool(steady)}


def _baseband(y, fs, line_hz, half_band_hz=TRACK_HALF_BAND_HZ):
    """The line demodulated to 0 Hz and low-passed (zero phase) to ``half_band_hz``: (l, n) complex."""
    n = y.shape[1]
    t = np.arange(n) / fs
    z = sps.detrend(y, axis=-1, type="linear") * np.exp(-2j * np.pi * line_hz * t)[None, :]
    sos = sps.butter(4, half_band_hz, fs=fs, output="sos")
    return sps.sosfiltfilt(sos, z.real, axis=-1) + 1j * sps.sosfiltfilt(sos, z.imag, axis=-1)


def _track_phase(y, fs, line_hz, order):
    """Correction of the spindle frequency (Hz) and the spindle angle's deviation from
    ``2 pi (f0 + correction) t`` (rad, shape (n,)) from line ``line_hz`` (spindle order
    ``order``): the channels' basebands combined along their principal direction, the phase
    unwrapped and smoothed by a least-squares cubic spline weighted by the line's power; None when
    the record is too short for two knots."""
    n = y.shape[1]
    t = np.arange(n) / fs
    z = _baseband(y, fs, line_hz)
    u, s, vh = np.linalg.svd(z, full_matrices=False)
    v = s[0] * vh[0]
    phase = np.unwrap(np.angle(v))
    w = np.abs(v) ** 2
    w = w / max(w.max(), np.finfo(float).tiny) + 1e-6
    n_knots = int(np.floor(t[-1] / TRACK_KNOT_S))
    if n_knots < 2:
        return None
    inner = np.linspace(t[0], t[-1], n_knots + 1)[1:-1]
    knots = np.concatenate([[t[0]] * 4, inner, [t[-1]] * 4])
    spline = interpolate.make_lsq_spline(t, phase, knots, k=3, w=w)
    smooth = spline(t)
    # the mean rate goes into the spindle frequency (the comb may have picked a sideband of a
    # wandering line), the rest is the angle's deviation from it
    slope, icpt = np.polyfit(t, smooth, 1, w=np.sqrt(w))
    return slope / (2.0 * np.pi * order), (smooth - slope * t - icpt) / order


def cutting_window(y, sample_rate_hz: float, spindle_rpm: float, teeth: int, *, threshold: float = 0.5,
                   min_gap_s: float = 1.0, info: dict | None = None):
    """The part of a record during which the tool cuts, from its strongest tooth line's envelope.

    The line is demodulated (``+-TRACK_HALF_BAND_HZ``) at the refined tooth frequency; the cut is
    the longest stretch where the envelope exceeds ``threshold`` times its 90th percentile, less
    the filter's settling (``0.5 / TRACK_HALF_BAND_HZ``) at each end. Only where the line stands
    :data:`WINDOW_LINE_TO_NOISE` times over the noise's envelope beside it (the same demodulation
    half a spindle frequency off, on both sides).

    Returns
    -------
    (int, int) or None
        Sample range ``[start, stop)``; None when the tool cuts throughout (nothing shorter by more
        than ``min_gap_s`` in all), there is no tooth line, or the line is too weak to tell
        (``info['line_to_noise']``, when ``info`` is given, says how weak).
    """
    y = np.array(y, dtype=float, ndmin=2)
    fs = float(sample_rate_hz)
    if spindle_rpm is None or not spindle_rpm > 0 or y.shape[1] < 4 * fs / TRACK_HALF_BAND_HZ:
        return None
    f0 = refine_spindle_frequency(y, fs, float(spindle_rpm) / 60.0, lines_only=True)
    freqs, tooth = harmonic_frequencies(f0, teeth, 0.45 * fs)
    if not np.any(tooth):
        return None
    best, best_e, best_hz = None, -1.0, np.nan
    for fh in freqs[tooth][:4]:
        e = np.sqrt(np.sum(np.abs(_baseband(y, fs, fh)) ** 2, axis=0))
        score = float(np.percentile(e, 90))
        if score > best_e:
            best, best_e, best_hz = e, score, fh
    noise = max(float(np.percentile(np.sqrt(np.sum(np.abs(_baseband(y, fs, best_hz + d)) ** 2, axis=0)), 90))
                for d in (-0.5 * f0, 0.5 * f0))
    ratio = best_e / max(noise, np.finfo(float).tiny)
    if info is not None:
        info["line_to_noise"] = ratio
    if ratio < WINDOW_LINE_TO_NOISE:
        return None
    on = best > threshold * best_e
    settle = int(round(0.5 * fs / TRACK_HALF_BAND_HZ))
    # the filter's own transient at the record's ends is no gap in the cut
    on[:settle], on[-settle:] = on[settle], on[-settle - 1]
    # longest run of samples above the threshold
    d = np.diff(np.concatenate([[0], on.astype(int), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    if starts.size == 0:
        return None
    j = int(np.argmax(stops - starts))
    a = starts[j] + (settle if starts[j] > 0 else 0)
    b = stops[j] - (settle if stops[j] < y.shape[1] else 0)
    if b - a < y.shape[1] / 4 or (y.shape[1] - (b - a)) < min_gap_s * fs:
        return None
    return int(a), int(b)


def strongest_line_hz(y, sample_rate_hz: float, center_hz: float, *, relative: float = 0.3):
    """Frequency and width of the strongest spectral peak within ``+-relative`` of ``center_hz``:
    ``(peak_hz, width_hz)``, the width where the (summed) Welch spectrum stays above half the peak
    (0.25 Hz resolution); a steady line is about two bins wide, a wandering speed smears it."""
    y = np.array(y, dtype=float, ndmin=2)
    y = y[~np.any(np.isnan(y), axis=1)]
    fs = float(sample_rate_hz)
    nper = min(y.shape[1], int(2 ** np.round(np.log2(4.0 * fs))))
    f, p = sps.welch(sps.detrend(y, axis=-1), fs=fs, nperseg=nper, axis=-1)
    p = p.sum(axis=0)
    band = (f >= center_hz * (1 - relative)) & (f <= min(center_hz * (1 + relative), 0.5 * fs))
    if not np.any(band):
        return float("nan"), float("nan")
    idx = np.flatnonzero(band)
    k = int(idx[np.argmax(p[idx])])
    lo = hi = k
    while lo > 0 and p[lo - 1] > 0.5 * p[k]:
        lo -= 1
    while hi < p.size - 1 and p[hi + 1] > 0.5 * p[k]:
        hi += 1
    return float(f[k]), float(f[hi] - f[lo] + (f[1] - f[0]))


def _line_set(f0, teeth, fs, n, alias_up_to):
    """Spindle multiples of ``f0`` below the Nyquist frequency, and with ``alias_up_to > 0.5`` the
    folded ones (:func:`remove_response_harmonics`): frequencies, tooth-passing, aliased, spindle
    orders, and the sign of each line's phase in the spindle angle (-1: folded with a sign flip)."""
    freqs, tooth = harmonic_frequencies(f0, teeth, 0.5 * fs)
    aliased = np.zeros(freqs.size, dtype=bool)
    orders = np.arange(1, freqs.size + 1)
    sign = np.ones(freqs.size)
    if alias_up_to > 0.5:
        # spindle multiples above Nyquist fold back when the acquisition has no anti-aliasing filter
        # (the Hurco files: 1650 Hz sampling, 600 Hz tooth lines, so their multiples land on every
        # 50 Hz); fold them and keep those not within 1/T of a line already there
        high, high_tooth = harmonic_frequencies(f0, teeth, alias_up_to * fs)
        k_high = np.arange(1, high.size + 1)[freqs.size:]
        high, high_tooth = high[freqs.size:], high_tooth[freqs.size:]
        signed = high - fs * np.round(high / fs)
        folded = np.abs(signed)
        tol = 1.0 / (n / fs)
        extra = []
        for fa, tp, k, sg in zip(folded, high_tooth, k_high, np.sign(signed)):
            taken = np.concatenate([freqs, [e[0] for e in extra]])
            if tol < fa < 0.5 * fs - tol and np.min(np.abs(taken - fa)) > tol:
                extra.append((fa, tp, k, sg))
        if extra:
            freqs = np.concatenate([freqs, [e[0] for e in extra]])
            tooth = np.concatenate([tooth, [e[1] for e in extra]])
            aliased = np.concatenate([aliased, np.ones(len(extra), dtype=bool)])
            orders = np.concatenate([orders, [e[2] for e in extra]])
            sign = np.concatenate([sign, [e[3] for e in extra]])
    return freqs, tooth, aliased, orders.astype(int), sign
