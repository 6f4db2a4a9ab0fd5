"""FRF estimates from forces and responses: H1, H2, Hv, coherence and random-error bands.

All estimators work on the Welch spectra of :mod:`oma.spectra` with several inputs at once (the
three force axes of a cut are all measured, so the full 3 x 3 receptance matrix is estimated):

* ``H1 = S_yu S_uu^-T`` -- unbiased by output noise (the tracker), the OMA default;
* ``H2 = S_yy^T S_yu^-H`` -- unbiased by input noise (square systems only);
* ``Hv`` -- total least squares per output row on noise-scaled channels (Leuridan et al.;
  Bendat & Piersol), between the two.

Random error of an estimate with ``n_d`` equivalent averages and ``q`` inputs (Bendat & Piersol,
Random Data, 4th ed., 2010, chapters on single- and multiple-input FRF estimates): the complex variance of ``H1_oi`` is
``S_nn,o [S_uu^-T]_ii / (n_d - q + 1)`` with ``S_nn,o = (1 - gamma^2_o) S_yy,oo`` the output noise
left unexplained (``gamma^2_o`` the multiple coherence); for one input this is the familiar
``eps[|H|] = sqrt(1 - gamma^2) / (|gamma| sqrt(2 n_d))``.

The noise spectrum ``S_nn,o`` is smooth, but its estimate at one line has only ``n_d - q + 1``
degrees of freedom: 2.8 for a 20 s record cut into 6.6 s segments with three force inputs. The
inverse variances that weight the modal fit are then heavy-tailed (the inverse of a chi-square
with under 4 degrees of freedom has no variance), and a few lines that came out quiet by chance
dominate it. So ``S_nn,o`` is averaged over adjacent lines until it has :data:`NOISE_DOF` degrees
of freedom (:func:`noise_lines`); ``[S_uu^-T]_ii`` is kept per line, the variance being
conditional on the measured inputs. The README's "Shop sampling rates" (session 31) gives what this
did to the force-based fits.

Records of the same pose are combined by pooling their spectra (segment-weighted), each record's
own harmonic lines being left out of the pool; lines that are harmonics in every record are
dropped from the estimate (forced response, not free response).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Sequence

import numpy as np

from ._arrays import readonly as _ro
from .frf_table import AXES, FRFTable
from .harmonics import Harmonics, default_half_width_hz, harmonic_line_mask
from .signals import PreparedSignals, detrend
from .spectra import Spectra, default_nperseg, pool_spectra, welch_spectra

__all__ = [
    "FRFEstimate",
    "frf_from_spectra",
    "estimate_frf",
    "frf_agreement",
    "noise_lines",
]

Estimator = Literal["h1", "h2", "hv"]
ESTIMATORS = ("h1", "h2", "hv")


@dataclass(frozen=True)
class FRFEstimate:
    """An estimated receptance matrix with its statistics.

    Attributes
    ----------
    table : FRFTable
        The estimate (m/N), with ordinary coherence ``(3, 3, n_freq)``.
    multiple_coherence : ndarray, shape (3, n_freq)
        Multiple coherence of each output with all measured inputs (NaN for outputs not measured).
    std_m_N : ndarray, shape (3, 3, n_freq)
        Standard deviation of the complex estimate (random error), m/N; ``inf`` where unknown.
    n_averages : float
        Equivalent independent averages (pooled over records).
    estimator : str
    excluded_hz : ndarray
        Lines dropped as harmonics, Hz.
    spectra : Spectra
        The pooled spectra on the kept lines.
    """

    table: FRFTable
    multiple_coherence: np.ndarray
    std_m_N: np.ndarray
    n_averages: float
    estimator: str
    excluded_hz: np.ndarray
    spectra: Spectra | None = field(default=None, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "multiple_coherence", _ro(self.multiple_coherence))
        object.__setattr__(self, "std_m_N", _ro(self.std_m_N))
        object.__setattr__(self, "excluded_hz", _ro(self.excluded_hz))

    @property
    def freq_hz(self) -> np.ndarray:
        return self.table.freq_hz

    @property
    def receptance_m_N(self) -> np.ndarray:
        return self.table.receptance_m_N

    @property
    def magnitude_error(self) -> np.ndarray:
        """Normalised random error of ``|H|``, ``eps = std(|H|) / |H|``, shape (3, 3, n_freq)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.std_m_N / np.sqrt(2.0) / np.abs(self.table.receptance_m_N)

    def magnitude_band(self, *, n_sigma: float = 2.0):
        """Lower and upper bounds of ``|H|``, ``|H| (1 -+ n_sigma eps)`` (about 95 % for 2), m/N."""
        mag = np.abs(self.table.receptance_m_N)
        eps = np.nan_to_num(self.magnitude_error, nan=np.inf)
        return np.clip(mag * (1 - n_sigma * eps), 0.0, None), mag * (1 + n_sigma * eps)


#: Degrees of freedom the output noise spectrum behind the random error is averaged to (see the
#: module notes and :func:`noise_lines`).
NOISE_DOF = 24.0


def noise_lines(n_averages: float, n_inputs: int) -> int:
    """Adjacent lines the output noise spectrum is averaged over: the smallest odd number whose
    ``n_d - q + 1`` degrees of freedom per line add up to :data:`NOISE_DOF` (1 for records with
    24 or more averages per input beyond the first)."""
    dof = max(n_averages - n_inputs + 1, 1.0)
    n = int(np.ceil(NOISE_DOF / dof - 1e-9))
    return n + 1 - n % 2


def _line_average(x, n: int):
    """Mean over ``n`` adjacent lines along the first axis (fewer at the ends), of the finite values
    only; lines that are not finite stay as they are. Summed directly, not as a running sum, whose
    cancellation turns the small values beside large ones negative."""
    if n <= 1 or x.shape[0] < 2:
        return x
    from scipy.ndimage import convolve1d

    ok = np.isfinite(x)
    ones = np.ones(n)
    total = convolve1d(np.where(ok, x, 0.0), ones, axis=0, mode="constant")
    count = convolve1d(ok.astype(float), ones, axis=0, mode="constant")
    return np.where(ok, total / np.maximum(count, 1.0), x)


def frf_from_spectra(spectra: Spectra, *, estimator: Estimator = "h1", noise_psd_ratio: float | None = None):
    """FRF matrix, ordinary and multiple coherence, and random error from Welch spectra.

    Parameters
    ----------
    spectra : Spectra
        ``n_in`` inputs and ``n_out`` outputs, no NaN.
    estimator : {'h1', 'h2', 'hv'}
    noise_psd_ratio : float, optional
        For Hv: ratio of the output noise PSD to the input noise PSD (units (m/N)^2). Both channels
        are scaled by their noise level so that total least squares is consistent. By default the
        ratio of the output and input auto spectra averaged over frequency is used.

    Returns
    -------
    h : ndarray, shape (n_out, n_in, n_freq), complex
    coherence : ndarray, shape (n_out, n_in, n_freq)
        Ordinary coherence ``|S_yu|^2 / (S_uu S_yy)``.
    multiple : ndarray, shape (n_out, n_freq)
    variance : ndarray, shape (n_out, n_in, n_freq)
        Complex variance of the H1 estimate (used for all three estimators as the random error).
    """
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {ESTIMATORS}, not {estimator!r}")
    suu = np.moveaxis(spectra.suu, -1, 0)  # (nf, q, q): [i, j] = E[U_i^* U_j]
    syu = np.moveaxis(spectra.syu, -1, 0)  # (nf, p, q): [o, i] = E[U_i^* Y_o]
    syy = np.moveaxis(spectra.syy, -1, 0)  # (nf, p, p)
    n_out, n_in = syu.shape[1], syu.shape[2]
    suu_t = np.swapaxes(suu, 1, 2)  # E[U U^H]
    inv_suu_t = np.linalg.pinv(suu_t)
    h1 = syu @ inv_suu_t
    auto_u = np.real(np.diagonal(suu, axis1=1, axis2=2))  # (nf, q)
    auto_y = np.real(np.diagonal(syy, axis1=1, axis2=2))  # (nf, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        coh = np.abs(syu) ** 2 / (auto_u[:, None, :] * auto_y[:, :, None])
        explained = np.real(np.einsum("foi,fij,foj->fo", h1, suu_t, np.conj(h1)))
        multiple = np.clip(explained / auto_y, 0.0, 1.0)
    noise = np.clip(auto_y * (1.0 - multiple), 0.0, None)  # (nf, p)
    noise = _line_average(noise, noise_lines(spectra.n_averages, n_in))
    dof = max(spectra.n_averages - n_in + 1, 1.0)
    var = noise[:, :, None] * np.real(np.diagonal(inv_suu_t, axis1=1, axis2=2))[:, None, :] / dof
    if estimator == "h1":
        h = h1
    elif estimator == "h2":
        if n_out != n_in:
            raise ValueError(f"H2 needs as many outputs as inputs; found {n_out} outputs and {n_in} inputs")
        h = np.swapaxes(syy, 1, 2) @ np.linalg.pinv(np.conj(np.swapaxes(syu, 1, 2)))
    else:
        if noise_psd_ratio is None:
            noise_psd_ratio = float(np.mean(auto_y) / np.mean(auto_u))
        scale = np.sqrt(noise_psd_ratio)  # output units per input unit
        h = np.zeros_like(h1)
        for o in range(n_out):
            c = np.zeros((suu.shape[0], n_in + 1, n_in + 1), dtype=complex)
            c[:, :n_in, :n_in] = suu_t
            c[:, :n_in, n_in] = np.conj(syu[:, o, :]) / scale
            c[:, n_in, :n_in] = syu[:, o, :] / scale
            c[:, n_in, n_in] = syy[:, o, o] / scale**2
            _, vecs = np.linalg.eigh(c)
            v = vecs[:, :, 0]  # smallest eigenvalue
            w = np.conj(v)
            h[:, o, :] = -w[:, :n_in] / w[:, n_in : n_in + 1] * scale
    return (
        np.moveaxis(h, 0, -1),
        np.moveaxis(coh, 0, -1),
        np.moveaxis(multiple, 0, -1),
        np.moveaxis(var, 0, -1),
    )


def estimate_frf(
    signals: PreparedSignals | Sequence[PreparedSignals],
    *,
    harmonics: Sequence[Harmonics | None] | Harmonics | None = None,
    estimator: Estimator = "h1",
    nperseg: int | None = None,
    half_width_hz: float | None = None,
    noise_psd_ratio: float | None = None,
) -> FRFEstimate:
    """Estimate the receptance matrix from one or more records of the same pose.

    Parameters
    ----------
    signals : PreparedSignals or sequence of them
        Force and displacement in the cut window (:func:`oma.signals.prepare_record`); all at the
        same sampling rate.
    harmonics : Harmonics or sequence (one per record), optional
        Lines within ``half_width_hz`` of a record's harmonics are left out of that record's
        contribution.
    estimator : {'h1', 'h2', 'hv'}
    nperseg : int, optional
        Welch segment length; :func:`~oma.spectra.default_nperseg` of the shortest record.
    half_width_hz : float, optional
        Half-width of the band left out around each harmonic; three lines by default.
    noise_psd_ratio : float, optional
        For Hv (see :func:`frf_from_spectra`).

    Returns
    -------
    FRFEstimate
    """
    sigs = [signals] if isinstance(signals, PreparedSignals) else list(signals)
    if not sigs:
        raise ValueError("no records to estimate an FRF from")
    fs = sigs[0].sample_rate_hz
    for s in sigs[1:]:
        if abs(s.sample_rate_hz - fs) > 1e-9 * fs:
            raise ValueError(f"records have different sampling rates: {fs} and {s.sample_rate_hz} Hz")
    if harmonics is None or isinstance(harmonics, Harmonics):
        harm = [harmonics] * len(sigs)
    else:
        harm = list(harmonics)
        if len(harm) != len(sigs):
            raise ValueError(f"{len(harm)} harmonics for {len(sigs)} records")
    u_axes = np.logical_and.reduce([s.force_axes for s in sigs])
    y_axes = np.logical_and.reduce([s.displacement_axes for s in sigs])
    if not np.any(u_axes) or not np.any(y_axes):
        raise ValueError("the records share no recorded force axis or no recorded motion axis")
    n_min = min(s.n_samples for s in sigs)
    nperseg = default_nperseg(n_min) if nperseg is None else int(nperseg)
    hw = default_half_width_hz(fs, nperseg) if half_width_hz is None else half_width_hz
    per_record, weights = [], []
    for s, hm in zip(sigs, harm):
        u = detrend(s.force_N[u_axes], kind="linear")
        y = detrend(s.displacement_m[y_axes], kind="linear")
        sp = welch_spectra(u, y, fs, nperseg=nperseg)
        per_record.append(sp)
        mask = np.zeros(sp.freq_hz.size, dtype=bool) if hm is None else harmonic_line_mask(sp.freq_hz, hm.freq_hz, hw)
        weights.append(~mask)
    weights = np.array(weights, dtype=float)
    keep = np.any(weights > 0, axis=0)
    keep[0] = False  # DC: the mean and the trend are not dynamics
    pooled = pool_spectra(per_record, weights=weights)
    f = pooled.freq_hz
    sub = Spectra(
        freq_hz=f[keep], suu=pooled.suu[..., keep], syu=pooled.syu[..., keep], syy=pooled.syy[..., keep],
        n_segments=pooled.n_segments, n_averages=pooled.n_averages, nperseg=nperseg, sample_rate_hz=fs,
    )
    h, coh, mult, var = frf_from_spectra(sub, estimator=estimator, noise_psd_ratio=noise_psd_ratio)
    nf = sub.freq_hz.size
    g = np.zeros((3, 3, nf), dtype=complex)
    c = np.zeros((3, 3, nf))
    sd = np.full((3, 3, nf), np.inf)
    mc = np.full((3, nf), np.nan)
    oi, ii = np.flatnonzero(y_axes), np.flatnonzero(u_axes)
    g[np.ix_(oi, ii)] = h
    c[np.ix_(oi, ii)] = coh
    sd[np.ix_(oi, ii)] = np.sqrt(var)
    mc[oi] = mult
    measured = np.zeros((3, 3), dtype=bool)
    measured[np.ix_(oi, ii)] = True
    table = FRFTable(
        sub.freq_hz, g, measured, coherence=c,
        meta={"estimator": estimator, "n_averages": float(pooled.n_averages), "nperseg": nperseg,
              "records": len(sigs)},
    )
    return FRFEstimate(
        table=table, multiple_coherence=mc, std_m_N=sd, n_averages=float(pooled.n_averages),
        estimator=estimator, excluded_hz=f[~keep & (f > 0)], spectra=sub,
    )


def frf_agreement(estimate: FRFTable, reference: FRFTable, band_hz) -> dict[str, float]:
    """Relative error of the direct FRFs of ``estimate`` against ``reference`` in a band.

    ``e_a = ||G_est,aa - G_ref,aa|| / ||G_ref,aa||`` (2-norm over the reference's lines inside
    ``band_hz``), the estimate interpolated linearly onto the reference's lines.

    Parameters
    ----------
    estimate, reference : FRFTable
        Anything with ``freq_hz``, ``measured`` and ``receptance(freq_hz)``/``receptance_m_N``.
    band_hz : (float, float)

    Returns
    -------
    dict
        ``{"X": e_x, ...}`` for the axes whose direct entry both tables have.
    """
    lo, hi = float(band_hz[0]), float(band_hz[1])
    if not hi > lo:
        raise ValueError(f"band_hz must be increasing, found {band_hz!r}")
    f = np.asarray(reference.freq_hz)
    sel = (f >= lo) & (f <= hi)
    if not np.any(sel):
        raise ValueError(f"the reference has no lines in {lo}..{hi} Hz")
    f = f[sel]
    g_est = estimate.receptance(f)
    out = {}
    for a, axis in enumerate(AXES):
        if estimate.measured[a, a] and reference.measured[a, a]:
            ref = reference.receptance_m_N[a, a][sel]
            out[axis] = float(np.linalg.norm(g_est[a, a] - ref) / np.linalg.norm(ref))
    return out
