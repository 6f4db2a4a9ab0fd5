"""Small signal-processing helpers of the diagnosis: harmonic coefficients and their noise,
aliasing, spectra of one part of a record, and the spectral kernel of a Welch estimate.

Conventions: signals ``(n_channels, n_samples)``, frequency in Hz, one-sided densities
(scipy.signal convention: ``sum(P) df`` is the variance). A periodic signal with spindle
frequency ``f_s`` is written ``x(t) = c_0 + sum_h Re(c_h exp(i 2 pi h f_s t))``, so ``|c_h|`` is the
amplitude of harmonic ``h``.
"""

from __future__ import annotations

import numpy as np
from scipy import signal as sps

__all__ = [
    "fold_frequency",
    "harmonic_coefficients",
    "sinusoid_coefficients",
    "harmonic_noise_variance",
    "harmonic_signal",
    "welch_psd",
    "expected_welch",
    "welch_kernel",
    "dft_band_power",
]


def fold_frequency(freq_hz, sample_rate_hz: float) -> np.ndarray:
    """Where a frequency appears after sampling at ``sample_rate_hz``: folded into ``[0, fs/2]``."""
    fs = float(sample_rate_hz)
    f = np.mod(np.asarray(freq_hz, dtype=float), fs)
    return np.where(f > fs / 2.0, fs - f, f)


def _basis(t, spindle_hz: float, n_harm: int) -> np.ndarray:
    """Columns ``1, cos(h w t), sin(h w t)``, h = 1..n_harm (powers of ``exp(i w t)`` by recurrence)."""
    out = np.empty((t.size, 2 * n_harm + 1))
    out[:, 0] = 1.0
    z = np.exp(2j * np.pi * spindle_hz * t)
    cur = np.ones_like(z)
    for h in range(1, n_harm + 1):
        cur = cur * z
        if h % 16 == 0:  # refresh against the slow drift of repeated products
            cur = np.exp(2j * np.pi * h * spindle_hz * t)
        out[:, 2 * h - 1] = cur.real
        out[:, 2 * h] = cur.imag
    return out


def _solve_normal(basis, x):
    """Least squares by the normal equations (the sinusoid columns are nearly orthogonal; a tiny
    ridge keeps a column that vanishes on the sample grid, e.g. a sine at the Nyquist frequency,
    at zero)."""
    gram = basis.T @ basis
    ridge = 1e-10 * np.trace(gram) / gram.shape[0]
    return np.linalg.solve(gram + ridge * np.eye(gram.shape[0]), basis.T @ x.T)


def harmonic_coefficients(x, sample_rate_hz: float, spindle_hz: float, n_harm: int, *, t0: float = 0.0):
    """Least-squares harmonic coefficients ``c_0 .. c_H`` of signals ``x``.

    Parameters
    ----------
    x : array_like, shape (n_channels, n)
    sample_rate_hz, spindle_hz : float
        Hz.
    n_harm : int
        Highest harmonic ``H`` of the spindle frequency.
    t0 : float
        Time of the first sample, s (the phase reference is ``t = 0``).

    Returns
    -------
    coefficients : ndarray, complex, shape (n_channels, n_harm + 1)
        ``c_0`` (the mean, real) and ``c_h = a_h - i b_h`` for ``a_h cos + b_h sin``.
    fitted : ndarray, shape (n_channels, n)
        The fitted periodic part.
    """
    x = np.array(x, dtype=float, ndmin=2)
    t = t0 + np.arange(x.shape[-1]) / float(sample_rate_hz)
    basis = _basis(t, spindle_hz, n_harm)
    coef = _solve_normal(basis, x)
    c = np.empty((x.shape[0], n_harm + 1), dtype=complex)
    c[:, 0] = coef[0]
    c[:, 1:] = (coef[1::2] - 1j * coef[2::2]).T
    return c, (basis @ coef).T


def sinusoid_coefficients(x, sample_rate_hz: float, freq_hz, *, t0: float = 0.0):
    """Least-squares mean and complex amplitudes of sinusoids at arbitrary frequencies.

    Returns ``(coefficients (n_channels, 1 + n_freq) complex, fitted (n_channels, n))``; the
    frequencies must be distinct as sampled (aliases of each other make the problem singular).
    """
    x = np.array(x, dtype=float, ndmin=2)
    t = t0 + np.arange(x.shape[-1]) / float(sample_rate_hz)
    fr = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    cols = [np.ones_like(t)]
    for f in fr:
        cols += [np.cos(2.0 * np.pi * f * t), np.sin(2.0 * np.pi * f * t)]
    basis = np.column_stack(cols)
    coef = _solve_normal(basis, x)
    c = np.empty((x.shape[0], fr.size + 1), dtype=complex)
    c[:, 0] = coef[0]
    c[:, 1:] = (coef[1::2] - 1j * coef[2::2]).T
    return c, (basis @ coef).T


def harmonic_signal(coefficients, sample_rate_hz: float, spindle_hz: float, n_samples: int, *, t0: float = 0.0):
    """The periodic signal of harmonic coefficients, shape (n_channels, n_samples)."""
    c = np.atleast_2d(coefficients)
    t = t0 + np.arange(int(n_samples)) / float(sample_rate_hz)
    h = np.arange(c.shape[1])
    return np.real(c @ np.exp(2j * np.pi * np.outer(h * spindle_hz, t)))


def welch_psd(x, sample_rate_hz: float, nperseg: int):
    """One-sided Welch PSD (Hann, 50 % overlap, linear detrend), ``(freq, psd)``."""
    x = np.array(x, dtype=float, ndmin=2)
    nperseg = int(min(nperseg, x.shape[-1]))
    return sps.welch(x, fs=sample_rate_hz, nperseg=nperseg, detrend="linear", axis=-1)


def harmonic_noise_variance(residual, sample_rate_hz: float, spindle_hz: float, n_harm: int, *,
                            nperseg: int | None = None) -> np.ndarray:
    """Variance of each least-squares harmonic coefficient from the background PSD around it.

    For a coefficient estimated over ``T`` seconds from a signal whose non-periodic part has the
    one-sided density ``S(f)`` near ``f_h = h f_s``, ``E|c_h - c_h^true|^2 = 2 S(f_h) / T`` (the
    cosine and sine amplitudes each have variance ``S / T``), and the mean has variance
    ``S(0) / (2 T)``.

    Parameters
    ----------
    residual : array_like, shape (n_channels, n)
        The signal with its harmonics removed.

    Returns
    -------
    ndarray, shape (n_channels, n_harm + 1)
    """
    r = np.array(residual, dtype=float, ndmin=2)
    n = r.shape[-1]
    duration = n / float(sample_rate_hz)
    if nperseg is None:
        nperseg = int(max(64, min(n, 2 ** np.round(np.log2(max(n / 4.0, 64.0))))))
    f, p = welch_psd(r, sample_rate_hz, nperseg)
    fh = np.arange(n_harm + 1) * float(spindle_hz)
    df = f[1] - f[0]
    s = np.empty((r.shape[0], n_harm + 1))
    for h, fr in enumerate(fh):
        # the line under the harmonic is depressed by the harmonic's removal: use its neighbours
        ring = (np.abs(f - fr) >= 1.5 * df) & (np.abs(f - fr) <= 3.5 * df) & (f > 0.5 * df)
        s[:, h] = p[:, ring].mean(axis=1) if np.any(ring) else np.interp(fr, f, p[0])
    out = 2.0 * s / duration
    out[:, 0] = s[:, 0] / (2.0 * duration)
    return out


def welch_kernel(nperseg: int, sample_rate_hz: float, step_hz: float) -> np.ndarray:
    """Normalised ``|W(f)|^2`` of a Hann window of ``nperseg`` samples at offsets ``k step_hz``,
    ``|f| <= 4 fs / nperseg`` (the kernel :func:`expected_welch` convolves with)."""
    df = sample_rate_hz / nperseg
    half = int(np.ceil(4.0 * df / step_hz))
    offsets = np.arange(-half, half + 1) * step_hz
    w = sps.get_window("hann", nperseg)
    t = np.arange(nperseg) / sample_rate_hz
    kern = np.abs(np.exp(-2j * np.pi * np.outer(offsets, t)) @ w) ** 2
    return kern / kern.sum()


def expected_welch(freq_fine_hz, psd_fine, freq_hz, nperseg: int, sample_rate_hz: float, *,
                   kernel=None) -> np.ndarray:
    """Expected value of a Hann-window Welch estimate at ``freq_hz`` for a smooth true PSD.

    ``E[P_w(f)] = int P(v) |W(f - v)|^2 dv / int |W|^2`` with ``W`` the DTFT of the Hann window of
    ``nperseg`` samples, evaluated by quadrature on the fine grid (its step must be well below
    ``fs / nperseg``). This is how narrow spectral features (a process-damping notch a few tenths
    of a hertz wide) are seen by an estimate of finite resolution.

    Parameters
    ----------
    freq_fine_hz : ndarray, shape (m,)
        Uniform fine grid, Hz.
    psd_fine : ndarray, shape (n_rows, m)
    freq_hz : ndarray, shape (k,)
        Where the estimate is wanted (inside the fine grid, away from its ends by 4 lines).
    kernel : ndarray, optional
        :func:`welch_kernel` for this grid step (computed when not given).

    Returns
    -------
    ndarray, shape (n_rows, k)
    """
    ff = np.asarray(freq_fine_hz, dtype=float)
    if kernel is None:
        kernel = welch_kernel(nperseg, sample_rate_hz, ff[1] - ff[0])
    p = np.atleast_2d(np.asarray(psd_fine, dtype=float))
    return np.stack([np.interp(freq_hz, ff, np.convolve(row, kernel[::-1], mode="same")) for row in p])


def dft_band_power(x, band_mask) -> np.ndarray:
    """Power of the part of ``x`` inside a band of DFT lines, per channel (Parseval).

    ``E = (1/N) [|X_0|^2 w_0 + 2 sum_{k >= 1} |X_k|^2]`` over the lines in ``band_mask`` (``rfft``
    lines of the full length ``N``; the Nyquist line, when kept, counts once): the sum of squares
    of the band-limited signal.

    Parameters
    ----------
    x : array_like, shape (n_channels, N)
    band_mask : array_like of bool, shape (n_channels, N // 2 + 1) or (N // 2 + 1,)
    """
    x = np.array(x, dtype=float, ndmin=2)
    n = x.shape[-1]
    spec = np.fft.rfft(x, axis=-1)
    w = np.full(spec.shape[-1], 2.0)
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    m = np.broadcast_to(np.asarray(band_mask, dtype=bool), spec.shape)
    return np.sum(np.where(m, w * np.abs(spec) ** 2, 0.0), axis=-1) / n
