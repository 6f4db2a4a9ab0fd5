"""Welch auto and cross spectral densities in the ``(n_out, n_in, n_freq)`` layout.

One-sided densities (scipy.signal convention): a white signal of variance ``s2`` sampled at ``fs``
has ``S = 2 s2 / fs`` and ``sum(S) * df`` equals its variance.

References
----------
P. D. Welch, "The use of fast Fourier transform for the estimation of power spectra", IEEE Trans.
Audio Electroacoust. 15 (1967) 70-73. J. S. Bendat, A. G. Piersol, Random Data, 4th ed. (2010).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

__all__ = ["Spectra", "welch_spectra", "default_nperseg", "equivalent_averages", "pool_spectra"]


@dataclass(frozen=True)
class Spectra:
    """Auto and cross spectral densities of inputs ``u`` (forces) and outputs ``y`` (responses).

    Attributes
    ----------
    freq_hz : ndarray, shape (n_freq,)
    suu : ndarray, shape (n_in, n_in, n_freq), complex
        ``suu[i, j] = S_{u_i u_j}`` (``E[U_i^* U_j]`` convention of :func:`scipy.signal.csd`), units^2/Hz.
    syu : ndarray, shape (n_out, n_in, n_freq), complex
        ``syu[o, i] = S_{u_i y_o}``: the cross spectrum whose ratio to ``S_{u_i u_i}`` is the H1 FRF.
    syy : ndarray, shape (n_out, n_out, n_freq), complex
    n_segments : int
        Number of (overlapping) segments averaged.
    n_averages : float
        Equivalent number of independent averages (Welch's overlap correction), used for the
        random error.
    nperseg : int
    sample_rate_hz : float
    """

    freq_hz: np.ndarray
    suu: np.ndarray
    syu: np.ndarray
    syy: np.ndarray
    n_segments: int
    n_averages: float
    nperseg: int
    sample_rate_hz: float

    @property
    def df_hz(self) -> float:
        return float(self.sample_rate_hz / self.nperseg)


def default_nperseg(n_samples: int) -> int:
    """Segment length: the power of two nearest to a quarter of the record (7 averages at 50 %).

    At least 64 samples and never more than the record.
    """
    n = max(int(2 ** np.round(np.log2(max(n_samples, 4) / 4.0))), 64)
    return int(min(n, n_samples))


def equivalent_averages(n_segments: int, nperseg: int, noverlap: int, window="hann") -> float:
    """Equivalent number of independent averages of a Welch estimate.

    Welch (1967): the variance of the averaged periodogram of white noise is that of
    ``n_d`` independent periodograms with ``1/n_d = (1/K) [1 + 2 sum_j (1 - j/K) rho(j)]`` where
    ``rho(j)`` is the squared normalised window correlation at a shift of ``j`` segment steps.
    """
    w = sps.get_window(window, nperseg)
    step = nperseg - noverlap
    k = n_segments
    total = 1.0
    for j in range(1, k):
        shift = j * step
        if shift >= nperseg:
            break
        rho = (np.sum(w[: nperseg - shift] * w[shift:]) / np.sum(w * w)) ** 2
        total += 2.0 * (1.0 - j / k) * rho
    return float(k / total)


def welch_spectra(u, y, sample_rate_hz: float, *, nperseg: int | None = None, noverlap: int | None = None,
                  window="hann", detrend="linear") -> Spectra:
    """Welch estimates of all auto and cross spectra between inputs ``u`` and outputs ``y``.

    Parameters
    ----------
    u : array_like, shape (n_in, n_samples)
        Inputs (forces), SI.
    y : array_like, shape (n_out, n_samples)
        Outputs (displacements), SI.
    sample_rate_hz : float
        Sampling rate, Hz.
    nperseg : int, optional
        Segment length; :func:`default_nperseg` by default.
    noverlap : int, optional
        Overlap; half a segment by default.
    window, detrend :
        As in :func:`scipy.signal.csd` (default Hann window, linear detrend per segment).

    Returns
    -------
    Spectra
    """
    u = np.array(u, dtype=float, ndmin=2)
    y = np.array(y, dtype=float, ndmin=2)
    n = u.shape[-1]
    if y.shape[-1] != n:
        raise ValueError(f"u and y have different lengths: {n} and {y.shape[-1]} samples")
    nperseg = default_nperseg(n) if nperseg is None else int(nperseg)
    if nperseg > n:
        raise ValueError(f"nperseg ({nperseg}) must not exceed the number of samples ({n}).")
    noverlap = nperseg // 2 if noverlap is None else int(noverlap)
    if noverlap >= nperseg:
        raise ValueError("noverlap must be less than nperseg.")
    kw = dict(fs=sample_rate_hz, window=window, nperseg=nperseg, noverlap=noverlap, detrend=detrend, axis=-1)
    # csd(x, y) = E[X^* Y]: broadcasting gives all pairs at once
    f, suu = sps.csd(u[:, None, :], u[None, :, :], **kw)
    _, syu = sps.csd(u[None, :, :], y[:, None, :], **kw)
    _, syy = sps.csd(y[:, None, :], y[None, :, :], **kw)
    n_seg = 1 + (n - nperseg) // (nperseg - noverlap)
    return Spectra(
        freq_hz=f,
        suu=suu,
        syu=syu,
        syy=syy,
        n_segments=int(n_seg),
        n_averages=equivalent_averages(n_seg, nperseg, noverlap, window),
        nperseg=nperseg,
        sample_rate_hz=float(sample_rate_hz),
    )


def pool_spectra(spectra, *, weights=None) -> Spectra:
    """Average several :class:`Spectra` of the same grid, weighted by their segment counts.

    ``weights`` (shape ``(n_spectra, n_freq)``, optional) zeroes a record at chosen lines (e.g. its
    own harmonics); the pooled value at a line averages only the records with non-zero weight
    there. Lines where every weight is zero are NaN.
    """
    spectra = list(spectra)
    if not spectra:
        raise ValueError("no spectra to pool")
    f = spectra[0].freq_hz
    for s in spectra[1:]:
        if s.freq_hz.shape != f.shape or not np.allclose(s.freq_hz, f):
            raise ValueError("spectra to pool have different frequency grids")
    n_seg = np.array([s.n_segments for s in spectra], dtype=float)
    w = np.ones((len(spectra), f.size)) if weights is None else np.asarray(weights, dtype=float)
    w = w * n_seg[:, None]
    total = np.sum(w, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.where(total > 0, 1.0 / total, np.nan)

    def avg(name):
        return sum(getattr(s, name) * wk[None, None, :] for s, wk in zip(spectra, w)) * norm[None, None, :]

    # equivalent averages per line: sum of the records' averages that contribute there
    n_avg = np.array([s.n_averages for s in spectra])
    eff = np.sum((w > 0) * n_avg[:, None], axis=0)
    return Spectra(
        freq_hz=f,
        suu=avg("suu"),
        syu=avg("syu"),
        syy=avg("syy"),
        n_segments=int(np.sum(n_seg)),
        n_averages=float(np.min(eff[eff > 0])) if np.any(eff > 0) else 0.0,
        nperseg=spectra[0].nperseg,
        sample_rate_hz=spectra[0].sample_rate_hz,
    )
