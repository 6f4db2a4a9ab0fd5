"""Whittle-ML fit of one group of output-only modes (:func:`oma.output_only.ml.refine_modes_ml`
drives it; the likelihood, its gradient and information are :mod:`oma.output_only.whittle`'s).

What is here: the start (SSI's frequency, damping and direction; the input covariance ``C`` and
background ``N`` by linear least squares on the periodogram matrix), Fisher scoring with
Levenberg damping from it, the tail models of the modes outside the group's band, and the maps
between nested models (a poorer tail model's optimum as the start of a richer one's fit; the fit
less one mode as the start of the refit without it), and the quasi-Newton finish of a fit the
scoring left short of its optimum.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from .whittle import _Model, _fisher, _free_c, _nll, _residual_columns, _response, _tril, _unpack

__all__: list[str] = []

#: Fisher-scoring steps taken with one evaluation of the information matrix.
FISHER_REUSE = 3
#: Quasi-Newton iterations of :func:`_finish`. Session 22, three of the extra case's 24.8 Hz fits
#: that had stopped 130-225 units of ``-log L`` short: 97-99 % of the 200 iterations' gain within
#: 20, 98.7-99.7 % within 30; a 70 Hz fit in a flat valley of the tails' input covariance gained
#: 0.01-0.03 per iteration there, which the cap and :data:`FINISH_MIN_GAIN` keep out.
FINISH_ITER = 30
#: A finish is kept when it lowers ``-log L`` by more than this: half the 95 % quantile of
#: chi-square with one degree of freedom (3.84 / 2). A scoring end nearer its optimum than that lies
#: inside every parameter's 95 % likelihood-ratio interval around the optimum, and a finish gains
#: nothing a user could tell from noise; the drift along a flat valley gains less.
FINISH_MIN_GAIN = 1.92
#: Newton decrement ``g^T J^-1 g`` under which a scoring end is taken as converged (the Fisher step
#: would lower ``-log L`` by half of it): twice the scoring's own tolerance.
FINISH_DECREMENT = 2e-2


def _scoring(p, mod: _Model, x, *, max_iter: int = 12, tol: float = 1e-2, warm: int = 4, jm=None,
             reuse: int = None):
    """Fisher scoring with Levenberg damping from ``p``. The first ``warm`` iterations move only
    the covariance factors (the linear least-squares start of ``C`` is rough, and a full step
    from it can throw a frequency across the band); a step moves no frequency by more than a
    quarter of its starting half-power width."""
    val, g = _nll(p, mod, x)
    if not val < 1e30:   # a start whose model spectrum is singular (:func:`whittle._whitener`): no step from it
        return p, val
    lam = 1e-3
    n_modal = 2 * mod.m + mod.m * mod.l
    age, jm_at_p = 0, jm is not None
    reuse = FISHER_REUSE if reuse is None else reuse
    it = 0
    while it < max_iter:
        # the information changes slowly near the optimum: recomputed every ``reuse`` steps (and
        # after a rejected step); ``jm`` given: that of ``p``
        if jm is None or age >= reuse or (it == warm and warm > 0):
            jm, age, jm_at_p = _fisher(p, mod), 0, True
            if jm is None:
                return p, val
        age += 1
        free = np.arange(p.size) if it >= warm else np.arange(n_modal, p.size)
        jf = jm[np.ix_(free, free)]
        diag = np.maximum(np.diag(jf), 1e-12)
        fresh = jm_at_p   # every step of this iteration is from the information at ``p``
        while True:
            step = np.zeros_like(p)
            step[free] = np.linalg.solve(jf + lam * np.diag(diag), -g[free])
            step[:mod.m] = np.clip(step[:mod.m], -0.25, 0.25)
            v2, g2 = _nll(p + step, mod, x)
            if v2 <= val:
                break
            lam *= 10.0
            if age > 1:
                jm, age, jm_at_p = _fisher(p, mod), 1, True
                if jm is None:
                    return p, val
                jf = jm[np.ix_(free, free)]
                diag = np.maximum(np.diag(jf), 1e-12)
            if lam > 1e8:
                if it < warm:
                    break
                return p, val
        if lam > 1e8:
            # (a warm iteration) no step of the covariance factors alone lowers ``-log L`` from
            # ``p``; from the information at ``p`` throughout, the warm iterations left would
            # repeat this one exactly, so the full steps start now (session 23: such fits had taken
            # 61 evaluations of the likelihood and moved nothing)
            lam, it = 1e-3, warm if fresh else it + 1
            continue
        done = val - v2 < tol and it >= warm
        p, val, g, jm_at_p = p + step, v2, g2, False
        lam = max(lam / 10.0, 1e-6)
        it += 1
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
    if mod.weight is None:
        pk = x[:, :, None] * x[:, None, :].conj()
    else:   # blocks: their mean periodogram matrix, each block's equations weighted by its bins
        pk = (x @ np.conj(np.swapaxes(x, 1, 2))) / mod.weight[:, None, None]
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
    rhs = pk.ravel()
    if mod.weight is not None:
        root = np.repeat(np.sqrt(mod.weight), l * l)
        amat, rhs = amat * root[:, None], rhs * root
    amat = np.vstack([amat.real, amat.imag])
    rhs = np.concatenate([rhs.real, rhs.imag])
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
    if mod.slope:
        parts.append([0.0])   # a flat input to start
    return np.concatenate(parts)


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


def _finish(p, mod: _Model, x, *, max_iter: int = FINISH_ITER):
    """A scoring fit carried on to its optimum: at most ``max_iter`` BFGS iterations from ``p``,
    the inverse Hessian started at the inverse Fisher information (Jacobi-scaled, with a 1e-6 ridge
    so that it is positive definite where the information is singular, e.g. along a direction
    vector's unidentified length). Returns ``(p, value, iterations)``: the finish's end when it
    lowers ``-log L`` by more than :data:`FINISH_MIN_GAIN`, else ``p`` and its value; ``p``
    itself, unfinished, when its Newton decrement is under :data:`FINISH_DECREMENT`.

    Why: Levenberg-damped Fisher scoring stops where a step shrunk by a large damping factor gains
    under its tolerance, and near a column of a Cholesky factor that goes to zero (a tail's input,
    the background of a record with no noise floor) the Hessian has negative curvature that the
    information does not see, so the scoring crawls or stops there (session 21: up to 152 units of
    ``-log L`` short). Session 22, 100 records of the benchmark's extra case: the 24.8 Hz mode's
    fit stopped more than 10 units short in 44 and up to 391; its damping came out 3.7 % low on
    average with a log-error sd of 0.113 and intervals covering 87 %, at the optimum 1.0 % and
    0.059 covering 95 %. BFGS learns the missing curvature from the gradients; started from the
    information it takes Fisher-sized steps from the first iteration."""
    val, g = _nll(p, mod, x)
    jm = _fisher(p, mod) if val < 1e30 else None
    if jm is None or not np.all(np.isfinite(jm)) or not np.all(np.isfinite(g)):
        return p, val, 0
    scale = np.sqrt(np.maximum(np.diag(jm), 1e-12))
    h0 = np.linalg.inv(jm / np.outer(scale, scale) + 1e-6 * np.eye(p.size)) / np.outer(scale, scale)
    h0 = 0.5 * (h0 + h0.T)
    if g @ h0 @ g < FINISH_DECREMENT:
        return p, val, 0
    r = minimize(lambda q: _nll(q, mod, x), p, jac=True, method="BFGS",
                 options={"hess_inv0": h0, "maxiter": max_iter, "gtol": 1e-5})
    if np.all(np.isfinite(r.x)) and r.fun < val - FINISH_MIN_GAIN:
        return r.x, float(r.fun), int(r.nit)
    return p, val, int(r.nit)


def _fit_group(w, x, f0, z0, u0, derivative, *, max_iter=40, residuals=True, previous=None, tails=None,
               slope=False, weight=None):
    """ML fit of one group of modes on the bins ``w``, ``x``: frequencies, damping, unit
    directions (m, l), the negative log-likelihood, the parameters and the model; None when the
    fit fails or is worse than its start. ``residuals``: the out-of-band modes' tails as residual
    terms coherent with the modes (:func:`oma.output_only.whittle._residual_columns`; the
    constant background is then dropped for displacement and acceleration, where one of the
    residual terms is constant); ``'known'``: the columns ``tails`` (:func:`_known_tails`) plus
    a constant background; ``'background'``: the residual terms incoherent with the modes; else
    a constant background. ``previous``: (model, parameters) of a fit of a model nested in this
    one, whose optimum starts this fit (:func:`_nested_start`). ``slope``: the input's level
    varies as ``(w / w_c)^beta`` across the band, ``beta`` fitted with the rest (a coloured
    background force; :mod:`oma.output_only.whittle`). ``weight``: the bins each ``w`` stands for,
    ``x`` then the roots of their summed periodogram matrices (:mod:`oma.output_only.blocks`).
    Fisher scoring
    (Levenberg-damped) from linear least squares: on the benchmark records it reached the best
    optimum of the tried schemes (L-BFGS-B first stalled in the ill-conditioned covariance
    factors) at a third of the cost."""
    m, l = f0.size, x.shape[1] if x.ndim >= 2 else 0
    if residuals == "known":
        fx = tails if tails is not None else np.zeros((w.size, l, 0), dtype=complex)
        noise = True
    else:
        fx = _residual_columns(w, l) if residuals else np.zeros((w.size, l, 0), dtype=complex)
        noise = not residuals or derivative == 1
    mod = _Model(m, l, w, None, fx, noise,
                 (np.asarray(f0, dtype=float), np.asarray(z0, dtype=float)), coherent=residuals != "background",
                 slope=bool(slope), weight=weight)
    if mod.n_bins * l < 4 * _n_params(mod):
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
    if mod.slope:
        parts.append([pp.beta])
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
    if mod.slope:
        parts.append([pp.beta])
    return new, np.concatenate(parts)


def _signed(p, mod: _Model):
    """The model with the constant background's sign free (``_Model.signed_background``) and the
    parameters that give it the spectrum of ``p``: ``N``'s Cholesky entries replaced by ``N``'s own
    lower triangle (unchanged without a background)."""
    new = mod._replace(signed_background=True)
    if mod.signed_background or not mod.noise:
        return new, np.array(p, dtype=float)
    pp = _unpack(p, mod)
    i = 2 * mod.m + mod.m * mod.l + pp.tm[0].size
    out = np.array(p, dtype=float)
    out[i:i + pp.tl[0].size] = pp.n[pp.tl]
    return new, out


def _orthogonalised(u):
    """Symmetric (Loewdin) orthonormalisation of the columns of ``u``: ``u (u^T u)^(-1/2)``, the
    orthonormal set nearest to ``u`` that favours no column."""
    ev, vec = np.linalg.eigh(u.T @ u)
    return u @ (vec / np.sqrt(np.maximum(ev, 1e-12))) @ vec.T


def _n_params(mod: _Model) -> int:
    """Free parameters of a group model (the direction's scale is not one)."""
    m, l = mod.m, mod.l
    return (2 * m + m * (l - 1) + _free_c(mod)[0].size + (l * (l + 1) // 2 if mod.noise else 0) + int(mod.slope)
            + (m * l if mod.complex_directions else 0))
