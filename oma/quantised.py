"""Maximum likelihood of a modal model from rounded (quantised) displacement.

A laser tracker's output is rounded to its resolution ``q`` (15 um) while a robot's background
response is only a few um rms. Rounding is not independent of the signal: by Bussgang's theorem
the rounded signal is ``alpha x + (uncorrelated)`` with a gain ``alpha`` that depends on where the
signal sits on the grid -- up to +-40 % for the paper's cell -- and every least-squares estimator,
H1 included, inherits it as a stiffness error; the residual is neither white nor independent of
the signal, which also biases damping. The exact likelihood of a rounded sample ``y_n`` given the
model's continuous response ``x_n`` and a small Gaussian error of scale ``s`` (the response to the
force sensor's own noise, model error) is the interval probability

    P(y_n) = Phi((y_n + q/2 - x_n) / s) - Phi((y_n - q/2 - x_n) / s),

log-concave in ``x_n``. It is maximised here by Levenberg-Marquardt over all parameters (poles by
finite differences of the regressors, everything else analytically), with ``s`` estimated too.
When ``s`` is well above ``q`` this tends to ordinary least squares; when it is small the rounding
boundaries pin the response down far better than least squares can.

References
----------
J. J. Bussgang, "Crosscorrelation functions of amplitude-distorted Gaussian signals", MIT RLE
Tech. Rep. 216 (1952). A. B. Sripad, D. L. Snyder, "A necessary and sufficient condition for
quantization errors to be uniform and white", IEEE Trans. ASSP 25 (1977) 442-448.
D. W. Marquardt, "An algorithm for least-squares estimation of nonlinear parameters", J. SIAM 11
(1963) 431-441.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import special

from .fit import lstsq_normal

__all__ = ["MIN_DAMPING", "interval_terms", "free_residue_ml", "modal_form_ml"]

logger = logging.getLogger(__name__)

#: Smallest damping ratio fitted; a mode driven to it is a sinusoid fitted to noise and is dropped.
MIN_DAMPING = 0.002


def interval_terms(y, x, q, sigma):
    """Terms of the rounded-sample likelihood ``P = Phi(b) - Phi(a)``, ``a, b = (y -+ q/2 - x)/sigma``.

    Returns ``-log P``, its first and second derivatives with respect to ``x``, and its derivative
    with respect to ``log sigma``, per sample.
    """
    a = (y - 0.5 * q - x) / sigma
    b = (y + 0.5 * q - x) / sigma
    flip = a > 0  # Phi(b) - Phi(a) on the side where it does not cancel
    pa = special.ndtr(np.where(flip, -b, a))
    pb = special.ndtr(np.where(flip, -a, b))
    p = pb - pa
    tiny = p < 1e-280
    inv_sqrt_2pi = 1.0 / np.sqrt(2.0 * np.pi)
    da, db = np.exp(-0.5 * a * a) * inv_sqrt_2pi, np.exp(-0.5 * b * b) * inv_sqrt_2pi
    p_safe = np.where(tiny, 1.0, p)
    r1 = (db - da) / p_safe
    r2 = (b * db - a * da) / p_safe
    nll = -np.log(p_safe)
    g = r1 / sigma
    h = (r2 + r1 * r1) / sigma**2
    gs = r2
    if np.any(tiny):
        # far outside the bin: Gaussian tail, -log P ~ d^2/2 with d the distance in sigmas
        d = np.where(x > y, -b, a)[tiny]
        nll[tiny] = 0.5 * d * d + np.log(np.maximum(np.abs(d), 1.0)) + 0.5 * np.log(2 * np.pi)
        g[tiny] = np.where((x > y)[tiny], d, -d) / sigma
        h[tiny] = 1.0 / sigma**2
        gs[tiny] = -d * d
    return nll, g, np.maximum(h, 1e-12 / sigma**2), gs


def _weighted_gram(x, w):
    """``x^T diag(w) x`` for ``w >= 0`` (symmetric rank-k update)."""
    from scipy.linalg.blas import dsyrk

    xw = np.asfortranarray(x * np.sqrt(w)[:, None])
    g = dsyrk(1.0, xw, trans=1)
    return np.triu(g) + np.triu(g, 1).T


def free_residue_ml(prob, fn, zeta, max_damping, *, max_iter=60):
    """Maximum likelihood of rounded displacement: Levenberg-Marquardt on all parameters.

    ``x_o = X(fn, zeta) beta_o``; the negative log-likelihood of the rounded samples is convex in
    ``beta_o`` (log-concave interval probabilities); ``fn, zeta`` enter through the regressors, whose
    derivatives are taken by finite differences (only the columns of the mode concerned). The
    scale ``s_o`` of each output is a parameter too (outer-product curvature).
    """
    recs = prob.records
    q = np.concatenate([np.full(r["y"].shape[1], r["step"]) for r in recs])
    y = np.concatenate([r["y_raw"] for r in recs], axis=1)
    n_out = y.shape[0]
    n_m = fn.size
    n_in = prob.n_in
    n_shared = n_m * n_in + (n_in if prob.residual else 0)

    def design(fn_, z_):
        return prob.full_design(fn_, z_)[0]

    th = np.concatenate([np.log(fn), np.log(zeta)])
    lo = np.concatenate([np.log(fn) - 0.2, np.full(n_m, np.log(MIN_DAMPING))])
    hi = np.concatenate([np.log(fn) + 0.2, np.full(n_m, np.log(max_damping))])
    x = design(fn, zeta)
    scale = np.linalg.norm(x, axis=0)
    scale[scale == 0] = 1.0
    xs = x / scale
    beta = lstsq_normal(xs, y.T).T  # (n_out, K) in scaled units
    lsig = np.log(np.maximum(np.sqrt(np.mean((y - beta @ xs.T) ** 2, axis=1)), 0.01 * q.min()))
    # floor of the error scale: a scale far below the grid makes the likelihood a set-membership
    # indicator (every parameter inside a polytope fits perfectly); 2 % of the grid is of the
    # order of the response to a force sensor's own noise (0.3 um for the paper's cell)
    lsig_lo = np.log(0.01 * q.min())

    def total(xs_, beta_, lsig_):
        pred = beta_ @ xs_.T
        return sum(float(np.sum(interval_terms(y[k], pred[k], q, np.exp(lsig_[k]))[0])) for k in range(n_out))

    f_now = total(xs, beta, lsig)
    lam = 1e-3
    n_th = th.size
    k_lin = xs.shape[1]
    n_par = n_th + n_out * (k_lin + 1)
    converged = False
    for it in range(max_iter):
        beta_raw = beta / scale
        jac = np.zeros((n_out, q.size, n_th))
        fn_c, z_c = np.exp(th[:n_m]), np.exp(th[n_m:])
        row, col_own = 0, n_shared
        step = 1e-6
        for rec in recs:
            n = rec["y"].shape[1]
            k_own = 2 * n_m + rec["nuis"].shape[1]
            for m in range(n_m):
                base_f, base_i = prob.mode_columns(rec, fn_c[m], z_c[m])
                sh_cols = slice(m * n_in, (m + 1) * n_in)
                ic_cols = slice(col_own + 2 * m, col_own + 2 * m + 2)
                for which in (0, 1):
                    f1 = fn_c[m] * (np.exp(step) if which == 0 else 1.0)
                    z1 = z_c[m] * (np.exp(step) if which == 1 else 1.0)
                    d_f, d_i = prob.mode_columns(rec, f1, z1)
                    contrib = ((d_f - base_f) @ beta_raw[:, sh_cols].T + (d_i - base_i) @ beta_raw[:, ic_cols].T) / step
                    jac[:, row : row + n, m + which * n_m] = contrib.T
            row += n
            col_own += k_own
        pred = beta @ xs.T
        hess = np.zeros((n_par, n_par))
        grad = np.zeros(n_par)
        for k in range(n_out):
            _, g, h, gs = interval_terms(y[k], pred[k], q, np.exp(lsig[k]))
            jt = jac[k]
            sl = slice(n_th + k * k_lin, n_th + (k + 1) * k_lin)
            hess[:n_th, :n_th] += jt.T @ (h[:, None] * jt)
            hb = xs.T @ (h[:, None] * jt)
            hess[sl, :n_th] = hb
            hess[:n_th, sl] = hb.T
            hess[sl, sl] = _weighted_gram(xs, h)
            grad[:n_th] += jt.T @ g
            grad[sl] = xs.T @ g
            js = n_th + n_out * k_lin + k
            grad[js] = np.sum(gs)
            hess[js, js] = np.sum(gs * gs) + 1e-9
        improved = False
        for _ in range(12):
            a = hess + lam * np.diag(np.diag(hess) + 1e-12)
            try:
                delta = -np.linalg.solve(a, grad)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            th_new = np.clip(th + delta[:n_th], lo, hi)
            beta_new = beta + delta[n_th : n_th + n_out * k_lin].reshape(n_out, k_lin)
            lsig_new = np.maximum(lsig + np.clip(delta[n_th + n_out * k_lin :], -1.0, 1.0), lsig_lo)
            xs_new = design(np.exp(th_new[:n_m]), np.exp(th_new[n_m:])) / scale
            f_new = total(xs_new, beta_new, lsig_new)
            if f_new < f_now:
                improved = True
                break
            lam *= 10
        if not improved:
            converged = True
            break
        gain = f_now - f_new
        th, beta, xs, lsig, f_now = th_new, beta_new, xs_new, lsig_new, f_new
        lam = max(lam / 10, 1e-9)
        logger.debug("free-residue ML %d: -logL %.3f (gain %.3g) fn %s zeta %s", it, f_now, gain,
                     np.exp(th[:n_m]), np.exp(th[n_m:]))
        if gain < 0.02:  # log-likelihood units: a parameter change well below its standard error
            converged = True
            break
    return np.exp(th[:n_m]), np.exp(th[n_m:]), beta / scale, np.exp(lsig), converged, f_now


def modal_form_ml(prob, fn, zeta, phi, max_damping, *, max_iter=60):
    """Maximum likelihood of rounded displacement in the ModalModel form itself.

    Each mode has a pole ``(fn, zeta)`` and a participation vector ``phi_r = u_r w_r / sqrt(k_r)``;
    its residue is the rank-one ``phi_r phi_r^T`` (reciprocal by construction). The response of
    output ``o`` is ``x_o = sum_r phi_ro (Y_r phi_r) + O beta_o`` with ``Y_r`` the mode's responses
    to the background force along each input and ``O`` the free-response and nuisance columns.
    Two modes of nearly equal frequency along different directions (a robot's X and Z modes) can
    only be two poles here, so the likelihood decides between one and two. Inputs and outputs
    must be the same axes.

    Returns
    -------
    dict with ``fn, zeta, phi, beta_own, sigma, nll, converged``.
    """
    recs = prob.records
    q = np.concatenate([np.full(r["y"].shape[1], r["step"]) for r in recs])
    y = np.concatenate([r["y_raw"] for r in recs], axis=1)
    n_out, n_tot = y.shape
    n_m = fn.size
    n_in = prob.n_in

    def columns(fn_, z_):
        """Forced responses (n_m, N, n_in) and own columns (N, K_own) of all records."""
        forced = np.zeros((n_m, n_tot, n_in))
        own_list = []
        k_own = sum(2 * n_m + rec["nuis"].shape[1] for rec in recs)
        own = np.zeros((n_tot, k_own))
        row, col = 0, 0
        for rec in recs:
            n = rec["y"].shape[1]
            for m in range(n_m):
                f_m, i_m = prob.mode_columns(rec, fn_[m], z_[m])
                forced[m, row : row + n] = f_m
                own[row : row + n, col + 2 * m : col + 2 * m + 2] = i_m
            k_n = rec["nuis"].shape[1]
            own[row : row + n, col + 2 * n_m : col + 2 * n_m + k_n] = rec["nuis"]
            row += n
            col += 2 * n_m + k_n
        return forced, own

    def predict(forced, own, phi_, beta_):
        z = np.einsum("mni,mi->mn", forced, phi_)  # (n_m, N)
        return phi_.T @ z + beta_ @ own.T, z

    th = np.concatenate([np.log(fn), np.log(np.clip(zeta, MIN_DAMPING * 1.01, max_damping * 0.99))])
    lo = np.concatenate([np.log(fn) - 0.2, np.full(n_m, np.log(MIN_DAMPING))])
    hi = np.concatenate([np.log(fn) + 0.2, np.full(n_m, np.log(max_damping))])
    phi = np.array(phi, dtype=float).reshape(n_m, n_in)
    forced, own = columns(np.exp(th[:n_m]), np.exp(th[n_m:]))
    own_scale = np.linalg.norm(own, axis=0)
    own_scale[own_scale == 0] = 1.0
    own_s = own / own_scale
    x_modal, _ = predict(forced, np.zeros_like(own_s), phi, np.zeros((n_out, own_s.shape[1])))
    beta = lstsq_normal(own_s, (y - x_modal).T).T
    res = y - predict(forced, own_s, phi, beta)[0]
    lsig = np.log(np.maximum(np.sqrt(np.mean(res**2, axis=1)), 0.01 * q.min()))
    lsig_lo = np.log(0.01 * q.min())

    def total(forced_, phi_, beta_, lsig_):
        pred = predict(forced_, own_s_cur[0], phi_, beta_)[0]
        return sum(float(np.sum(interval_terms(y[k], pred[k], q, np.exp(lsig_[k]))[0])) for k in range(n_out))

    own_s_cur = [own_s]
    f_now = total(forced, phi, beta, lsig)
    n_th, n_phi, k_own = 2 * n_m, n_m * n_in, own_s.shape[1]
    n_shared = n_th + n_phi
    n_par = n_shared + n_out * (k_own + 1)
    lam = 1e-3
    converged = False
    step = 1e-6
    for it in range(max_iter):
        fn_c, z_c = np.exp(th[:n_m]), np.exp(th[n_m:])
        pred, zmod = predict(forced, own_s, phi, beta)
        beta_raw = beta / own_scale
        # d x_o / d theta: finite differences of the mode's forced and free-response columns
        d_th = np.zeros((n_out, n_tot, n_th))
        for m in range(n_m):
            for which in (0, 1):
                f1 = fn_c[m] * (np.exp(step) if which == 0 else 1.0)
                z1 = z_c[m] * (np.exp(step) if which == 1 else 1.0)
                row, col = 0, 0
                for rec in recs:
                    n = rec["y"].shape[1]
                    f0_, i0_ = prob.mode_columns(rec, fn_c[m], z_c[m])
                    f1_, i1_ = prob.mode_columns(rec, f1, z1)
                    dz = (f1_ - f0_) @ phi[m] / step  # (n,)
                    di = (i1_ - i0_) / step  # (n, 2)
                    ic = slice(col + 2 * m, col + 2 * m + 2)
                    d_th[:, row : row + n, m + which * n_m] = np.outer(phi[m], dz) + beta_raw[:, ic] @ di.T
                    row += n
                    col += 2 * n_m + rec["nuis"].shape[1]
        hess = np.zeros((n_par, n_par))
        grad = np.zeros(n_par)
        for k in range(n_out):
            _, g, h, gs = interval_terms(y[k], pred[k], q, np.exp(lsig[k]))
            # d x_k / d phi_rj = delta_kj z_r + phi_rk Y_r[:, j]
            d_phi = np.zeros((n_tot, n_phi))
            for m in range(n_m):
                d_phi[:, m * n_in : (m + 1) * n_in] = phi[m, k] * forced[m]
                d_phi[:, m * n_in + k] += zmod[m]
            js = np.hstack([d_th[k], d_phi])  # (N, n_shared)
            sl = slice(n_shared + k * k_own, n_shared + (k + 1) * k_own)
            hess[:n_shared, :n_shared] += js.T @ (h[:, None] * js)
            hb = own_s.T @ (h[:, None] * js)
            hess[sl, :n_shared] = hb
            hess[:n_shared, sl] = hb.T
            hess[sl, sl] = _weighted_gram(own_s, h)
            grad[:n_shared] += js.T @ g
            grad[sl] = own_s.T @ g
            jsig = n_shared + n_out * k_own + k
            grad[jsig] = np.sum(gs)
            hess[jsig, jsig] = np.sum(gs * gs) + 1e-9
        improved = False
        for _ in range(12):
            a = hess + lam * np.diag(np.diag(hess) + 1e-12)
            try:
                delta = -np.linalg.solve(a, grad)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            th_new = np.clip(th + delta[:n_th], lo, hi)
            phi_new = phi + delta[n_th:n_shared].reshape(n_m, n_in)
            beta_new = beta + delta[n_shared : n_shared + n_out * k_own].reshape(n_out, k_own)
            lsig_new = np.maximum(lsig + np.clip(delta[n_shared + n_out * k_own :], -1.0, 1.0), lsig_lo)
            forced_new, own_new = columns(np.exp(th_new[:n_m]), np.exp(th_new[n_m:]))
            own_s_cur[0] = own_new / own_scale
            f_new = total(forced_new, phi_new, beta_new, lsig_new)
            if f_new < f_now:
                improved = True
                break
            own_s_cur[0] = own_s
            lam *= 10
        if not improved:
            converged = True
            break
        gain = f_now - f_new
        th, phi, beta, lsig, f_now = th_new, phi_new, beta_new, lsig_new, f_new
        forced, own_s = forced_new, own_s_cur[0]
        lam = max(lam / 10, 1e-9)
        logger.debug("modal-form ML %d: -logL %.3f (gain %.3g) fn %s zeta %s", it, f_now, gain,
                     np.exp(th[:n_m]), np.exp(th[n_m:]))
        if gain < 0.02:
            converged = True
            break
    pred, _ = predict(forced, own_s, phi, beta)
    return {"fn": np.exp(th[:n_m]), "zeta": np.exp(th[n_m:]), "phi": phi, "sigma": np.exp(lsig), "nll": f_now,
            "converged": converged, "pred": pred, "nuis_part": (beta / own_scale) @ (own * _nuis_mask(recs, n_m)).T,
            "n_par": n_par}


def _nuis_mask(recs, n_m):
    """Mask of the nuisance columns among the own columns (free-response columns excluded)."""
    mask = []
    for rec in recs:
        mask += [0.0] * (2 * n_m) + [1.0] * rec["nuis"].shape[1]
    return np.array(mask)
