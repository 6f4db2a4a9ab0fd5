"""Covariance-driven stochastic subspace identification (SSI-cov) with automatic mode selection.

Output-only: the structure is driven by an unmeasured broadband force, so the output correlation
``R_k = E[y_{t+k} y_t^T]`` of the response is that of a stochastic state-space model
``x_{t+1} = A x_t + w_t``, ``y_t = C x_t + v_t``; ``R_k = C A^{k-1} G`` for ``k >= 1``. The block
Toeplitz matrix of correlations factors as observability times reversed controllability; its SVD
gives ``C`` and ``A`` at any model order, whose eigenvalues are the discrete poles (Peeters & De
Roeck, Mech. Syst. Signal Process. 13(6), 1999; Brincker & Ventura, Introduction to Operational
Modal Analysis, 2015, ch. 9).

The model order is not given: poles are computed at every even order up to ``max_order``; a pole is
*stable* when a pole of the next lower order lies within 1 % in frequency, 10 % in damping and
0.95 in MAC; stable physical poles are grouped by hierarchical clustering on the distance
``|f_i - f_j| / max(f_i, f_j) + (1 - MAC_ij)`` (Magalhaes, Cunha & Caetano, Mech. Syst. Signal
Process. 23(2), 2009), and a cluster is a mode when it holds stable poles from at least 30 % of
the orders (benchmark records: noise clusters up to 0.17, true modes 0.37-0.93 but for one record in
twenty; a 0.25 threshold recovered that mode but let a noise cluster of 0.27 through in the
two-mode test). Frequency and damping of a mode are 20 % trimmed means over its
cluster (one pole per order), its shape the phase-aligned mean of the members' shapes.

Signals are ``(n_channels, n_samples)``, time last; frequency in Hz.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy import stats
from scipy.linalg import eigh, solve_triangular

from .._arrays import readonly as _ro

__all__ = ["output_correlations", "segment_correlations", "ssi_poles", "SSIPoles", "StabilisedModes", "select_modes", "mac", "same_mode",
           "match_modes"]


def output_correlations(y, max_lag: int) -> np.ndarray:
    """Unbiased output correlations ``R_k = 1/(N-k) sum_t y_{t+k} y_t^T``, k = 0..max_lag.

    Parameters
    ----------
    y : array_like, shape (n_channels, n_samples)
    max_lag : int

    Returns
    -------
    ndarray, shape (max_lag + 1, n_channels, n_channels)
    """
    y = np.asarray(y, dtype=float)
    l, n = y.shape
    n_fft = int(2 ** np.ceil(np.log2(2 * n)))
    spec = np.fft.rfft(y, n=n_fft, axis=-1)
    cross = np.fft.irfft(spec[:, None, :] * np.conj(spec[None, :, :]), n=n_fft, axis=-1)[..., : max_lag + 1]
    return np.moveaxis(cross, -1, 0) / (n - np.arange(max_lag + 1))[:, None, None]


def segment_correlations(y, start: int, stop: int, max_lag: int) -> np.ndarray:
    """Correlations of the samples ``start:stop`` of ``y`` with the samples up to ``max_lag`` later.

    ``R_k = 1/n_k sum_{t = start}^{stop - 1} y_{t+k} y_t^T`` over the ``t + k`` still inside ``y``:
    lags reach past the segment's end, so segments of any length add up to the correlation of the
    whole record (with the weights ``n_k``) and none needs to be long compared with the lags.

    Lags that reach past the end of ``y`` from every sample of the segment get zero (no products).

    Returns
    -------
    ndarray, shape (max_lag + 1, n_channels, n_channels)

    Raises
    ------
    RecordError
        ``y`` spans fewer than :data:`MIN_LAG_MULTIPLE` times ``max_lag`` samples: a record too short
        for the correlations SSI needs (their longest lags would rest on a handful of products).
    """
    y = np.asarray(y, dtype=float)
    _check_record_length(y.shape[1], max_lag)
    seg = y[:, start:stop]
    ext = y[:, start:min(stop + max_lag, y.shape[1])]
    n_fft = int(2 ** np.ceil(np.log2(seg.shape[1] + ext.shape[1])))
    a = np.fft.rfft(ext, n=n_fft, axis=-1)
    b = np.fft.rfft(seg, n=n_fft, axis=-1)
    cross = np.fft.irfft(a[:, None, :] * np.conj(b[None, :, :]), n=n_fft, axis=-1)[..., : max_lag + 1]
    if cross.shape[-1] < max_lag + 1:  # a short segment at the record's end: its longest lags have no products
        cross = np.concatenate([cross, np.zeros(cross.shape[:-1] + (max_lag + 1 - cross.shape[-1],))], axis=-1)
    count = np.minimum(seg.shape[1], ext.shape[1] - np.arange(max_lag + 1))
    return np.moveaxis(cross, -1, 0) / np.maximum(count, 1)[:, None, None]


#: A record must span at least this many times the longest correlation lag: the longest lag is
#: then still averaged over three times its own length (a 1.1 s cut meets it for modes down to
#: 4 Hz; 0.5-0.7 s cuts found no mode, or untrusted ones, before it was enforced).
MIN_LAG_MULTIPLE = 4


def _check_record_length(n_samples: int, max_lag: int) -> None:
    """Raise :class:`~oma.errors.RecordError` for a record too short for lags up to ``max_lag``."""
    need = MIN_LAG_MULTIPLE * max_lag
    if n_samples < need:
        from ..errors import RecordError

        raise RecordError(
            None, "cut.window_s",
            f"a cut window at least {need / n_samples:.2f} times as long as this one (output-only "
            f"identification correlates the response over lags up to {max_lag} samples at its analysis "
            f"rate, and a record must span {MIN_LAG_MULTIPLE} times the longest lag)",
            f"{n_samples} samples at that rate (record too short)")


def mac(a, b) -> np.ndarray:
    """Modal assurance criterion between the columns of ``a`` (l, m) and ``b`` (l, n): (m, n)."""
    a = np.asarray(a, dtype=complex).reshape(a.shape[0], -1)
    b = np.asarray(b, dtype=complex).reshape(b.shape[0], -1)
    num = np.abs(a.conj().T @ b) ** 2
    den = np.outer(np.sum(np.abs(a) ** 2, axis=0), np.sum(np.abs(b) ** 2, axis=0))
    return num / np.maximum(den, np.finfo(float).tiny)


def real_direction(shape) -> np.ndarray:
    """Real unit direction of a complex mode shape: rotated to be as real as possible, largest
    component positive."""
    phi = np.asarray(shape, dtype=complex)
    alpha = 0.5 * np.angle(np.sum(phi ** 2))
    u = np.real(phi * np.exp(-1j * alpha))
    u = u / max(np.linalg.norm(u), np.finfo(float).tiny)
    return u if u[np.argmax(np.abs(u))] >= 0 else -u


def same_mode(freq_hz, shape, other_freq_hz, other_shapes) -> np.ndarray:
    """Whether each of the ``other`` modes (frequencies (n,), shapes (l, n)) is the mode
    (``freq_hz``, ``shape`` (l,)) seen twice: within 2 % of its frequency and MAC above 0.9."""
    other_freq_hz = np.atleast_1d(np.asarray(other_freq_hz, dtype=float))
    if other_freq_hz.size == 0:
        return np.zeros(0, dtype=bool)
    close = np.abs(other_freq_hz / float(freq_hz) - 1.0) < 0.02
    return close & (mac(np.asarray(shape).reshape(-1, 1), other_shapes)[0] > 0.9)


@dataclass(frozen=True)
class SSIPoles:
    """Poles of every model order of one SSI-cov run.

    Attributes
    ----------
    order : ndarray of int, shape (n_poles,)
        Model order the pole came from.
    freq_hz, damping_ratio : ndarray, shape (n_poles,)
        Undamped natural frequency (Hz) and damping ratio of each pole (one of each conjugate pair).
    shapes : ndarray of complex, shape (n_channels, n_poles)
        Mode shapes ``C psi``.
    stable : ndarray of bool, shape (n_poles,)
        Stable against the next lower order (frequency, damping and MAC) and physical.
    orders : ndarray of int
        The orders computed.
    """

    order: np.ndarray
    freq_hz: np.ndarray
    damping_ratio: np.ndarray
    shapes: np.ndarray = field(repr=False)
    stable: np.ndarray
    orders: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "order", _ro(self.order, int))
        object.__setattr__(self, "orders", _ro(self.orders, int))
        object.__setattr__(self, "freq_hz", _ro(self.freq_hz))
        object.__setattr__(self, "damping_ratio", _ro(self.damping_ratio))
        object.__setattr__(self, "shapes", _ro(self.shapes, complex))
        object.__setattr__(self, "stable", _ro(self.stable, bool))


def ssi_poles(correlations, sample_rate_hz: float, *, block_rows: int, max_order: int,
              band_hz: tuple[float, float], max_damping: float = 0.25, tol_freq: float = 0.01,
              tol_damping: float = 0.10, tol_mac: float = 0.95) -> SSIPoles:
    """Poles of the SSI-cov model at every even order ``2 .. max_order`` and their stability.

    Parameters
    ----------
    correlations : array_like, shape (>= 2 block_rows, l, l)
        Output correlations (:func:`output_correlations`).
    sample_rate_hz : float
        Sampling rate of the correlations, Hz.
    block_rows : int
        ``i``: the Toeplitz matrix is ``(l i, l i)`` built from ``R_1 .. R_{2i-1}``.
    max_order : int
        Largest model order (at most ``l i``).
    band_hz : (float, float)
        Poles outside are not physical here.
    max_damping : float
        Poles with larger damping (or negative) are not physical.
    tol_freq, tol_damping, tol_mac : float
        Stability criteria against the next lower order.
    """
    r = np.asarray(correlations, dtype=float)
    l = r.shape[1]
    i = int(block_rows)
    # block (a, b) is R_{i + a - b}: gathered at once (a double loop of i^2 block copies took 20-40 ms
    # at i = 200)
    lag = i + np.arange(i)[:, None] - np.arange(i)[None, :]
    toeplitz = r[lag].transpose(0, 2, 1, 3).reshape(l * i, l * i)
    max_order = int(min(max_order, l * i - l))
    # the leading left singular vectors and values only, as the eigenvectors of T T^T (a full SVD
    # of the (l i)^2 Toeplitz matrix cost 2.5x as much: 74 against 30 ms at l i = 600, and most of
    # SSI's time on real records). Squaring costs precision only where s_k / s_1 approaches 1e-8,
    # far below the orders kept.
    gram, ni = toeplitz @ toeplitz.T, l * i
    ev, vec = eigh(0.5 * (gram + gram.T), subset_by_index=[ni - max_order, ni - 1], check_finite=False)
    u, s = vec[:, ::-1], np.sqrt(np.maximum(ev[::-1], 0.0))
    # no order beyond the Toeplitz matrix's numerical rank (the squared singular values lose what is
    # under 1e-7 of the first): past it the observability matrix has columns of rounding noise and
    # the shifted system is singular (session 23: a one-channel record, decimated with a steep
    # filter, was rank 50 of 60 and raised)
    rank = int(np.sum(s > 1e-7 * s[0])) if s.size and s[0] > 0 else 0
    max_order = min(max_order, rank - rank % 2)
    orders = np.arange(2, max_order + 1, 2)
    if orders.size == 0:   # no second-order system in the correlations (a silent band): no poles
        return SSIPoles(order=np.zeros(0, dtype=int), freq_hz=np.zeros(0), damping_ratio=np.zeros(0),
                        shapes=np.zeros((l, 0), dtype=complex), stable=np.zeros(0, dtype=bool), orders=orders)
    obs_full = u[:, :max_order] * np.sqrt(s[:max_order])[None, :]
    # A_n = pinv(O_up[:, :n]) O_down[:, :n] for every n from one QR of O_up: the first n columns of
    # O_up are Q[:, :n] R[:n, :n], so A_n = R[:n, :n]^-1 (Q^T O_down)[:n, :n]
    q_up, r_up = np.linalg.qr(obs_full[:-l])
    qt_down = q_up.T @ obs_full[l:]
    rec = {"order": [], "f": [], "z": [], "phi": []}
    prev = None
    stable = []
    for n in orders:
        obs = obs_full[:, :n]
        a_mat = solve_triangular(r_up[:n, :n], qt_down[:n, :n])
        lam, psi = np.linalg.eig(a_mat)
        keep = lam.imag > 0
        lam, psi = lam[keep], psi[:, keep]
        with np.errstate(divide="ignore", invalid="ignore"):
            sc = np.log(lam) * sample_rate_hz
        wn = np.abs(sc)
        f = wn / (2 * np.pi)
        z = -sc.real / np.maximum(wn, np.finfo(float).tiny)
        phi = obs[:l] @ psi
        phys = (f >= band_hz[0]) & (f <= band_hz[1]) & (z > 0) & (z < max_damping)
        st = np.zeros(f.size, dtype=bool)
        if prev is not None and prev[0].size and np.any(phys):
            # each physical pole against the nearest pole of the order below: frequency, damping
            # and the MAC of the two shapes (all poles at once: a MAC call per pole cost 0.1-0.2 s
            # of a real file's SSI runs)
            pf, pz, pphi = prev
            k = np.flatnonzero(phys)
            d = np.abs(pf[None, :] - f[k, None]) / f[k, None]
            j = np.argmin(d, axis=1)
            st[k] = ((d[np.arange(k.size), j] < tol_freq) & (np.abs(pz[j] - z[k]) < tol_damping * z[k])
                     & (np.diagonal(mac(phi[:, k], pphi[:, j])) > tol_mac))
        prev = (f[phys], z[phys], phi[:, phys])
        rec["order"].append(np.full(f.size, n))
        rec["f"].append(f)
        rec["z"].append(z)
        rec["phi"].append(phi)
        stable.append(st & phys)
    return SSIPoles(
        order=np.concatenate(rec["order"]), freq_hz=np.concatenate(rec["f"]),
        damping_ratio=np.concatenate(rec["z"]), shapes=np.hstack(rec["phi"]),
        stable=np.concatenate(stable), orders=orders,
    )


@dataclass(frozen=True)
class StabilisedModes:
    """Modes selected from a stabilisation diagram.

    Attributes
    ----------
    freq_hz, damping_ratio : ndarray, shape (n_modes,)
        Cluster medians.
    shapes : ndarray of complex, shape (n_channels, n_modes)
    support : ndarray, shape (n_modes,)
        Fraction of the orders with a stable pole in the cluster.
    clusters : tuple of ndarray
        Indices into the :class:`SSIPoles` of each mode's members.
    """

    freq_hz: np.ndarray
    damping_ratio: np.ndarray
    shapes: np.ndarray = field(repr=False)
    support: np.ndarray
    clusters: tuple = field(repr=False)

    def __post_init__(self):
        order = np.argsort(self.freq_hz)
        object.__setattr__(self, "freq_hz", _ro(np.asarray(self.freq_hz)[order]))
        object.__setattr__(self, "damping_ratio", _ro(np.asarray(self.damping_ratio)[order]))
        object.__setattr__(self, "shapes", _ro(np.asarray(self.shapes, dtype=complex)[:, order], complex))
        object.__setattr__(self, "support", _ro(np.asarray(self.support)[order]))
        object.__setattr__(self, "clusters", tuple(self.clusters[k] for k in order))

    @property
    def n_modes(self) -> int:
        return int(self.freq_hz.size)


#: Fraction cut from each end of a cluster before averaging (a trimmed mean: robust to a stray
#: pole like the median, but smooth in the data, which the jackknife needs; the jackknife
#: variance of a median is inconsistent, Efron 1982, and gave intervals 3-5 times too wide here).
TRIM = 0.2


def _centre(values) -> float:
    return float(stats.trim_mean(np.asarray(values, dtype=float), TRIM))


def _summary(poles: SSIPoles, members: np.ndarray):
    """Median frequency and damping of a cluster, and its mean shape (members scaled to unit norm
    and turned in phase onto the member nearest the median frequency before averaging)."""
    f = _centre(poles.freq_hz[members])
    z = _centre(poles.damping_ratio[members])
    rep = poles.shapes[:, members[int(np.argmin(np.abs(poles.freq_hz[members] - f)))]]
    rep = rep / max(np.linalg.norm(rep), np.finfo(float).tiny)
    acc = np.zeros_like(rep)
    for m in members:
        phi = poles.shapes[:, m] / max(np.linalg.norm(poles.shapes[:, m]), np.finfo(float).tiny)
        inner = np.vdot(phi, rep)
        acc += phi * (inner / max(abs(inner), np.finfo(float).tiny))
    return f, z, acc / len(members)


def select_modes(poles: SSIPoles, *, cut_distance: float = 0.04, min_support: float = 0.3) -> StabilisedModes:
    """Cluster the stable poles and keep the clusters present in at least ``min_support`` of the orders.

    A cluster that holds two poles of one order keeps, for that order, only the one nearest the
    cluster's median frequency (so the medians are over one pole per order).
    """
    idx = np.flatnonzero(poles.stable)
    n_orders = poles.orders.size
    if idx.size < 2:
        return StabilisedModes(np.zeros(0), np.zeros(0), np.zeros((poles.shapes.shape[0], 0)), np.zeros(0), ())
    f = poles.freq_hz[idx]
    dist_f = np.abs(f[:, None] - f[None, :]) / np.maximum(f[:, None], f[None, :])
    dist = dist_f + (1.0 - mac(poles.shapes[:, idx], poles.shapes[:, idx]))
    np.fill_diagonal(dist, 0.0)
    dist = 0.5 * (dist + dist.T)
    condensed = dist[np.triu_indices(idx.size, 1)]
    labels = fcluster(linkage(condensed, method="average"), t=cut_distance, criterion="distance")
    out_f, out_z, out_phi, out_s, out_c = [], [], [], [], []
    for lab in np.unique(labels):
        members = idx[labels == lab]
        fm = np.median(poles.freq_hz[members])
        # one pole per order: the one nearest the median frequency
        keep = []
        for n in np.unique(poles.order[members]):
            m = members[poles.order[members] == n]
            keep.append(m[int(np.argmin(np.abs(poles.freq_hz[m] - fm)))])
        members = np.array(keep)
        support = members.size / n_orders
        if support < min_support:
            continue
        fz = _summary(poles, members)
        out_f.append(fz[0])
        out_z.append(fz[1])
        out_phi.append(fz[2])
        out_s.append(support)
        out_c.append(members)
    l = poles.shapes.shape[0]
    return StabilisedModes(np.array(out_f), np.array(out_z),
                           np.array(out_phi).T if out_phi else np.zeros((l, 0)), np.array(out_s), tuple(out_c))


def match_modes(poles: SSIPoles, freq_hz, shapes, *, tol_freq: float = 0.05, min_mac: float = 0.8):
    """Frequency and damping, per reference mode, of the poles of another run nearest to it.

    For each reference mode (``freq_hz``, ``shapes`` (l, m)) the stable poles within ``tol_freq``
    (relative) whose MAC with the reference shape exceeds ``min_mac`` are taken, one per order
    (the nearest in frequency), and their medians returned: the estimator of
    :func:`select_modes` applied to this run with the clusters fixed by the reference.

    Returns
    -------
    freq_hz, damping_ratio : ndarray, shape (m,)
        NaN where no pole matched.
    shapes : ndarray of complex, shape (l, m)
        Mean shapes of the matched poles (NaN where none).
    """
    ref_f = np.asarray(freq_hz, dtype=float)
    out_f = np.full(ref_f.size, np.nan)
    out_z = np.full(ref_f.size, np.nan)
    out_phi = np.full((poles.shapes.shape[0], ref_f.size), np.nan, dtype=complex)
    idx = np.flatnonzero(poles.stable)
    if idx.size == 0:
        return out_f, out_z, out_phi
    m = mac(np.asarray(shapes).reshape(-1, ref_f.size), poles.shapes[:, idx])
    for k, fr in enumerate(ref_f):
        d = np.abs(poles.freq_hz[idx] / fr - 1.0)
        ok = (d < tol_freq) & (m[k] > min_mac)
        if not np.any(ok):
            continue
        cand = idx[ok]
        keep = []
        for n in np.unique(poles.order[cand]):
            c = cand[poles.order[cand] == n]
            keep.append(c[int(np.argmin(np.abs(poles.freq_hz[c] - fr)))])
        keep = np.array(keep)
        out_f[k], out_z[k], out_phi[:, k] = _summary(poles, keep)
    return out_f, out_z, out_phi
