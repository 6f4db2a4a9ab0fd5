"""Maximum-likelihood refinement of output-only modes on the output spectral matrix (Whittle).

After SSI-cov has fixed the number and rough place of the modes, each group of modes whose bands
overlap is refined by maximising the Whittle likelihood of the full-record periodogram matrix
``P_k = x_k x_k^H`` (harmonics already regressed out) over the bins of the group's band,

    -log L = sum_k  log det S(f_k) + x_k^H S(f_k)^-1 x_k,

with the parametric output spectrum of real modes under a white input of unknown level,

    S(f) = w^(2 d) V(f) C V(f)^H + N,    V(f)[:, r] = u_r / (w_r^2 - w^2 + 2 i zeta_r w_r w),

``u_r`` real unit directions, ``C`` the (real, positive semi-definite) input covariance, ``N`` a
constant positive-definite background and ``d`` the derivative order of the measured quantity
(0 displacement, 1 velocity, 2 acceleration). Whittle (1953); for OMA: Pintelon, Guillaume &
Schoukens, MSSP 21 (2007). The bins within 0.1 Hz of a regressed milling line are left out (the
regression notches them).

The tails of the modes outside the band are modelled, per group, by a constant ``N`` or (chosen
by BIC) by the responses of the other modes found, ``u_j / D_j(w)`` at their estimated frequency,
damping and direction, as extra columns of ``V`` whose input covariance is coupled to the band's
modes, plus ``N``. The one white force drives the modes in the band and the tails of those
outside, so the tails are coherent with the modes: a 70 Hz mode driven by the X and Y forces is
coherent with the X mode's mass line, which neither a constant nor an incoherent background can
represent, and which biased the 24.8 Hz mode by -1.5 % and let a spurious second mode near 80 Hz
in. Generic residual terms (``(w_c/w)^2`` and ``1`` per channel, incoherent or coherent), the
tail models of rounds 1-2, remain selectable (``residual_terms``); their freedom biased the close
pair's damping (session 6).

SSI decides how many modes there are; where it formed no cluster for a true mode (a weak mode
beside a strong one, or between two groups), the refined model of the nearest group leaves that
mode's response unexplained. Each refined group is scanned for it with the score test of one more
mode (:func:`_missing_mode`); a large excess is refitted as a mode and kept under the same
likelihood gate as every other (session 13).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from scipy.linalg import eigh

from .harmonics import at_milling_line
from .ssi import same_mode
from .whittle import (_Model, _fisher, _free_c, _input_level, _nll, _residual_columns, _response, _spectrum, _tril,
                      _unpack)

__all__ = ["refine_modes_ml", "RefinedModes"]

#: Excess of the residual scan (:func:`_missing_mode`: the largest generalised eigenvalue less 1,
#: in units of its noise ``1/sqrt(n_eff)``) above which a group is refitted with one more mode.
#: Session 13: over 135 refined groups of 70 benchmark records the largest excess without a
#: missing mode was 5.1 (median about 2); the three records whose SSI missed a true mode gave 8.2-9.6.
ADD_SIGMAS = 6.0
#: Fisher-scoring iterations of the refits without one mode (:func:`refine_modes_ml` ``evidence``;
#: started from the full fit's other modes, they converge in a few).
EVIDENCE_ITER = 6
#: Fisher-scoring steps of a jackknife replicate's refit from the full-record optimum.
JACKKNIFE_ITER = 12
#: Fisher-scoring steps taken with one evaluation of the information matrix.
FISHER_REUSE = 3


def _scoring(p, mod: _Model, x, *, max_iter: int = 12, tol: float = 1e-2, warm: int = 4, jm=None,
             reuse: int = None):
    """Fisher scoring with Levenberg damping from ``p``. The first ``warm`` iterations move only
    the covariance factors (the linear least-squares start of ``C`` is rough, and a full step
    from it can throw a frequency across the band); a step moves no frequency by more than a
    quarter of its starting half-power width."""
    val, g = _nll(p, mod, x)
    lam = 1e-3
    n_modal = 2 * mod.m + mod.m * mod.l
    age = 0
    reuse = FISHER_REUSE if reuse is None else reuse
    for it in range(max_iter):
        # the information changes slowly near the optimum: recomputed every ``reuse`` steps (and
        # after a rejected step); ``jm`` given: that of ``p``
        if jm is None or age >= reuse or (it == warm and warm > 0):
            jm, age = _fisher(p, mod), 0
        age += 1
        free = np.arange(p.size) if it >= warm else np.arange(n_modal, p.size)
        jf = jm[np.ix_(free, free)]
        diag = np.maximum(np.diag(jf), 1e-12)
        while True:
            step = np.zeros_like(p)
            step[free] = np.linalg.solve(jf + lam * np.diag(diag), -g[free])
            step[:mod.m] = np.clip(step[:mod.m], -0.25, 0.25)
            v2, g2 = _nll(p + step, mod, x)
            if v2 <= val:
                break
            lam *= 10.0
            if age > 1:
                jm, age = _fisher(p, mod), 1
                jf = jm[np.ix_(free, free)]
                diag = np.maximum(np.diag(jf), 1e-12)
            if lam > 1e8:
                if it < warm:
                    break
                return p, val
        if lam > 1e8:
            lam = 1e-3
            continue
        done = val - v2 < tol and it >= warm
        p, val, g = p + step, v2, g2
        lam = max(lam / 10.0, 1e-6)
        if done:
            break
    return p, val


def _initial(mod: _Model, f, z, u, x):
    """Start: SSI frequency, damping, direction; C and N by linear least squares on P, made PSD."""
    m, l, gain = mod.m, mod.l, mod.gain
    d = _response(np.asarray(f), np.asarray(z), np.asarray(z), mod.w)
    v = u[None, :, :] / d[:, None, :]
    if mod.q:
        v = np.concatenate([v, mod.fx], axis=2)
    mq = m + mod.q
    pk = x[:, :, None] * x[:, None, :].conj()
    cols = []
    pairs = [(r, s) for r in range(mq) for s in range(r, mq) if mod.coherent or not (r < m <= s)]
    for r, s in pairs:
        cols.append((gain[:, None, None] * (v[:, :, r:r + 1] * v[:, None, :, s].conj()
                                            + (v[:, :, s:s + 1] * v[:, None, :, r].conj() if s != r else 0))
                     ).ravel())
    if mod.noise:
        for a in range(l):
            for b in range(a, l):
                e = np.zeros((l, l)); e[a, b] = e[b, a] = 1.0
                cols.append(np.broadcast_to(e, pk.shape).ravel())
    amat = np.array(cols).T
    amat = np.vstack([amat.real, amat.imag])
    rhs = np.concatenate([pk.ravel().real, pk.ravel().imag])
    coef = np.linalg.lstsq(amat, rhs, rcond=None)[0]
    c = np.zeros((mq, mq)); n = np.zeros((l, l))
    k = 0
    for r, s in pairs:
        c[r, s] = c[s, r] = coef[k]; k += 1
    if mod.noise:
        for a in range(l):
            for b in range(a, l):
                n[a, b] = n[b, a] = coef[k]; k += 1

    def psd_chol(a, floor):
        if a.size == 0:
            return a
        ev, vec = np.linalg.eigh(a)
        ev = np.maximum(ev, floor * max(ev.max(), 1e-300))
        return np.linalg.cholesky((vec * ev) @ vec.T)

    lc = psd_chol(c, 1e-3)
    ln = psd_chol(n, 1e-3) if mod.noise else np.zeros((l, l))
    if not np.all(np.isfinite(lc)) or not np.all(np.isfinite(ln)):
        return None
    parts = [np.zeros(m), np.log(z), u.T.ravel(), lc[_free_c(mod)]]
    if mod.noise:
        parts.append(ln[_tril(l)])
    return np.concatenate(parts)


def _band_bins(ffts, a, b, lines, guard):
    """Angular frequencies (K,) and DFT vectors (K, l) of the bins in ``[a, b]`` Hz of all
    records, bins within ``guard`` of a milling line left out."""
    ws, xs = [], []
    for freq, x in ffts:
        sel = (freq >= a) & (freq <= b)
        if lines.size:
            sel &= np.min(np.abs(freq[:, None] - lines[None, :]), axis=1) > guard
        ws.append(2 * np.pi * freq[sel]); xs.append(x[:, sel].T)
    return np.concatenate(ws), np.concatenate(xs)


def _background_nll(x):
    """Negative log-likelihood of the bins under a constant background alone (its ML estimate,
    the sample covariance: ``K log det N + K l``)."""
    k, l = x.shape
    n = (x.T @ x.conj()) / k
    return float(k * np.real(np.linalg.slogdet(n)[1]) + k * l)


#: The tail model each richer one extends (its fit starts from that one's optimum).
_TAIL_PARENT = {"known": False, "background": False, True: "background"}


def _known_tails(w, tails, scale):
    """Columns of the modes outside the group (their frequencies, damping and directions as
    estimated, in the group's channel scale): ``u_j / D_j(w)`` normalised as the modes' own,
    shape (K, l, q)."""
    f, z, u = tails
    uu = u / scale[:, None]
    uu = uu / np.linalg.norm(uu, axis=0)
    d = _response(np.asarray(f, float), np.asarray(z, float), np.asarray(z, float), w)
    return (uu[None, :, :] / d[:, None, :]).astype(complex)


def _fit_group(w, x, f0, z0, u0, derivative, *, max_iter=40, residuals=True, previous=None, tails=None):
    """ML fit of one group of modes on the bins ``w``, ``x``: frequencies, damping, unit
    directions (m, l), the negative log-likelihood, the parameters and the model; None when the
    fit fails or is worse than its start. ``residuals``: the out-of-band modes' tails as residual
    terms coherent with the modes (:func:`_residual_columns`; the constant background is then
    dropped for displacement and acceleration, where one of the residual terms is constant);
    else a constant background. ``previous``: (model, parameters) of a fit of a model nested in
    this one, whose optimum starts this fit (:func:`_nested_start`). Fisher scoring (Levenberg-damped) from linear least squares: on
    the benchmark records it reached the best optimum of the tried schemes (L-BFGS-B first
    stalled in the ill-conditioned covariance factors) at a third of the cost."""
    m, l = f0.size, x.shape[1] if x.ndim == 2 else 0
    if residuals == "known":
        fx = tails if tails is not None else np.zeros((w.size, l, 0), dtype=complex)
        noise = True
    else:
        fx = _residual_columns(w, l) if residuals else np.zeros((w.size, l, 0), dtype=complex)
        noise = not residuals or derivative == 1
    mod = _Model(m, l, w, None, fx, noise,
                 (np.asarray(f0, dtype=float), np.asarray(z0, dtype=float)), coherent=residuals != "background")
    if w.size * l < 4 * _n_params(mod):
        return None
    gain = w ** (2 * derivative)
    mod = mod._replace(gain=gain / np.mean(gain))
    p0 = None
    if previous is not None and previous[0].m == m:
        p0 = _nested_start(previous[0], previous[1], mod)
        mod = mod._replace(ref=previous[0].ref)
    if p0 is None:
        p0 = _initial(mod, mod.ref[0], mod.ref[1], np.asarray(u0, dtype=float).reshape(l, m), x)
    if p0 is None:
        return None
    fun0 = _nll(p0, mod, x)[0]
    if fun0 >= 1e30:
        return None
    px, fun = _scoring(p0, mod, x, max_iter=max_iter)
    if not np.all(np.isfinite(px)) or fun > fun0:
        return None
    f, z, u = _unpack(px, mod)[:3]
    return f, z, u, fun, px, mod


def _nested_start(prev: _Model, p, mod: _Model):
    """Parameters of ``mod`` that give the same spectrum as ``p`` of the nested model ``prev``
    (constant background -> residual terms as background -> coherent residual terms): the modes
    and their ``C`` block kept, a constant background moved into the residual block whose shape
    is constant (mass line for acceleration, stiffness line for displacement), the rest near 0."""
    pp = _unpack(p, prev)
    m, l, q = mod.m, mod.l, mod.q
    c = np.zeros((m + q, m + q))
    c[:m + prev.q, :m + prev.q] = pp.c if prev.q <= q else pp.c[:m + q, :m + q]
    n = pp.n.copy()
    if prev.q == 0 and q and not mod.noise:
        for start in (0, l):   # the residual block whose shape is constant in the measured quantity
            shape = mod.gain * np.abs(mod.fx[:, 0, start]) ** 2
            if np.ptp(shape) < 1e-6 * np.max(shape):
                c[m + start:m + start + l, m + start:m + start + l] = n / np.mean(shape)
                n = np.zeros((l, l))
                break
    if not mod.coherent:
        c[m:, :m] = c[:m, m:] = 0.0
    ev, vec = np.linalg.eigh(c)
    lc = np.linalg.cholesky((vec * np.maximum(ev, 1e-6 * max(ev.max(), 1e-300))) @ vec.T)
    parts = [p[:2 * m + m * l], lc[_free_c(mod)]]
    if mod.noise:
        ev, vec = np.linalg.eigh(n)
        parts.append(np.linalg.cholesky((vec * np.maximum(ev, 1e-6 * max(ev.max(), 1e-300))) @ vec.T)[_tril(l)])
    out = np.concatenate(parts)
    return out if np.all(np.isfinite(out)) else None


def _without_mode(p, mod: _Model, j: int):
    """The model without mode ``j`` and its parameters giving the spectrum of ``p`` less that
    mode's term (its row and column of ``C`` dropped): the start of the refit without it."""
    pp = _unpack(p, mod)
    m, l = mod.m, mod.l
    rest = np.delete(np.arange(m), j)
    new = mod._replace(m=m - 1, ref=(mod.ref[0][rest], mod.ref[1][rest]))
    keep = np.delete(np.arange(m + mod.q), j)
    c = pp.c[np.ix_(keep, keep)]
    if c.size:
        ev, vec = np.linalg.eigh(c)
        lc = np.linalg.cholesky((vec * np.maximum(ev, 1e-9 * max(ev.max(), 1e-300))) @ vec.T)
    else:
        lc = c
    vraw = p[2 * m:2 * m + m * l].reshape(m, l)[rest]
    parts = [p[:m][rest], p[m:2 * m][rest], vraw.ravel(), lc[_free_c(new)]]
    if mod.noise:
        parts.append(pp.ln[_tril(l)])
    return new, np.concatenate(parts)


def _orthogonalised(u):
    """Symmetric (Loewdin) orthonormalisation of the columns of ``u``: ``u (u^T u)^(-1/2)``, the
    orthonormal set nearest to ``u`` that favours no column."""
    ev, vec = np.linalg.eigh(u.T @ u)
    return u @ (vec / np.sqrt(np.maximum(ev, 1e-12))) @ vec.T


def _n_params(mod: _Model) -> int:
    """Free parameters of a group model (the direction's scale is not one)."""
    m, l = mod.m, mod.l
    return 2 * m + m * (l - 1) + _free_c(mod)[0].size + (l * (l + 1) // 2 if mod.noise else 0)


def _information_se(p, mod: _Model, x, u, direction_scale, derivative: int = 0) -> np.ndarray:
    """Standard errors of a group's frequencies (Hz), log damping ratios, direction angles (rad)
    and log input levels (:func:`oma.output_only.whittle._input_level`) at its optimum ``p``,
    shape (4, m): per parameter the larger of the model-based variance (the
    inverse Fisher information, all parameters of the group jointly, its input covariance and
    tails included) and the robust one (the sandwich ``J^-1 (sum_k g_k g_k^T) J^-1`` of the
    bins' scores ``g_k``, which stays valid when the spectral model is misspecified: Huber 1967,
    White 1982). The Whittle bins are asymptotically independent, so the bins' scores may be
    summed as independent terms. ``u`` (m, l): the group's unit directions in its channels;
    ``direction_scale`` (l,): the channels' scale to the signal's units, where the angle is
    measured.

    Why not the segment jackknife used before: measured on 20 records of each benchmark case
    (docs/output_only.md), its damping intervals of the close 10.0 Hz mode covered 75-80 % (the
    replicates, refitted from the full-record optimum, stay in its basin along the close pair's
    ridge; 10 segments make the variance itself uncertain) and a few replicate sets collapsed to
    zero width; these cover 90-100 % for every mode, at no refits.
    """
    m, l = mod.m, mod.l
    jinv = np.linalg.pinv(_fisher(p, mod), rcond=1e-12, hermitian=True)
    g = _nll(p, mod, x, per_bin=True)[1]
    sandwich = jinv @ (g.T @ g) @ jinv
    out = np.full((4, m), np.nan)
    grad_level = _input_level(p, mod, derivative, direction_scale)[1]
    f0, z0 = mod.ref
    norms = _unpack(p, mod).norm  # of the raw direction vectors: their length is not identified
    for cov in (jinv, sandwich):
        var = np.maximum(np.diag(cov), 0.0)
        out[0] = np.fmax(out[0], f0 * z0 * np.sqrt(var[:m]))
        out[1] = np.fmax(out[1], np.sqrt(var[m:2 * m]))
        for r in range(m):
            # the raw direction vector v's covariance through w = D v / |D v| (D the channels'
            # scale): dw/dv = (I - w w^T) D / |D v|, |D v| = |v| |D u|
            i = 2 * m + r * l
            du = direction_scale * u[r]
            w = du / np.linalg.norm(du)
            jac = (np.eye(l) - np.outer(w, w)) * direction_scale[None, :] / (np.linalg.norm(du) * norms[r])
            angle_var = np.trace(jac @ cov[i:i + l, i:i + l] @ jac.T)
            out[2, r] = np.fmax(out[2, r], np.sqrt(max(angle_var, 0.0)))
        out[3] = np.fmax(out[3], np.sqrt(np.maximum(np.einsum("ri,ij,rj->r", grad_level, cov, grad_level), 0.0)))
    return out


def _missing_mode(w, x, p, mod: _Model, band, *, n_freq: int = 200, within=(0.0, np.inf)):
    """The strongest response in a group's band that its fitted model does not explain: the score
    test of adding one mode. Adding ``s a_k u u^T`` to the model spectrum ``S_k`` (``a_k`` the
    gain-weighted squared response of a mode at ``f_c``, ``zeta_c``) changes ``-log L`` at ``s = 0``
    by ``-s u^T (A - B) u`` with ``A = sum_k a_k S_k^-1 x_k x_k^H S_k^-1`` and
    ``B = sum_k a_k S_k^-1``; under the fitted model ``E[A] = B``, so the largest generalised
    eigenvalue ``r`` of ``(Re A, Re B)`` is about 1 plus noise of relative size ``1/sqrt(n_eff)``
    (``n_eff = (sum a)^2 / sum a^2``, the bins the candidate's peak spans) and far above it where a
    mode is missing. Scanned over ``f_c`` inside the band (the candidate's half-power band twice
    over clear of the band's edges, where the tails of the modes outside belong), ``zeta_c`` the
    group's median damping. Returns ``(r, n_eff, f_c, zeta_c, u)``, ``u`` the eigenvector in the
    group's channels (unit), or None."""
    pp = _unpack(p, mod)
    s = _spectrum(p, mod)[-1]
    sinv = np.linalg.inv(s)
    y = (sinv @ x[:, :, None])[..., 0]
    outer = np.real(y[:, :, None] * y[:, None, :].conj())
    sinv_r = np.real(sinv)
    zc = float(np.clip(np.median(pp.z), 0.01, 0.1))
    lo = max(band[0], within[0], w.min() / (2 * np.pi)) / (1.0 - 2.0 * zc)
    hi = min(band[1], within[1], w.max() / (2 * np.pi)) / (1.0 + 2.0 * zc)
    if not hi > lo:
        return None
    best = None
    for fc in np.linspace(lo, hi, n_freq):
        d = _response(np.array([fc]), np.array([zc]), np.array([zc]), w)[:, 0]
        a = mod.gain / np.abs(d) ** 2
        a = a / a.sum()
        amat = np.einsum("k,kij->ij", a, outer)
        bmat = np.einsum("k,kij->ij", a, sinv_r)
        try:
            ev, vec = eigh(amat, bmat)
        except np.linalg.LinAlgError:
            continue
        if best is None or ev[-1] > best[0]:
            best = (float(ev[-1]), float(1.0 / np.sum(a ** 2)), float(fc), zc, vec[:, -1] / np.linalg.norm(vec[:, -1]))
    return best


def _mode_gain(fits, fit, j: int, x):
    """The decrease of the group's negative log-likelihood that its mode ``j`` brings: the group
    refitted without it on the same bins, both with the richest tail model fitted (coherent residual
    terms: under a poorer one a spurious mode can stand in for the coherent tails). The refit starts
    from the fit less the mode's term and runs :data:`EVIDENCE_ITER` steps: the gain errs on the
    high side. None when the refit fails."""
    ref = next((ft for ft in fits if ft[5].q and ft[5].coherent), fit)
    mod0, p0 = _without_mode(ref[4], ref[5], j)
    fun0 = _scoring(p0, mod0, x, max_iter=EVIDENCE_ITER, warm=0)[1]
    return float(fun0 - ref[3]) if np.isfinite(fun0) and fun0 < 1e30 else None


def _new_mode_apart(fit, g, f0, z0, lines) -> bool:
    """Whether the last mode of a group's ``fit`` (one the scan added) is a mode of its own: not
    another group's (outside twice their half-power bands), not a second copy of one of its
    group's (:func:`oma.output_only.ssi.same_mode`, SSI's rule for its clusters: on real records a
    peak that is not quite the model's shape leaves an excess beside it), not a milling line's
    remainder (:func:`oma.output_only.harmonics.at_milling_line`, SSI's rule too)."""
    f, z, u = fit[0], fit[1], fit[2]
    fc, zc = f[-1], z[-1]
    others = np.setdiff1d(np.arange(f0.size), g)
    if np.any(np.abs(fc - f0[others]) < 2.0 * z0[others] * f0[others]):
        return False
    if np.any(same_mode(fc, u[-1], f[:-1], u[:-1].T)):
        return False
    return not at_milling_line(fc, zc, lines)[0]


def band_groups(freq_hz, damping, *, half_width: float = 6.0, min_half_width_hz: float = 1.0) -> list[list[int]]:
    """The groups of modes that :func:`refine_modes_ml` fits jointly: modes whose bands
    ``f (1 +- half_width zeta)`` (at least ``min_half_width_hz``) overlap, in order of frequency."""
    f0, z0 = np.asarray(freq_hz, dtype=float), np.asarray(damping, dtype=float)
    if f0.size == 0:
        return []
    hw = np.maximum(half_width * z0 * f0, min_half_width_hz)
    lo, hi = f0 - hw, f0 + hw
    order = np.argsort(lo)
    groups, cur, cur_hi = [], [int(order[0])], hi[order[0]]
    for k in order[1:]:
        if lo[k] <= cur_hi:
            cur.append(int(k))
            cur_hi = max(cur_hi, hi[k])
        else:
            groups.append(cur)
            cur, cur_hi = [int(k)], hi[k]
    groups.append(cur)
    return groups


class RefinedModes(NamedTuple):
    """What :func:`refine_modes_ml` returns (see there)."""

    freq_hz: np.ndarray
    damping: np.ndarray
    directions: np.ndarray
    fitted: np.ndarray
    replicates: np.ndarray | None
    standard_errors: np.ndarray
    input_level: np.ndarray


def refine_modes_ml(residuals, sample_rate_hz: float, freq_hz, damping, directions, *, derivative: int = 2,
                    lines_hz=(), half_width: float = 6.0, min_half_width_hz: float = 1.0,
                    line_guard_hz: float = 0.1, max_iter: int = 40, evidence: dict | None = None,
                    segments=None, residual_terms="auto", direction_scale=None,
                    add_missing: float | None = ADD_SIGMAS, band_hz=(0.0, np.inf)):
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
    half_width : float
        A mode's band is ``f (1 +- half_width zeta)`` (at least ``min_half_width_hz``); modes with
        overlapping bands are fitted jointly.
    max_iter : int
        Fisher-scoring iterations.
    evidence : dict, optional
        Filled, for every mode of a group that was fitted, with ``index: (gain, penalty)``: the
        decrease of the group's negative log-likelihood that the mode brings (the group refitted
        without it on the same bins, both with the richest tail model fitted) and the BIC penalty
        of the mode's parameters, ``0.5 (l + 2) log(n_bins)`` (Schwarz 1978): the mode is
        supported when the gain exceeds the penalty; an unsupported mode is dropped and its group
        refitted without it (``evidence['dropped']``: the mask of the dropped modes;
        ``evidence['added']``: the mask of the modes the scan added).
    segments : sequence of (record, start, stop), optional
        Delete-one-segment jackknife: per segment, the record's samples ``start:stop`` zeroed
        (the rest scaled to the same power) and each group's model refitted by Fisher scoring
        from the full-record optimum (at most ``JACKKNIFE_ITER`` steps: one step with the
        information held fixed gave frequency intervals covering 60-75 % for the close pair, 8
        steps with it held over 4 damping intervals covering 65-80 %).
    direction_scale : array_like, shape (l,), optional
        The replicates' direction angles are measured after multiplying the directions by this
        (the channels' scale; default 1).
    add_missing : float or None
        The scan for a mode SSI missed (:func:`_missing_mode`; default :data:`ADD_SIGMAS`): where
        a refined group's model leaves an excess above this many of its noise units, the group is
        refitted with one more mode at the excess (its band widened to hold it; moved by the fit
        within that band, re-centred once), kept when its likelihood gain exceeds its BIC penalty
        (``evidence``) and it is a mode of its own (:func:`_new_mode_apart`).
        Session 12's benchmark: SSI formed no cluster for a true mode in 3 of 140 records (the
        extra case's X beside Z in 2, the damped structure's 21 Hz between two groups in 1).
        None: no scan.
    band_hz : (float, float)
        The scan's candidates lie inside this band (the analysed one).
    residual_terms : {'auto', False, 'known', 'background', True} or a sequence of them
        The tails of the modes outside a group's band: a constant background (False); the
        responses of the other modes found (``'known'``: each ``u_j / D_j(w)`` at its estimated
        frequency, damping and direction, their input coherent with the group's modes, since the
        same white force drives them all, plus the constant background for the rest); generic
        residual terms as a frequency-dependent background (``'background'``: ``N(w)`` spanned by
        the mass- and stiffness-line shapes of every channel); or those terms coherent with the
        group's modes (True). A sequence: per group, the one with the smallest BIC. 'auto'
        (default): ``(False, 'known')``. Why (session 6, 20 records x 5 cases): the generic
        terms (a 6 x 6 covariance block) have the freedom to take a mode's skirts, and the BIC
        picked them in most close-pair groups: the X damping came out 11 % low (with 'known':
        6-8 %), and in the extra-mode case the 24.8 Hz mode's frequency error was 0.48 % mean
        and the worst record 2.04 % (with 'known': 0.33 %, 1.72 %); CPU 10-15 % less. The generic
        terms remain for tails of modes nobody found (e.g. just above the analysis band):
        ``(False, 'known', 'background', True)`` costs about 40 % more CPU.

    Returns
    -------
    freq_hz, damping, directions : ndarray, shapes (m + a,), (m + a,), (l, m + a)
        Refined values (the starting values for a group whose fit failed or moved a frequency by
        more than half its band), then the ``a`` modes the scan added (``evidence['added']``).
    fitted : ndarray of bool, shape (m,)
    replicates : ndarray, shape (3, n_segments, m) or None
        With ``segments``: frequency, damping and the angle (rad) of the direction from the
        full-record one, per segment (NaN where not fitted).
    standard_errors : ndarray, shape (4, m)
        From the information at the optimum (:func:`_information_se`): frequency (Hz), log
        damping, the direction's angle (rad, in the channels times ``direction_scale``) and the
        log input level; NaN where not fitted.
    input_level : ndarray, shape (m,)
        Each mode's input level in the channels times ``direction_scale``, as displacement
        (:func:`oma.output_only.whittle._input_level`: ``E|u . F|^2 / k^2`` per Hz, two-sided);
        NaN where not fitted.
    """
    f0 = np.asarray(freq_hz, dtype=float)
    z0 = np.asarray(damping, dtype=float)
    u0 = np.asarray(directions, dtype=float)
    fs = float(sample_rate_hz)
    l = u0.shape[0]
    f_out, z_out, u_out = f0.copy(), z0.copy(), u0.copy()
    ok = np.zeros(f0.size, dtype=bool)
    reps = None if segments is None else np.full((3, len(segments), f0.size), np.nan)
    se = np.full((4, f0.size), np.nan)
    level = np.full(f0.size, np.nan)
    dscale = np.ones(l) if direction_scale is None else np.asarray(direction_scale, dtype=float)
    if f0.size == 0:
        return RefinedModes(f_out, z_out, u_out, ok, reps, se, level)

    def spectra(rs):
        out = []
        for r in rs:
            r = np.asarray(r, dtype=float)
            out.append((np.fft.rfftfreq(r.shape[1], 1.0 / fs), np.fft.rfft(r, axis=1) / np.sqrt(fs * r.shape[1])))
        return out

    ffts = spectra(residuals)
    gapped = []
    for i, a, b in segments or ():
        rs = [np.asarray(r, dtype=float) for r in residuals]
        r = rs[i].copy()
        r[:, a:b] = 0.0
        rs[i] = r * np.sqrt(r.shape[1] / max(r.shape[1] - (b - a), 1))
        gapped.append(spectra(rs))
    hw = np.maximum(half_width * z0 * f0, min_half_width_hz)
    lo, hi = f0 - hw, f0 + hw
    groups = band_groups(f0, z0, half_width=half_width, min_half_width_hz=min_half_width_hz)
    lines = np.asarray(lines_hz, dtype=float).ravel()
    kinds = (False, "known") if residual_terms == "auto" else \
        tuple(residual_terms) if isinstance(residual_terms, (tuple, list)) else (residual_terms,)
    dropped = np.zeros(f0.size, dtype=bool)
    added = np.zeros(f0.size, dtype=bool)

    def fit_chain(g, w, x, ug):
        """The group's fits along the nested tail models; the chosen one by BIC; None if none."""
        fits, by_kind = [], {}
        for r in kinds:
            # each richer model started from the optimum of the model it extends (same spectrum,
            # so its fit can only improve the likelihood); the first from SSI's directions and, for
            # close modes, also from their symmetric orthogonalisation (SSI mixes the directions of
            # close modes, and the likelihood has local optima there): the better of the two
            prev = by_kind.get(_TAIL_PARENT[r], by_kind.get(False)) if r in _TAIL_PARENT else None
            starts = [ug] if prev is not None or g.size < 2 else [ug, _orthogonalised(ug)]
            tails = None
            if r == "known":
                others = np.setdiff1d(np.arange(f0.size), g)
                if others.size == 0:
                    continue  # no mode outside the group: the constant background is the same model
                tails = _known_tails(w, (f0[others], z0[others], u0[:, others]), scale)
            cands = [_fit_group(w, x, f0[g], z0[g], st, derivative, max_iter=max_iter, residuals=r, previous=prev,
                                tails=tails)
                     for st in starts]
            cands = [ft for ft in cands if ft is not None]
            if cands:
                ft = min(cands, key=lambda c: c[3])
                fits.append(ft)
                by_kind[r] = (ft[5], ft[4])
        if not fits:
            return None
        # the tail model with the smallest BIC
        return fits, min(fits, key=lambda ft: ft[3] + 0.5 * _n_params(ft[5]) * np.log(w.size))

    def group_bins(g, band):
        """The band's bins, its DFT vectors in channels scaled to unit power in the band (a mode's
        direction there is not dominated by a channel that is loud elsewhere in the record, where
        a small error of the starting direction would be magnified), the scale, and the group's
        starting directions in those channels."""
        w, x = _band_bins(ffts, *band, lines, line_guard_hz)
        scale = np.sqrt(np.mean(np.abs(x) ** 2, axis=0)) if x.size else np.ones(l)
        scale = np.where(scale > 0, scale, 1.0)
        ug = u0[:, g] / scale[:, None]
        return w, x / scale, scale, ug / np.linalg.norm(ug, axis=0)

    for g in groups:
        g = np.array(g)
        band = (lo[g].min(), hi[g].max())
        w, x, scale, ug = group_bins(g, band)
        if x.size == 0:
            continue
        chain = fit_chain(g, w, x, ug)
        if chain is None:
            continue
        fits, fit = chain
        if evidence is not None:
            # each mode against the group without it (:func:`_mode_gain`); the penalty is that of
            # the mode's own parameters (frequency, damping, direction, input variance)
            ref_fit = next((ft for ft in fits if ft[5].q and ft[5].coherent), fit)
            weak = np.zeros(g.size, dtype=bool)
            for j, k in enumerate(g):
                if ref_fit[5].m == 1 and not ref_fit[5].q and not ref_fit[5].noise:
                    continue
                gain = _mode_gain(fits, fit, j, x)
                if gain is not None:
                    evidence[int(k)] = (gain, 0.5 * (l + 2) * np.log(w.size))
            # the least supported mode, if under its penalty, is dropped (two candidates for one
            # peak each look redundant while the other is there: only one of them goes)
            margin = np.array([evidence[int(k)][0] - evidence[int(k)][1] if int(k) in evidence else np.inf
                               for k in g])
            if margin.size and margin.min() < 0:
                weak[int(np.argmin(margin))] = True
            if np.any(weak):
                dropped[g[weak]] = True
                g, ug = g[~weak], ug[:, ~weak]
                chain = fit_chain(g, w, x, ug) if g.size else None
                if chain is None:
                    continue
                fits, fit = chain
        f, z, u, fun, px, mod = fit
        if add_missing is not None and not np.any(np.abs(f - f0[g]) > hw[g] / 2):
            found = _missing_mode(w, x, px, mod, band, within=band_hz)
            if found is not None and found[0] > 1.0 + add_missing / np.sqrt(found[1]):
                # a mode the group's model leaves unexplained (SSI formed no cluster for it): the
                # group refitted with it, on a band widened to hold the candidate's own band (the
                # refit may move it: once re-centred where it went), kept when the likelihood gains
                # more than the mode's BIC penalty (the gate of every mode) and it is a mode of its
                # own (:func:`_new_mode_apart`)
                _, _, fc, zc, uc = found
                uc = uc * scale
                f0, z0 = np.append(f0, fc), np.append(z0, zc)
                u0 = np.column_stack([u0, uc / np.linalg.norm(uc)])
                hw, lo, hi = np.append(hw, 0.0), np.append(lo, 0.0), np.append(hi, 0.0)
                g_c = np.append(g, f0.size - 1)
                for _attempt in range(2):
                    hw[-1] = max(half_width * z0[-1] * f0[-1], min_half_width_hz)
                    lo[-1], hi[-1] = f0[-1] - hw[-1], f0[-1] + hw[-1]
                    band_c = (min(band[0], lo[-1]), max(band[1], hi[-1]))
                    w_c, x_c, scale_c, ug_c = group_bins(g_c, band_c)
                    chain_c = fit_chain(g_c, w_c, x_c, ug_c)
                    if chain_c is not None and not band_c[0] <= chain_c[1][0][-1] <= band_c[1]:
                        chain_c = None   # the fit took it out of the band: not a mode of this band
                    if chain_c is None or abs(chain_c[1][0][-1] - f0[-1]) <= hw[-1] / 2:
                        break
                    f0[-1], z0[-1] = chain_c[1][0][-1], float(np.clip(chain_c[1][1][-1], 0.005, 0.2))
                gain, penalty = None, 0.5 * (l + 2) * np.log(max(w_c.size, 1))
                if chain_c is not None:
                    fits_c, fit_c = chain_c
                    gain = _mode_gain(fits_c, fit_c, g_c.size - 1, x_c)
                apart = chain_c is not None and _new_mode_apart(fit_c, g_c, f0, z0, lines)
                if gain is not None and apart and gain > penalty \
                        and not np.any(np.abs(fit_c[0] - f0[g_c]) > hw[g_c] / 2) and not np.any(fit_c[1] > 0.5):
                    f_out, z_out = np.append(f_out, f0[-1]), np.append(z_out, z0[-1])
                    u_out = np.column_stack([u_out, u0[:, -1]])
                    ok, dropped, added = np.append(ok, False), np.append(dropped, False), np.append(added, True)
                    se = np.column_stack([se, np.full(4, np.nan)])
                    level = np.append(level, np.nan)
                    if reps is not None:
                        reps = np.concatenate([reps, np.full((3, reps.shape[1], 1), np.nan)], axis=2)
                    if evidence is not None:
                        evidence[int(f0.size - 1)] = (gain, penalty)
                    g, band, w, x, scale, ug, fits, fit = g_c, band_c, w_c, x_c, scale_c, ug_c, fits_c, fit_c
                    f, z, u, fun, px, mod = fit
                else:
                    f0, z0, u0 = f0[:-1], z0[:-1], u0[:, :-1]
                    hw, lo, hi = hw[:-1], lo[:-1], hi[:-1]
        if np.any(np.abs(f - f0[g]) > hw[g] / 2) or np.any(z > 0.5):
            continue
        f_out[g], z_out[g] = f, z
        ok[g] = True
        for j, k in enumerate(g):
            uk = u[j] * scale / np.linalg.norm(u[j] * scale)
            u_out[:, k] = uk if uk @ u0[:, k] >= 0 else -uk
        se[:, g] = _information_se(px, mod, x, u, dscale * scale, derivative)
        level[g] = _input_level(px, mod, derivative, dscale * scale)[0]
        if gapped:
            # the information is the expected one (it depends on the parameters, not the data):
            # every replicate starts from the full-record optimum, so from the same matrix
            jm = _fisher(px, mod)
            for s_i, sp in enumerate(gapped):
                xj = _band_bins(sp, *band, lines, line_guard_hz)[1] / scale[None, :]
                pj, vj = _scoring(px, mod, xj, max_iter=JACKKNIFE_ITER, warm=0, jm=jm)
                if not vj < 1e30:
                    continue
                fj, zj, uj = _unpack(pj, mod)[:3]
                if np.all(np.isfinite(pj)):
                    reps[0, s_i, g], reps[1, s_i, g] = fj, zj
                    ua, ub = uj * (dscale * scale)[None, :], u * (dscale * scale)[None, :]
                    cosine = np.abs(np.sum(ua * ub, axis=1)) / (np.linalg.norm(ua, axis=1) * np.linalg.norm(ub, axis=1))
                    reps[2, s_i, g] = np.arccos(np.minimum(cosine, 1.0))
    if evidence is not None:
        evidence["dropped"] = dropped
        evidence["added"] = added
    return RefinedModes(f_out, z_out, u_out, ok, reps, se, level)
