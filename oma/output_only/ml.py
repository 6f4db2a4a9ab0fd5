"""Maximum-likelihood refinement of output-only modes on the output spectral matrix (Whittle).

After SSI-cov has fixed the number and rough place of the modes, each group of modes whose bands
overlap is refined by maximising the Whittle likelihood of the full-record periodogram matrix
``P_k = x_k x_k^H`` (harmonics already regressed out) over the bins of the group's band,

    -log L = sum_k  log det S(f_k) + x_k^H S(f_k)^-1 x_k,

with the parametric output spectrum of real modes under a white input of unknown level,

    S(f) = w^(2 d) V(f) C V(f)^H + N,    V(f)[:, r] = u_r / (w_r^2 - w^2 + 2 i zeta_r w_r w),

``u_r`` real unit directions, ``C`` the (real, positive semi-definite) modal input covariance,
``N`` a constant positive-definite background (tails of the modes outside the band, sensor noise)
and ``d`` the derivative order of the measured quantity (0 displacement, 1 velocity,
2 acceleration). Whittle (1953); for OMA: Pintelon, Guillaume & Schoukens, MSSP 21 (2007).
The bins within 0.1 Hz of a regressed milling line are left out (the regression notches them).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import minimize

__all__ = ["refine_modes_ml"]


def _tril(n):
    return np.tril_indices(n)


class _Params(NamedTuple):
    """The decoded parameter vector: frequencies ``f`` (m,), damping ``z`` (m,), unit directions
    ``u`` (m, l) and the norms ``norm`` (m,) of their raw vectors, the Cholesky factors ``lc`` (m, m)
    and ``ln`` (l, l) of the input covariance ``c`` and the noise covariance ``n``, and the index
    sets ``tm``, ``tl`` of those factors' free entries."""

    f: np.ndarray
    z: np.ndarray
    u: np.ndarray
    norm: np.ndarray
    lc: np.ndarray
    ln: np.ndarray
    c: np.ndarray
    n: np.ndarray
    tm: tuple
    tl: tuple


def _unpack(p, m, l, ref) -> _Params:
    """Decode ``p``: ``f0 (1 + zeta0 p_f)``, ``exp(p_z)``, raw directions, the two Cholesky factors."""
    f0, z0 = ref
    i = 0
    f = f0 * (1.0 + z0 * p[i:i + m]); i += m
    z = np.exp(p[i:i + m]); i += m
    vraw = p[i:i + m * l].reshape(m, l); i += m * l
    norm = np.maximum(np.linalg.norm(vraw, axis=1), 1e-300)
    tm, tl = _tril(m), _tril(l)
    lc = np.zeros((m, m)); lc[tm] = p[i:i + tm[0].size]; i += tm[0].size
    ln = np.zeros((l, l)); ln[tl] = p[i:i + tl[0].size]
    return _Params(f, z, vraw / norm[:, None], norm, lc, ln, lc @ lc.T, ln @ ln.T, tm, tl)


def _response(f, z, z0, w):
    """Normalised modal response ``2 zeta0 / (1 - (w/w_r)^2 + 2 i zeta w/w_r)``, shape (K, m)
    (peak about 1: the input covariance is O(1), which the optimiser needs)."""
    q = w[:, None] / (2 * np.pi * f[None, :])
    return (1.0 - q ** 2 + 2j * z[None, :] * q) / (2 * z0[None, :])


def _spectrum(p, m, l, w, gain, ref):
    f, z, u, _, _, _, c, n, _, _ = _unpack(p, m, l, ref)
    d = _response(f, z, ref[1], w)   # (K, m)
    v = u.T[None, :, :] / d[:, None, :]                                                    # (K, l, m)
    s = gain[:, None, None] * np.einsum("kar,rs,kbs->kab", v, c, v.conj())
    return s + n[None, :, :]


def _nll(p, m, l, w, gain, x, ref):
    """Whittle negative log-likelihood and its gradient (analytic) in the parameters ``p``."""
    f0, z0 = ref
    f, z, u, norm, lc, ln, c, n, tm, tl = _unpack(p, m, l, ref)
    q = w[:, None] / (2 * np.pi * f[None, :])
    d = _response(f, z, z0, w)                                             # (K, m)
    v = u.T[None, :, :] / d[:, None, :]                                    # (K, l, m)
    s = gain[:, None, None] * (v @ c @ np.conj(np.swapaxes(v, 1, 2))) + n[None]
    try:
        chol = np.linalg.cholesky(s)
    except np.linalg.LinAlgError:
        return 1e30, np.zeros_like(p)
    logdet = 2.0 * np.sum(np.log(np.real(np.diagonal(chol, axis1=1, axis2=2))))
    sinv = np.linalg.inv(s)
    y = (sinv @ x[:, :, None])[..., 0]
    val = float(logdet + np.real(np.sum(np.conj(x) * y)))
    gmat = sinv - y[:, :, None] * np.conj(y)[:, None, :]                   # dL/dS^T, Hermitian
    vh = np.conj(np.swapaxes(v, 1, 2))
    a = gain[:, None, None] * (vh @ gmat @ v)                              # (K, m, m)
    b = gain[:, None, None] * (c[None] @ vh @ gmat)                        # (K, m, l)
    grad = np.zeros_like(p)
    # per mode: e_r = sum_a B[r, a] u_a / d ... dL = 2 Re sum_k tr(B dV)
    bu = np.einsum("kra,ra->kr", b, u)                                     # (K, m)
    dd = -bu / d ** 2                                                      # dL/dd (times 2 Re)
    dd_df = (2 * q ** 2 - 2j * z[None, :] * q) / (f[None, :] * 2 * z0[None, :])
    dd_dz = 2j * q / (2 * z0[None, :])
    grad[:m] = 2 * np.real(np.sum(dd * dd_df, axis=0)) * f0 * z0
    grad[m:2 * m] = 2 * np.real(np.sum(dd * dd_dz, axis=0)) * z
    gv = 2 * np.real(np.sum(b / d[:, :, None], axis=0))                   # (m, l) dL/du
    gv = (gv - np.sum(gv * u, axis=1, keepdims=True) * u) / norm[:, None]
    grad[2 * m:2 * m + m * l] = gv.ravel()
    ar = np.real(np.sum(a, axis=0))
    ar = 0.5 * (ar + ar.T)
    grad[2 * m + m * l:2 * m + m * l + tm[0].size] = (2 * ar @ lc)[tm]
    gr = np.real(np.sum(gmat, axis=0))
    gr = 0.5 * (gr + gr.T)
    grad[2 * m + m * l + tm[0].size:] = (2 * gr @ ln)[tl]
    return val, grad


def _fisher(p, m, l, w, gain, ref):
    """Fisher information of the Whittle likelihood, ``J_ij = Re sum_k tr(S^-1 dS_i S^-1 dS_j)``."""
    f0, z0 = ref
    f, z, u, norm, lc, ln, c, n, tm, tl = _unpack(p, m, l, ref)
    q = w[:, None] / (2 * np.pi * f[None, :])
    d = _response(f, z, z0, w)
    v = u.T[None, :, :] / d[:, None, :]
    vh = np.conj(np.swapaxes(v, 1, 2))
    s = gain[:, None, None] * (v @ c @ vh) + n[None]
    sinv = np.linalg.inv(s)
    ds = []

    def from_dv(dv):   # dS for a change dV (K, l, m)
        t = gain[:, None, None] * (dv @ c @ vh)
        return t + np.conj(np.swapaxes(t, 1, 2))

    dd_df = (2 * q ** 2 - 2j * z[None, :] * q) / (f[None, :] * 2 * z0[None, :]) * (f0 * z0)[None, :]
    dd_dz = 2j * q / (2 * z0[None, :]) * z[None, :]
    for dd in (dd_df, dd_dz):
        for r in range(m):
            dv = np.zeros_like(v)
            dv[:, :, r] = -v[:, :, r] * (dd[:, r] / d[:, r])[:, None]
            ds.append(from_dv(dv))
    for r in range(m):
        for a in range(l):
            du = (np.eye(l)[a] - u[r] * u[r, a]) / norm[r]
            dv = np.zeros_like(v)
            dv[:, :, r] = du[None, :] / d[:, r][:, None]
            ds.append(from_dv(dv))
    for a, b in zip(*tm):
        e = np.zeros((m, m)); e[a, b] = 1.0
        dc = e @ lc.T + lc @ e.T
        ds.append(gain[:, None, None] * (v @ dc @ vh))
    for a, b in zip(*tl):
        e = np.zeros((l, l)); e[a, b] = 1.0
        ds.append(np.broadcast_to(e @ ln.T + ln @ e.T, s.shape))
    wmat = sinv[None] @ np.array(ds)                                        # (P, K, l, l)
    return np.real(np.einsum("pkab,qkba->pq", wmat, wmat))


def _scoring(p, m, l, w, gain, x, ref, *, max_iter: int = 12, tol: float = 1e-6):
    """Fisher scoring with Levenberg damping from ``p`` (near the optimum: a few steps)."""
    val, g = _nll(p, m, l, w, gain, x, ref)
    lam = 1e-3
    for _ in range(max_iter):
        jm = _fisher(p, m, l, w, gain, ref)
        diag = np.maximum(np.diag(jm), 1e-12)
        while True:
            step = np.linalg.solve(jm + lam * np.diag(diag), -g)
            v2, g2 = _nll(p + step, m, l, w, gain, x, ref)
            if v2 <= val:
                break
            lam *= 10.0
            if lam > 1e8:
                return p, val
        done = val - v2 < tol
        p, val, g = p + step, v2, g2
        lam = max(lam / 10.0, 1e-6)
        if done:
            break
    return p, val


def _initial(m, l, f, z, u, w, gain, x):
    """Start: SSI frequency, damping, direction; C and N by linear least squares on P, made PSD."""
    d = _response(np.asarray(f), np.asarray(z), np.asarray(z), w)
    v = u[None, :, :] / d[:, None, :]
    pk = x[:, :, None] * x[:, None, :].conj()
    cols = []
    for r in range(m):
        for s in range(r, m):
            e = np.zeros((m, m)); e[r, s] = e[s, r] = 1.0
            cols.append((gain[:, None, None] * np.einsum("kar,rs,kbs->kab", v, e, v.conj())).ravel())
    for a in range(l):
        for b in range(a, l):
            e = np.zeros((l, l)); e[a, b] = e[b, a] = 1.0
            cols.append(np.broadcast_to(e, pk.shape).ravel())
    amat = np.array(cols).T
    amat = np.vstack([amat.real, amat.imag])
    rhs = np.concatenate([pk.ravel().real, pk.ravel().imag])
    coef = np.linalg.lstsq(amat, rhs, rcond=None)[0]
    c = np.zeros((m, m)); n = np.zeros((l, l))
    k = 0
    for r in range(m):
        for s in range(r, m):
            c[r, s] = c[s, r] = coef[k]; k += 1
    for a in range(l):
        for b in range(a, l):
            n[a, b] = n[b, a] = coef[k]; k += 1

    def psd_chol(a, floor):
        ev, vec = np.linalg.eigh(a)
        ev = np.maximum(ev, floor * max(ev.max(), 1e-300))
        return np.linalg.cholesky((vec * ev) @ vec.T)

    lc = psd_chol(c, 1e-3)
    ln = psd_chol(n, 1e-3)
    if not np.all(np.isfinite(lc)) or not np.all(np.isfinite(ln)):
        return None
    return np.concatenate([np.zeros(m), np.log(z), u.T.ravel(), lc[_tril(m)], ln[_tril(l)]])


def refine_modes_ml(residuals, sample_rate_hz: float, freq_hz, damping, directions, *, derivative: int = 2,
                    lines_hz=(), half_width: float = 6.0, min_half_width_hz: float = 1.0,
                    line_guard_hz: float = 0.1, max_iter: int = 200, ftol: float = 2.2e-9, failed=None,
                    scoring_only: bool = False):
    """Whittle-ML frequency, damping and direction of output-only modes (see the module docstring).

    Parameters
    ----------
    residuals : sequence of ndarray, shape (l, n_samples)
        Response records of one pose with the harmonics removed (channels in a common unit).
    sample_rate_hz : float
    freq_hz, damping : array_like, shape (m,)
        Starting values (SSI).
    directions : array_like, shape (l, m)
        Starting real directions in the channels of ``residuals``.
    derivative : {0, 1, 2}
        Displacement, velocity or acceleration.
    lines_hz : array_like
        Milling lines regressed out; bins within ``line_guard_hz`` are left out.
    max_iter, ftol : int, float
        Iteration limit and relative tolerance of the L-BFGS-B optimiser.
    half_width : float
        A mode's band is ``f (1 +- half_width zeta)`` (at least ``min_half_width_hz``); modes with
        overlapping bands are fitted jointly.

    failed : float, optional
        None: a group whose fit fails (or moves a frequency by more than half its band) keeps its
        starting values; a number (NaN): it gets this value.

    Returns
    -------
    freq_hz, damping, directions : ndarray, shapes (m,), (m,), (l, m)
        Refined values.
    """
    f0 = np.asarray(freq_hz, dtype=float)
    z0 = np.asarray(damping, dtype=float)
    u0 = np.asarray(directions, dtype=float)
    fs = float(sample_rate_hz)
    l = u0.shape[0]
    f_out, z_out, u_out = f0.copy(), z0.copy(), u0.copy()
    if f0.size == 0:
        return f_out, z_out, u_out
    ok = np.zeros(f0.size, dtype=bool)
    ffts = []
    for r in residuals:
        r = np.asarray(r, dtype=float)
        n = r.shape[1]
        ffts.append((np.fft.rfftfreq(n, 1.0 / fs), np.fft.rfft(r, axis=1) / np.sqrt(fs * n)))
    hw = np.maximum(half_width * z0 * f0, min_half_width_hz)
    lo, hi = f0 - hw, f0 + hw
    order = np.argsort(lo)
    groups, cur, cur_hi = [], [order[0]], hi[order[0]]
    for k in order[1:]:
        if lo[k] <= cur_hi:
            cur.append(k); cur_hi = max(cur_hi, hi[k])
        else:
            groups.append(cur); cur, cur_hi = [k], hi[k]
    groups.append(cur)
    lines = np.asarray(lines_hz, dtype=float).ravel()
    for g in groups:
        g = np.array(g)
        a, b = lo[g].min(), hi[g].max()
        ws, xs = [], []
        for freq, x in ffts:
            sel = (freq >= a) & (freq <= b)
            if lines.size:
                sel &= np.min(np.abs(freq[:, None] - lines[None, :]), axis=1) > line_guard_hz
            ws.append(2 * np.pi * freq[sel]); xs.append(x[:, sel].T)
        w = np.concatenate(ws); x = np.concatenate(xs)
        m = g.size
        if w.size < 4 * (m + l):
            continue
        gain = w ** (2 * derivative)
        gain = gain / np.mean(gain)
        scale = np.sqrt(np.mean(np.abs(x) ** 2))
        x = x / scale
        ref = (f0[g], z0[g])
        p0 = _initial(m, l, f0[g], z0[g], u0[:, g], w, gain, x)
        if p0 is None or _nll(p0, m, l, w, gain, x, ref)[0] >= 1e30:
            continue
        if scoring_only:
            px, fun = _scoring(p0, m, l, w, gain, x, ref)
        else:
            res = minimize(_nll, p0, args=(m, l, w, gain, x, ref), jac=True, method="L-BFGS-B",
                           options={"maxiter": max_iter, "ftol": ftol})
            px, fun = _scoring(res.x, m, l, w, gain, x, ref)
        f, z, u = _unpack(px, m, l, ref)[:3]
        if not np.all(np.isfinite(px)) or np.any(np.abs(f - f0[g]) > hw[g] / 2) or np.any(z > 0.5) \
                or fun > _nll(p0, m, l, w, gain, x, ref)[0]:
            continue
        f_out[g], z_out[g] = f, z
        ok[g] = True
        for j, k in enumerate(g):
            uk = u[j] if u[j] @ u0[:, k] >= 0 else -u[j]
            u_out[:, k] = uk
    if failed is not None:
        f_out[~ok], z_out[~ok], u_out[:, ~ok] = failed, failed, failed
    return f_out, z_out, u_out
