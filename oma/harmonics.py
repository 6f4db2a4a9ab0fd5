"""Milling harmonics: where they are, how to take them out, and the background force left.

Stable milling forces are periodic in the spindle revolution: lines at multiples of the spindle
frequency ``f_s = rpm / 60`` (the tooth-passing lines ``teeth * f_s`` and their multiples are the
strong ones; the others come from runout). They are forced response and are kept out of the FRF
estimate; the broadband rest of the force (the background) is what excites the structure's free
response (Nguyen & Melkote 2020; Brincker & Ventura, Introduction to Operational Modal Analysis,
2015, on harmonics in OMA).

The nominal spindle speed of a record can be off by a few percent (controller override, spindle
slip); the spindle frequency is refined by maximising the energy of the whole harmonic comb in the
force spectrum, which locates it to a fraction of the line spacing because the comb has many teeth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._arrays import readonly as _ro
from scipy import ndimage, optimize
from scipy import signal as sps

from ._linalg import lstsq_normal
from .spectra import default_nperseg

__all__ = [
    "Harmonics",
    "harmonic_frequencies",
    "refine_spindle_frequency",
    "find_harmonics",
    "harmonic_line_mask",
    "remove_harmonic_lines",
    "background_variance",
    "BackgroundEstimate",
    "fit_harmonic_signal",
    "fit_angle_orders",
]


def harmonic_frequencies(spindle_hz: float, teeth: int, max_hz: float):
    """Multiples of the spindle frequency up to ``max_hz`` (excluded), and which are tooth lines.

    Returns
    -------
    freq_hz : ndarray, shape (n,)
        ``h * spindle_hz`` for ``h = 1, 2, ...``.
    tooth_passing : ndarray of bool, shape (n,)
        True where ``h`` is a multiple of ``teeth``.
    """
    if spindle_hz <= 0:
        raise ValueError(f"spindle_hz must be positive, not {spindle_hz!r}")
    h = np.arange(1, int(np.floor(max_hz / spindle_hz - 1e-12)) + 1)
    return h * spindle_hz, (h % max(int(teeth), 1)) == 0


def _comb_energy(x_windowed, sample_rate_hz, f0, max_hz):
    """Energy of the DFT of the windowed signals at the multiples of ``f0``, ``sum_h |X(h f0)|^2``.

    The harmonics' phasors come from :func:`_angle_powers` (a few signal lengths of memory). They
    used to be the (n_h, n) matrix of all of them: at 10 kHz over 20 s 22 million complex
    exponentials, 355 MB and 1 s per evaluation, the most of ``identify --output-only``'s time
    (session 30)."""
    x = np.asarray(x_windowed, dtype=float)
    n_h = int(np.floor(max_hz / f0 - 1e-12))
    phi = (2.0 * np.pi * f0 / sample_rate_hz) * np.arange(x.shape[-1])
    # |X_h|^2 = (x . cos h phi)^2 + (x . sin h phi)^2 per signal
    return float(sum(np.sum((x @ z.T) ** 2) for _, z in _angle_powers(phi, n_h)))


#: Bins on each side over which :func:`refine_spindle_frequency` (``lines_only``) takes the
#: spectrum's local floor (its median).
LINE_FLOOR_BINS = 20
#: A comb of lines stands out of a record (``lines_only``) when, over the candidate frequencies,
#: the best sum of the multiples' heights over their local floor is at least this many times the
#: median sum. Session 24: the fifteen real Hurco files 120-2 500; records without lines 1.7-2.1.
LINE_COMB_CONTRAST = 5.0


def refine_spindle_frequency(force, sample_rate_hz: float, nominal_hz: float, *, search: float = 0.05,
                             lines_only: bool = False) -> float:
    """Spindle frequency that maximises the energy of the harmonic comb in the force, Hz.

    Parameters
    ----------
    force : array_like, shape (n_axes, n_samples)
        Force signals (NaN rows are ignored), N.
    sample_rate_hz : float
        Sampling rate, Hz.
    nominal_hz : float
        Spindle frequency from the record's rpm, Hz.
    search : float
        Relative half-width of the search interval around the nominal value (0.05: +-5 %, which
        keeps the half and double frequencies out of reach).
    lines_only : bool
        Return ``nominal_hz`` when no comb of lines stands out of the record: the multiples'
        heights over their local floor (the median over :data:`LINE_FLOOR_BINS` bins each side),
        summed, best at most :data:`LINE_COMB_CONTRAST` times their median over the candidates.
        A line stands far over its neighbours, the peak of a lightly damped mode a few times; in a
        response without lines the comb's energy is a mode's (session 24: a 530 Hz mode at 0.2 %
        damping was taken for the 12th order of a 44.2 Hz spindle, nominal 45 Hz, and removed as
        a line). Where lines stand out the comb's energy decides, as without it, unless its best
        comb stands under half the best comb's height (weak lines beside a sharp mode): then the
        lines' comb is refined.

    Returns
    -------
    float
        Refined spindle frequency, Hz.
    """
    x = np.array(force, dtype=float, ndmin=2)
    x = x[~np.any(np.isnan(x), axis=1)]
    if x.size == 0:
        return float(nominal_hz)
    n = x.shape[-1]
    x = sps.detrend(x, axis=-1, type="linear") * sps.get_window("hann", n)[None, :]
    nyq = 0.5 * sample_rate_hz
    lo, hi = nominal_hz * (1 - search), nominal_hz * (1 + search)
    # coarse: zero-padded spectrum sampled on the comb; grid step well below the comb's resolution
    n_fft = int(2 ** np.ceil(np.log2(16 * n)))
    spec = np.sum(np.abs(np.fft.rfft(x, n=n_fft, axis=-1)) ** 2, axis=0)
    fgrid = np.fft.rfftfreq(n_fft, 1.0 / sample_rate_hz)
    if lines_only:
        plain = np.sum(np.abs(np.fft.rfft(x, axis=-1)) ** 2, axis=0)
        floor = ndimage.median_filter(plain, size=2 * LINE_FLOOR_BINS + 1, mode="nearest")
        height = spec / np.maximum(np.interp(fgrid, np.fft.rfftfreq(n, 1.0 / sample_rate_hz), floor),
                                   np.finfo(float).tiny)
    n_harm_max = max(int(np.floor(nyq / lo)), 1)
    step = 0.05 * sample_rate_hz / n / n_harm_max
    cands = np.arange(lo, hi + step, step)
    energy = np.zeros(cands.size)
    heights = np.zeros(cands.size)
    for h in range(1, n_harm_max + 1):
        fh = h * cands
        k = int(np.searchsorted(fh, nyq))   # the candidates (ascending) whose multiple h is below Nyquist
        energy[:k] += np.interp(fh[:k], fgrid, spec)
        if lines_only:
            heights[:k] += np.interp(fh[:k], fgrid, height)
    if lines_only and not heights.max() >= LINE_COMB_CONTRAST * np.median(heights):
        return float(nominal_hz)   # no comb of lines in the record: nothing to refine against
    i = int(np.argmax(energy))
    if lines_only and heights[i] < 0.5 * heights.max():
        i = int(np.argmax(heights))   # the most energetic comb is not one of lines (a mode's peak)
    a, b = cands[max(i - 2, 0)], cands[min(i + 2, cands.size - 1)]
    res = optimize.minimize_scalar(
        lambda f0: -_comb_energy(x, sample_rate_hz, f0, nyq), bounds=(a, b), method="bounded",
        options={"xatol": 1e-6 * nominal_hz},
    )
    return float(res.x)


@dataclass(frozen=True)
class Harmonics:
    """The milling harmonics of one record.

    Attributes
    ----------
    spindle_hz : float
        Refined spindle frequency, Hz.
    nominal_spindle_hz : float
        From the record's rpm, Hz.
    teeth : int
    freq_hz : ndarray, shape (n,)
        All spindle multiples below the Nyquist frequency, Hz.
    tooth_passing : ndarray of bool, shape (n,)
    significant : ndarray of bool, shape (n,)
        Lines that stand out of the background force spectrum (in at least one axis) by more than
        ``threshold`` (10 dB by default).
    """

    spindle_hz: float
    nominal_spindle_hz: float
    teeth: int
    freq_hz: np.ndarray
    tooth_passing: np.ndarray
    significant: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "freq_hz", _ro(self.freq_hz))
        object.__setattr__(self, "tooth_passing", _ro(self.tooth_passing, bool))
        object.__setattr__(self, "significant", _ro(self.significant, bool))

    @property
    def spindle_rpm(self) -> float:
        return 60.0 * self.spindle_hz

    @property
    def found_hz(self) -> np.ndarray:
        """The significant lines, Hz."""
        return self.freq_hz[self.significant]

    def to_dict(self) -> dict:
        return {
            "spindle_hz": self.spindle_hz,
            "nominal_spindle_hz": self.nominal_spindle_hz,
            "teeth": self.teeth,
            "found_hz": [float(f) for f in self.found_hz],
        }


def harmonic_line_mask(freq_hz, harmonic_hz, half_width_hz: float) -> np.ndarray:
    """Boolean mask of the lines of ``freq_hz`` within ``half_width_hz`` of any harmonic."""
    f = np.asarray(freq_hz, dtype=float)
    hz = np.asarray(harmonic_hz, dtype=float)
    if hz.size == 0:
        return np.zeros(f.size, dtype=bool)
    return np.any(np.abs(f[:, None] - hz[None, :]) <= half_width_hz, axis=1)


def remove_harmonic_lines(freq_hz, psd, mask) -> np.ndarray:
    """Replace masked lines of a PSD by linear interpolation between the nearest kept lines.

    Parameters
    ----------
    freq_hz : array_like, shape (n_freq,)
    psd : array_like, shape (..., n_freq)
    mask : array_like of bool, shape (n_freq,)
        Lines to replace.

    Returns
    -------
    ndarray, shape (..., n_freq)
    """
    f = np.asarray(freq_hz, dtype=float)
    p = np.array(psd, dtype=float, ndmin=1)
    m = np.asarray(mask, dtype=bool)
    keep = ~m
    if not np.any(keep):
        raise ValueError("every line is masked; nothing to interpolate from")
    flat = p.reshape(-1, f.size)
    out = np.array(flat)
    for row in out:
        row[m] = np.interp(f[m], f[keep], row[keep])
    return out.reshape(p.shape)


def default_half_width_hz(sample_rate_hz: float, nperseg: int) -> float:
    """Half-width of the band removed around each harmonic: 3 lines (Hann main lobe is 2)."""
    return 3.0 * sample_rate_hz / nperseg


def find_harmonics(
    force, sample_rate_hz: float, spindle_rpm: float, teeth: int, *, refine: bool = True, search: float = 0.05,
    nperseg: int | None = None, threshold_db: float = 10.0
) -> Harmonics:
    """Locate the milling harmonics of a force record.

    Parameters
    ----------
    force : array_like, shape (n_axes, n_samples)
        Force, N.
    sample_rate_hz : float
    spindle_rpm : float
        Nominal spindle speed, rev/min.
    teeth : int
    refine : bool
        Refine the spindle frequency from the spectrum (:func:`refine_spindle_frequency`).
    search : float
        Relative search half-width for the refinement.
    nperseg : int, optional
        Welch segment length used to decide which lines are significant.
    threshold_db : float
        A line is significant when its PSD exceeds the interpolated background by this much.
    """
    x = np.array(force, dtype=float, ndmin=2)
    x = x[~np.any(np.isnan(x), axis=1)]
    nominal = float(spindle_rpm) / 60.0
    f0 = refine_spindle_frequency(x, sample_rate_hz, nominal, search=search) if refine else nominal
    freqs, tooth = harmonic_frequencies(f0, teeth, 0.5 * sample_rate_hz)
    n = x.shape[-1]
    nperseg = default_nperseg(n) if nperseg is None else nperseg
    f, p = sps.welch(x, fs=sample_rate_hz, nperseg=nperseg, detrend="linear", axis=-1)
    hw = default_half_width_hz(sample_rate_hz, nperseg)
    mask = harmonic_line_mask(f, freqs, hw) | (f < 2 * sample_rate_hz / nperseg)
    floor = remove_harmonic_lines(f, p, mask)
    at = np.clip(np.round(freqs / (sample_rate_hz / nperseg)).astype(int), 0, f.size - 1)
    ratio = p[:, at] / np.maximum(floor[:, at], np.finfo(float).tiny)
    significant = np.any(ratio > 10.0 ** (threshold_db / 10.0), axis=0)
    return Harmonics(
        spindle_hz=f0,
        nominal_spindle_hz=nominal,
        teeth=int(teeth),
        freq_hz=freqs,
        tooth_passing=tooth,
        significant=significant,
    )


@dataclass(frozen=True)
class BackgroundEstimate:
    """Background (non-harmonic) force of one or more records.

    Attributes
    ----------
    variance_N2 : ndarray, shape (3,)
        Variance of the background force per axis X, Y, Z, N^2 (NaN for axes not recorded), the
        force sensor's noise variance subtracted when it is known.
    freq_hz : ndarray, shape (n_freq,)
    psd : ndarray, shape (3, n_freq)
        Force PSD, N^2/Hz.
    psd_clean : ndarray, shape (3, n_freq)
        The PSD with the harmonic lines interpolated over, N^2/Hz.
    removed : ndarray of bool, shape (n_freq,)
        Lines that were interpolated over.
    sensor_noise_variance_N2 : float
        What was subtracted, N^2.
    """

    variance_N2: np.ndarray
    freq_hz: np.ndarray
    psd: np.ndarray
    psd_clean: np.ndarray
    removed: np.ndarray
    sensor_noise_variance_N2: float = 0.0

    def __post_init__(self):
        for name in ("variance_N2", "freq_hz", "psd", "psd_clean"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "removed", _ro(self.removed, bool))


def background_variance(
    force, sample_rate_hz: float, harmonics: Harmonics, *, nperseg: int | None = None,
    sensor_noise_variance_N2: float | None = None, excess: float = 4.0
) -> BackgroundEstimate:
    """Variance of the background force per axis: the force PSD with the harmonics removed, integrated.

    ``sigma^2 = integral_0^{fs/2} P_clean(f) df`` (Nguyen & Melkote 2020). The harmonics are
    removed in two steps: (1) sinusoids at every spindle multiple (refined frequency), a constant
    and a line are fitted by least squares and subtracted in the time domain; (2) in the Welch
    PSD of what is left, the lines within two bins of a harmonic that still stand ``excess`` times
    above the local background (a harmonic whose amplitude or frequency wanders) are replaced by
    interpolation, as are the two lowest lines (depressed by the detrending). The sensor's own
    noise variance, when known, is subtracted: it is measured but does not excite the structure.

    Parameters
    ----------
    force : array_like, shape (3, n_samples)
        Force along X, Y, Z, N (NaN rows for axes not recorded).
    sample_rate_hz : float
    harmonics : Harmonics
    nperseg : int, optional
        Welch segment length (:func:`~oma.spectra.default_nperseg`).
    sensor_noise_variance_N2 : float, optional
    excess : float
        Threshold of step (2), a ratio of PSD levels.
    """
    x = np.array(force, dtype=float, ndmin=2)
    n = x.shape[-1]
    nperseg = default_nperseg(n) if nperseg is None else nperseg
    ok = ~np.any(np.isnan(x), axis=1)
    f = np.fft.rfftfreq(nperseg, 1.0 / sample_rate_hz)
    df = sample_rate_hz / nperseg
    p = np.full((x.shape[0], f.size), np.nan)
    p_res = np.full_like(p, np.nan)
    mask = f < 2 * df
    if np.any(ok):
        _, p[ok] = sps.welch(x[ok], fs=sample_rate_hz, nperseg=nperseg, detrend="linear", axis=-1)
        residual = x[ok] - fit_harmonic_signal(x[ok], sample_rate_hz, harmonics.freq_hz)
        _, p_res[ok] = sps.welch(residual, fs=sample_rate_hz, nperseg=nperseg, detrend="linear", axis=-1)
        for fh in harmonics.freq_hz:
            near = np.abs(f - fh) <= 2.0 * df
            ring = (np.abs(f - fh) > 2.0 * df) & (np.abs(f - fh) <= 10.0 * df) & (f >= 2 * df)
            if not np.any(ring):
                continue
            level = np.median(p_res[ok][:, ring], axis=1)
            if np.any(np.max(p_res[ok][:, near], axis=1) > excess * level):
                mask |= near
    clean = np.full_like(p, np.nan)
    if np.any(ok):
        clean[ok] = remove_harmonic_lines(f, p_res[ok], mask)
    # one-sided density: interior lines count df, DC and Nyquist lines df/2
    wts = np.full(f.size, df)
    wts[0] = 0.5 * df
    if nperseg % 2 == 0:
        wts[-1] = 0.5 * df
    var = clean @ wts
    noise = float(sensor_noise_variance_N2 or 0.0)
    var = var - noise
    return BackgroundEstimate(
        variance_N2=var, freq_hz=f, psd=p, psd_clean=clean, removed=mask, sensor_noise_variance_N2=noise
    )


def fit_harmonic_signal(x, sample_rate_hz: float, harmonic_hz, *, trend: bool = True) -> np.ndarray:
    """Least-squares fit of a constant, a line and sinusoids at ``harmonic_hz`` to signals ``x``.

    Parameters
    ----------
    x : array_like, shape (n_channels, n_samples)
    sample_rate_hz : float
    harmonic_hz : array_like, shape (n_h,)
    trend : bool
        Include the constant and linear terms.

    Returns
    -------
    ndarray, shape (n_channels, n_samples)
        The fitted periodic (plus trend) part; ``x - fit`` is the background.
    """
    x = np.array(x, dtype=float, ndmin=2)
    n = x.shape[-1]
    t = np.arange(n) / sample_rate_hz
    basis = harmonic_basis(t, harmonic_hz, trend=trend)
    if basis.shape[1] == 0:
        return np.zeros_like(x)
    coef = lstsq_normal(basis, x.T)
    return (basis @ coef).T


def fit_angle_orders(y, t, angle_rad, orders, sign, *, with_fit: bool = True):
    """Least squares of ``y`` on the trend and lines that are orders of one angle: the columns
    ``[1, (t - mean t) / ptp t, cos(h_i phi), s_i sin(h_i phi) ...]`` for each line ``i`` of order
    ``h_i`` and sign ``s_i``, ``phi = angle_rad``. Returns the coefficients (2 + 2 p, l), laid out as
    :func:`lstsq_normal` of :func:`harmonic_basis` lays them out, and the fit (l, n; None without
    ``with_fit``: it costs another pass over the powers).

    These are :func:`harmonic_basis`'s columns for spindle lines and their folds: a line at
    ``|h f0 - k fs|`` (sign that of ``h f0 - k fs``) with the extra phase ``s h dphi``, sampled at
    ``t = j / fs``, is ``cos(h phi)`` and ``s sin(h phi)`` of the angle ``phi = 2 pi f0 t + dphi``.
    Every product of two such columns is a sum of ``exp(i k phi)`` over the samples, ``k`` up to
    twice the highest order, so the normal equations cost ``O(n h_max)`` (the powers of
    ``exp(i phi)`` stepped by one product, rounding ``k`` epsilons) where the design costs
    ``O(n p^2)`` and ``n p`` numbers in memory: at 25.6 kHz over 20 s, 570 columns, 2.3 GB
    (session 30). The solve is :func:`oma._linalg.solve_normal`, the same column-scaled,
    ridge-guarded equations.

    Parameters
    ----------
    y : array_like, shape (l, n)
    t : array_like, shape (n,)
        Sample times, s (the trend's).
    angle_rad : array_like, shape (n,)
    orders : array_like of int, shape (p,)
        Positive.
    sign : array_like, shape (p,)
        +-1.
    """
    from ._linalg import solve_normal

    y = np.array(y, dtype=float, ndmin=2)
    t = np.asarray(t, dtype=float)
    phi = np.asarray(angle_rad, dtype=float)
    a = np.asarray(orders, dtype=int)
    s = np.asarray(sign, dtype=float)
    n, p = t.size, a.size
    tau = (t - t.mean()) / max(np.ptp(t), 1e-12)
    h_max = int(a.max()) if p else 0
    # power sums: e[k] = sum exp(i k phi), e_tau[k] = sum tau exp(i k phi), e_y[k] = y exp(i k phi)
    e = np.zeros(2 * h_max + 1, dtype=complex)
    e_tau = np.zeros(h_max + 1, dtype=complex)
    e_y = np.zeros((h_max + 1, y.shape[0]), dtype=complex)
    e[0], e_tau[0] = n, tau.sum()
    for k, z in _angle_powers(phi, 2 * h_max):
        e[k] = complex(*z.sum(axis=1))
        if k <= h_max:
            e_tau[k] = complex(*(z @ tau))
            ry = y @ z.T                                   # (l, 2): sum y cos, sum y sin
            e_y[k] = ry[:, 0] + 1j * ry[:, 1]
    d = a[:, None] - a[None, :]
    e_diff = np.where(d >= 0, e[np.abs(d)], np.conj(e[np.abs(d)]))
    e_sum = e[a[:, None] + a[None, :]]
    ss = np.outer(s, s)
    gram = np.empty((2 + 2 * p, 2 + 2 * p))
    gram[:2, :2] = [[n, tau.sum()], [tau.sum(), tau @ tau]]
    cos_, sin_ = slice(2, None, 2), slice(3, None, 2)
    gram[0, cos_], gram[0, sin_] = e[a].real, s * e[a].imag
    gram[1, cos_], gram[1, sin_] = e_tau[a].real, s * e_tau[a].imag
    gram[cos_, :2], gram[sin_, :2] = gram[:2, cos_].T, gram[:2, sin_].T
    gram[cos_, cos_] = 0.5 * (e_diff + e_sum).real                  # cos a phi cos b phi
    gram[sin_, sin_] = ss * 0.5 * (e_diff - e_sum).real             # sin a phi sin b phi
    gram[cos_, sin_] = s[None, :] * 0.5 * (e_sum - e_diff).imag     # cos a phi sin b phi
    gram[sin_, cos_] = gram[cos_, sin_].T
    rhs = np.empty((2 + 2 * p, y.shape[0]))
    rhs[0], rhs[1] = y.sum(axis=1), y @ tau
    rhs[cos_], rhs[sin_] = e_y[a].real, s[:, None] * e_y[a].imag
    coef = solve_normal(gram, rhs)
    if not with_fit:
        return coef, None
    # the fit, order by order: sum over the lines of order h of a cos(h phi) + s b sin(h phi)
    per_order = np.zeros((h_max + 1, y.shape[0], 2))
    np.add.at(per_order, a, np.stack([coef[cos_], s[:, None] * coef[sin_]], axis=-1))
    fit = coef[0][:, None] + coef[1][:, None] * tau[None, :]
    for k, z in _angle_powers(phi, h_max):
        fit += per_order[k] @ z
    return coef, fit


def _angle_powers(phi, k_max):
    """``(k, [cos k phi; sin k phi])`` for ``k = 1 .. k_max``, each (2, n), from one evaluation of
    ``cos phi`` and ``sin phi`` (one complex product per sample and step; the array is reused)."""
    c1, s1 = np.cos(phi), np.sin(phi)
    z = np.stack([c1, s1])
    tmp = np.empty_like(c1)
    for k in range(1, k_max + 1):
        if k > 1:   # (a + ib)(c1 + i s1)
            np.multiply(z[0], s1, out=tmp)
            z[0] *= c1
            z[0] -= z[1] * s1
            z[1] *= c1
            z[1] += tmp
        yield k, z


def harmonic_basis(t, harmonic_hz, *, trend: bool = True, phase_rad=None) -> np.ndarray:
    """Columns ``[1, t - mean(t), cos(2 pi f t + p), sin(2 pi f t + p) ...]`` at each harmonic,
    (n, n_cols); ``phase_rad`` (n_h, n), optional: each line's extra phase over time (the lines as
    orders of a tracked spindle angle, :mod:`oma.output_only.harmonics`), 0 by default."""
    t = np.asarray(t, dtype=float)
    hz = np.atleast_1d(harmonic_hz)
    extra = np.zeros((hz.size, 1)) if phase_rad is None else np.asarray(phase_rad, dtype=float)
    cols = []
    if trend:
        cols += [np.ones_like(t), (t - t.mean()) / max(np.ptp(t), 1e-12)]
    for fh, ph in zip(hz, extra):
        arg = 2.0 * np.pi * fh * t + ph
        cols += [np.cos(arg), np.sin(arg)]
    return np.column_stack(cols) if cols else np.zeros((t.size, 0))
