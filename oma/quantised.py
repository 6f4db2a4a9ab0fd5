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
(1963) 431-441. K.-Y. Liang, S. L. Zeger, "Longitudinal data analysis using generalized linear
models", Biometrika 73 (1986) 13-22 (the block sandwich).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import special

from ._linalg import lstsq_normal

__all__ = ["MIN_DAMPING", "MIN_BLOCKS", "interval_terms", "free_residue_ml", "modal_form_ml", "block_labels",
           "sandwich_se"]

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


def _marquardt(state, f_now, curvature, move, *, max_iter, what):
    """Levenberg-Marquardt minimisation of a negative log-likelihood.

    ``curvature(state)`` gives the gradient and the Gauss-Newton Hessian at ``state``;
    ``move(state, delta)`` the new state and its negative log-likelihood. A step that lowers the
    objective is taken and the damping relaxed; otherwise the damping grows tenfold (at most 12
    times). Converged when no step helps or one gains less than 0.02 (log-likelihood units: a
    parameter change well below its standard error).

    Returns the final state, its objective and whether it converged.
    """
    lam = 1e-3
    for it in range(max_iter):
        grad, hess = curvature(state)
        for _ in range(12):
            a = hess + lam * np.diag(np.diag(hess) + 1e-12)
            try:
                delta = -np.linalg.solve(a, grad)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            new, f_new = move(state, delta)
            if f_new < f_now:
                break
            lam *= 10
        else:
            return state, f_now, True
        gain = f_now - f_new
        state, f_now = new, f_new
        lam = max(lam / 10, 1e-9)
        logger.debug("%s %d: -logL %.3f (gain %.3g)", what, it, f_now, gain)
        if gain < 0.02:
            return state, f_now, True
    return state, f_now, False


def _add_output_terms(hess, grad, js, lin, sl_lin, i_sig, y_k, pred_k, q, lsig_k):
    """Add output ``k``'s interval-likelihood terms to the gradient and Gauss-Newton Hessian.

    ``js`` (N, n_shared): derivatives of the output's prediction with respect to the shared
    (nonlinear and cross-output) parameters; ``lin`` (N, K): its own linear columns, parameters
    ``sl_lin``; ``i_sig`` the index of its log error scale.
    """
    n_sh = js.shape[1]
    _, g, h, gs = interval_terms(y_k, pred_k, q, np.exp(lsig_k))
    hess[:n_sh, :n_sh] += js.T @ (h[:, None] * js)
    hb = lin.T @ (h[:, None] * js)
    hess[sl_lin, :n_sh] = hb
    hess[:n_sh, sl_lin] = hb.T
    hess[sl_lin, sl_lin] = _weighted_gram(lin, h)
    grad[:n_sh] += js.T @ g
    grad[sl_lin] = lin.T @ g
    grad[i_sig] = np.sum(gs)
    hess[i_sig, i_sig] = np.sum(gs * gs) + 1e-9


def _error_scale(res, q):
    """Starting log error scale per output, and its floor.

    A scale far below the grid makes the likelihood a set-membership indicator (every parameter
    inside a polytope fits perfectly) and, where an output crosses a single rounding boundary, it
    leaves the response's amplitude undetermined (a probit model identifies only amplitude /
    scale). The floor here is 1 % of the grid; :func:`modal_form_ml` raises it to the response to
    the force sensor's own noise (:func:`input_noise_scale`) when that is known.
    """
    lo = np.log(0.01 * q.min())
    return np.maximum(np.log(np.maximum(np.sqrt(np.mean(res**2, axis=1)), 1e-300)), lo), lo


def input_noise_scale(prob, fn, zeta, phi):
    """Standard deviation of each output's response to the measured force's own noise, m.

    The measured force is the true one plus white noise of variance ``v`` per sample
    (``rec["force_noise"]``, N^2: the sensor's noise and its rounding), a two-sided PSD ``v / fs``,
    so the model driven by it misses the true response by the response to that noise:
    ``(v / fs) sum_j int h_oj(t)^2 dt`` with ``h_oj = sum_r phi_ro phi_rj g_r`` (Parseval), i.e.
    ``(v / fs) sum_rs phi_ro phi_so (phi_r . phi_s) I_rs`` with ``I_rs = int g_r g_s dt`` of the
    unit-mass impulse responses in closed form (the modal cross-correlation of random-vibration
    theory, A. Der Kiureghian, "Structural response to stationary excitation", J. Eng. Mech. Div.
    ASCE 106 (1980) 1195-1213). Exact for continuous white noise; the sampled noise differs by the
    hold's spectrum, negligible for modes below a quarter of the sampling rate. None when no
    record gives its force noise.
    """
    v = max((rec.get("force_noise") or 0.0) for rec in prob.records)
    if v <= 0 or fn.size == 0:
        return None
    w = 2.0 * np.pi * np.asarray(fn, dtype=float)
    a = np.asarray(zeta, dtype=float) * w  # decay rates
    sa = a[:, None] + a[None, :]
    i_rs = 2.0 * sa / ((w[:, None] ** 2 - w[None, :] ** 2) ** 2
                       + 4.0 * sa * (a[:, None] * w[None, :] ** 2 + a[None, :] * w[:, None] ** 2))
    phi = np.asarray(phi, dtype=float)
    var = np.einsum("ro,so,rs->o", phi, phi, (phi @ phi.T) * i_rs) * v / prob.fs
    return np.sqrt(np.maximum(var, 0.0))


def _frequency_bounds(prob, fn, step):
    """Start and bounds of ``log fn``: ``+-step`` around it, capped at the problem's resolved band
    (``prob.frequency_bounds``; uncapped for a problem without one)."""
    bounds = getattr(prob, "frequency_bounds", None)
    if bounds is not None:
        return bounds(np.asarray(fn, dtype=float), step)
    lf = np.log(np.asarray(fn, dtype=float))
    return lf, lf - step, lf + step


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

    def design(th_):
        return prob.full_design(np.exp(th_[:n_m]), np.exp(th_[n_m:]))[0]

    lf, lf_lo, lf_hi = _frequency_bounds(prob, fn, 0.2)
    th = np.concatenate([lf, np.log(zeta)])
    lo = np.concatenate([lf_lo, np.full(n_m, np.log(MIN_DAMPING))])
    hi = np.concatenate([lf_hi, np.full(n_m, np.log(max_damping))])
    x = design(th)
    scale = np.linalg.norm(x, axis=0)
    scale[scale == 0] = 1.0
    xs = x / scale
    beta = lstsq_normal(xs, y.T).T  # (n_out, K) in scaled units
    lsig, lsig_lo = _error_scale(y - beta @ xs.T, q)
    n_th = th.size
    k_lin = xs.shape[1]
    n_par = n_th + n_out * (k_lin + 1)

    def total(xs_, beta_, lsig_):
        pred = beta_ @ xs_.T
        return sum(float(np.sum(interval_terms(y[k], pred[k], q, np.exp(lsig_[k]))[0])) for k in range(n_out))

    def curvature(st):
        th_, beta_, xs_, lsig_ = st
        beta_raw = beta_ / scale
        jac = np.zeros((n_out, q.size, n_th))
        fn_c, z_c = np.exp(th_[:n_m]), np.exp(th_[n_m:])
        row, col_own = 0, n_shared
        step = 1e-6
        for rec in recs:
            n = rec["y"].shape[1]
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
            col_own += 2 * n_m + rec["nuis"].shape[1]
        pred = beta_ @ xs_.T
        hess = np.zeros((n_par, n_par))
        grad = np.zeros(n_par)
        for k in range(n_out):
            _add_output_terms(hess, grad, jac[k], xs_, slice(n_th + k * k_lin, n_th + (k + 1) * k_lin),
                              n_th + n_out * k_lin + k, y[k], pred[k], q, lsig_[k])
        return grad, hess

    def move(st, delta):
        th_, beta_, _, lsig_ = st
        th_new = np.clip(th_ + delta[:n_th], lo, hi)
        beta_new = beta_ + delta[n_th : n_th + n_out * k_lin].reshape(n_out, k_lin)
        lsig_new = np.maximum(lsig_ + np.clip(delta[n_th + n_out * k_lin :], -1.0, 1.0), lsig_lo)
        xs_new = design(th_new) / scale
        return (th_new, beta_new, xs_new, lsig_new), total(xs_new, beta_new, lsig_new)

    state = (th, beta, xs, lsig)
    (th, beta, _, lsig), f_now, converged = _marquardt(state, total(xs, beta, lsig), curvature, move,
                                                       max_iter=max_iter, what="free-residue ML")
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
    dict with ``fn, zeta, phi, sigma, nll, converged, pred, nuis_part, n_par``, and ``uncertainty``,
    a function of nothing giving :func:`_block_sandwich`'s result at the optimum (computed only
    for the fit that is kept).
    """
    recs = prob.records
    q = np.concatenate([np.full(r["y"].shape[1], r["step"]) for r in recs])
    y = np.concatenate([r["y_raw"] for r in recs], axis=1)
    n_out, n_tot = y.shape
    n_m = fn.size
    n_in = prob.n_in

    def columns(th_):
        """Forced responses (n_m, N, n_in) and own columns (N, K_own) of all records."""
        fn_, z_ = np.exp(th_[:n_m]), np.exp(th_[n_m:])
        forced = np.zeros((n_m, n_tot, n_in))
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

    def predict(forced, own_s_, phi_, beta_):
        z = np.einsum("mni,mi->mn", forced, phi_)  # (n_m, N)
        return phi_.T @ z + beta_ @ own_s_.T, z

    lf, lf_lo, lf_hi = _frequency_bounds(prob, fn, 0.2)
    th = np.concatenate([lf, np.log(np.clip(zeta, MIN_DAMPING * 1.01, max_damping * 0.99))])
    lo = np.concatenate([lf_lo, np.full(n_m, np.log(MIN_DAMPING))])
    hi = np.concatenate([lf_hi, np.full(n_m, np.log(max_damping))])
    phi = np.array(phi, dtype=float).reshape(n_m, n_in)
    forced, own = columns(th)
    own_scale = np.linalg.norm(own, axis=0)
    own_scale[own_scale == 0] = 1.0
    own_s = own / own_scale
    x_modal = predict(forced, np.zeros_like(own_s), phi, np.zeros((n_out, own_s.shape[1])))[0]
    beta = lstsq_normal(own_s, (y - x_modal).T).T
    lsig, grid_floor = _error_scale(y - predict(forced, own_s, phi, beta)[0], q)

    def scale_floor(th_, phi_):
        """Log error-scale floor per output at these parameters (see :func:`_error_scale`)."""
        s_in = input_noise_scale(prob, np.exp(th_[:n_m]), np.exp(th_[n_m:]), phi_)
        return grid_floor if s_in is None else np.maximum(grid_floor, np.log(np.maximum(s_in, 1e-300)))

    lsig = np.maximum(lsig, scale_floor(th, phi))

    def total(forced_, own_s_, phi_, beta_, lsig_):
        pred = predict(forced_, own_s_, phi_, beta_)[0]
        return sum(float(np.sum(interval_terms(y[k], pred[k], q, np.exp(lsig_[k]))[0])) for k in range(n_out))

    n_th, n_phi, k_own = 2 * n_m, n_m * n_in, own_s.shape[1]
    n_shared = n_th + n_phi
    n_par = n_shared + n_out * (k_own + 1)
    step = 1e-6

    def output_jacobians(st):
        """Per output ``k``: the derivatives of its prediction with respect to the shared
        parameters (N, n_shared), and the prediction (n_out, N)."""
        th_, phi_, beta_, lsig_, forced_, own_s_ = st
        fn_c, z_c = np.exp(th_[:n_m]), np.exp(th_[n_m:])
        pred, zmod = predict(forced_, own_s_, phi_, beta_)
        beta_raw = beta_ / own_scale
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
                    dz = (f1_ - f0_) @ phi_[m] / step  # (n,)
                    di = (i1_ - i0_) / step  # (n, 2)
                    ic = slice(col + 2 * m, col + 2 * m + 2)
                    d_th[:, row : row + n, m + which * n_m] = np.outer(phi_[m], dz) + beta_raw[:, ic] @ di.T
                    row += n
                    col += 2 * n_m + rec["nuis"].shape[1]
        js = []
        for k in range(n_out):
            # d x_k / d phi_rj = delta_kj z_r + phi_rk Y_r[:, j]
            d_phi = np.zeros((n_tot, n_phi))
            for m in range(n_m):
                d_phi[:, m * n_in : (m + 1) * n_in] = phi_[m, k] * forced_[m]
                d_phi[:, m * n_in + k] += zmod[m]
            js.append(np.hstack([d_th[k], d_phi]))
        return js, pred

    def curvature(st, jacobians=None):
        js, pred = output_jacobians(st) if jacobians is None else jacobians
        hess = np.zeros((n_par, n_par))
        grad = np.zeros(n_par)
        for k in range(n_out):
            _add_output_terms(hess, grad, js[k], st[5], slice(n_shared + k * k_own, n_shared + (k + 1) * k_own),
                              n_shared + n_out * k_own + k, y[k], pred[k], q, st[3][k])
        return grad, hess

    def move(st, delta):
        th_, phi_, beta_, lsig_, _, _ = st
        th_new = np.clip(th_ + delta[:n_th], lo, hi)
        phi_new = phi_ + delta[n_th:n_shared].reshape(n_m, n_in)
        beta_new = beta_ + delta[n_shared : n_shared + n_out * k_own].reshape(n_out, k_own)
        # the error scale follows the floor the model sets (the response to the force's noise)
        lsig_new = np.maximum(lsig_ + np.clip(delta[n_shared + n_out * k_own :], -1.0, 1.0),
                              scale_floor(th_new, phi_new))
        forced_new, own_new = columns(th_new)
        own_s_new = own_new / own_scale
        return ((th_new, phi_new, beta_new, lsig_new, forced_new, own_s_new),
                total(forced_new, own_s_new, phi_new, beta_new, lsig_new))

    state = (th, phi, beta, lsig, forced, own_s)
    state, f_now, converged = _marquardt(state, total(forced, own_s, phi, beta, lsig), curvature, move,
                                         max_iter=max_iter, what="modal-form ML")
    th, phi, beta, lsig, forced, own_s = state
    pred, _ = predict(forced, own_s, phi, beta)
    own = own_s * own_scale

    def uncertainty():
        return _block_sandwich(state, output_jacobians, curvature, recs, prob.fs, y, q, n_shared, k_own, n_out, n_m)

    return {"fn": np.exp(th[:n_m]), "zeta": np.exp(th[n_m:]), "phi": phi, "sigma": np.exp(lsig), "nll": f_now,
            "converged": converged, "pred": pred, "nuis_part": (beta / own_scale) @ (own * _nuis_mask(recs, n_m)).T,
            "n_par": n_par, "uncertainty": uncertainty}


#: Blocks of the sandwich: this many decay times of the modes (median) ...
BLOCK_DECAY_TIMES = 4.0
#: ... and at least this long, s; fewer than MIN_BLOCKS blocks give no standard errors.
MIN_BLOCK_S = 0.5
MIN_BLOCKS = 8


def block_labels(recs, fs, fn, zeta):
    """Block of each sample of the stacked records, and the first sample of each block.

    Blocks are :data:`BLOCK_DECAY_TIMES` decay times ``1 / (zeta w)`` long (the median over the
    modes: a spurious lightly damped mode the fit keeps, e.g. 0.4 % at 9.9 Hz beside the 10 Hz
    pair, must not make one block of a 20 s record; at least :data:`MIN_BLOCK_S`), contiguous
    within a record; a record's tail joins its last block, a record shorter than a block is one.
    """
    decay = 1.0 / (np.asarray(zeta, dtype=float) * 2.0 * np.pi * np.asarray(fn, dtype=float))
    block = max(BLOCK_DECAY_TIMES * float(np.median(decay)), MIN_BLOCK_S)
    per = max(int(round(block * fs)), 1)
    labels, g_count = [], 0
    for rec in recs:
        n = rec["y"].shape[1]
        k_rec = max(n // per, 1)
        labels.append(g_count + np.minimum(np.arange(n) // per, k_rec - 1))
        g_count += k_rec
    labels = np.concatenate(labels)
    return labels, np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])


def _block_sandwich(state, output_jacobians, curvature, recs, fs, y, q, n_shared, k_own, n_out, n_m):
    """Standard errors of ``(log fn, log zeta)`` at the optimum that hold for coloured residuals.

    The likelihood counts every sample as independent; the residuals of a real fit are not
    (background force filtered by dynamics the model leaves out, the rounding of a slowly moving
    signal), so its inverse Hessian is too narrow by about the ratio of the residual spectrum's
    peak to its mean. The block (cluster-robust) sandwich ``H^-1 (sum_b s_b s_b^T) H^-1`` sums the
    per-sample scores over contiguous blocks long against the residuals' correlation (here
    :data:`BLOCK_DECAY_TIMES` decay times ``1 / (zeta w)`` of the modes, :func:`block_labels`), so
    correlation inside a block is counted and blocks are nearly independent (Liang & Zeger 1986;
    the "segment jackknife" of the output-only modes without its refits). ``G / (G - 1)`` corrects
    the sum for the estimated mean. The error scales are held at their optimum (one sits on its
    floor). Fewer than :data:`MIN_BLOCKS` blocks: NaN (too short to tell its own scatter). The
    model-based standard error is a floor.

    Returns the standard errors (2 n_m,) and the number of blocks.
    """
    th, _, _, lsig, _, own_s = state
    _, starts = block_labels(recs, fs, np.exp(th[:n_m]), np.exp(th[n_m:]))
    g_count = starts.size
    if g_count < MIN_BLOCKS:
        return np.full(2 * n_m, np.nan), g_count
    js, pred = output_jacobians(state)
    _, hess = curvature(state, (js, pred))
    keep = np.arange(n_shared + n_out * k_own)  # error scales held
    try:
        h_inv = np.linalg.inv(hess[np.ix_(keep, keep)])
    except np.linalg.LinAlgError:
        return np.full(2 * n_m, np.nan), g_count
    scores = np.zeros((g_count, keep.size))
    for k in range(n_out):
        _, g, _, _ = interval_terms(y[k], pred[k], q, np.exp(lsig[k]))
        scores[:, :n_shared] += np.add.reduceat(js[k] * g[:, None], starts, axis=0)
        scores[:, n_shared + k * k_own: n_shared + (k + 1) * k_own] = np.add.reduceat(own_s * g[:, None], starts,
                                                                                    axis=0)
    return sandwich_se(h_inv, scores, h_inv)[: 2 * n_m], g_count


def sandwich_se(bread, scores, model_cov):
    """Standard errors of the block sandwich ``bread (sum_b s_b s_b^T) bread G / (G - 1)`` from the
    block scores (G, p), floored at the model-based ones (the diagonal of ``model_cov``): the
    sandwich of a few blocks is itself noisy (14 degrees of freedom: +-19 % in the standard
    error), so it is never allowed below the fit's own curvature."""
    g_count = scores.shape[0]
    cov = bread @ (scores.T @ scores) @ bread * (g_count / (g_count - 1.0))
    return np.sqrt(np.maximum(np.maximum(np.diag(cov), np.diag(model_cov)), 0.0))



def _nuis_mask(recs, n_m):
    """Mask of the nuisance columns among the own columns (free-response columns excluded)."""
    mask = []
    for rec in recs:
        mask += [0.0] * (2 * n_m) + [1.0] * rec["nuis"].shape[1]
    return np.array(mask)
