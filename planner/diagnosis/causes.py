"""Candidate causes: each an extension of the model with few parameters, fitted on the fit halves.

Every candidate works on the part of the comparison where its signature lives
(:mod:`~planner.diagnosis.compare`) and returns an :class:`Extension`: the fitted parameters
(physical units in the key names) and its prediction of that part on the validation halves, which
the diagnosis scores against the baseline.

========================  =========  ==============================================================
cause                     part       extension, fit, parameters
========================  =========  ==============================================================
runout                    force      one radius offset per tooth (form-free: an eccentric axis and
                                     unequal radii are both patterns of offsets); harmonics of the
                                     rigid-tool force (:func:`~planner.diagnosis.forcemodel.
                                     analytic_harmonics`) fitted by weighted least squares. Reported:
                                     half the spread of the radii (with two teeth only
                                     ``rho_0 - rho_1`` acts: ``A |cos(phase)|`` of an eccentric axis).
force_sensor_dynamics     force      measured = ``w^2 / (s^2 + 2 zeta w s + w^2)`` x true force;
                                     the resonance multiplies the predicted harmonics. Frequency
                                     and damping (with the coefficients free again), multi-start
                                     least squares.
nonlinear_cutting         force      size effect ``K ~ (h / h_ref)^-p`` fitted with the coefficients
                                     free: the shape of the force pulse the linear-plus-edge model
                                     cannot take, whatever the law's form. ``h_ref`` is the first
                                     record's feed per tooth (the fitted coefficients hold there).
channel_delay             structure  displacement read at ``t - delay``; 1-D search (+-100 ms).
unmodeled_mode            structure  one more mode ``u u^T / (k (1 - r^2 + 2 i zeta r))``: for each
                                     trial ``(f_n, zeta)`` the symmetric matrix ``u u^T / k`` is
                                     linear (variable projection), then its dominant eigenpair;
                                     ``f_n`` inside the records' band.
cross_coupling            structure  one mode's direction turned (two angles), its stiffness kept;
                                     the mode that gains most among those inside the band.
pose_drift                structure  every natural frequency inside the band scaled by ``s0 (1 + r
                                     t / T)`` along the record (mass and damping ratio kept), or by
                                     a step ``s0 (1 + r [t >= t_s])``; ``r`` is the relative change
                                     over the record.
                                     The form that fits the first half better predicts the second.
process_damping           stability  ``C`` of Budak & Tunc's flank force in the closed-loop force
                                     spectrum (:mod:`~planner.diagnosis.closedloop`), refined on
                                     the force harmonics (simulated, the coefficients re-adjusted
                                     at each trial) where the forced vibration carries it.
========================  =========  ==============================================================

The band is the one every record shows (:func:`~planner.diagnosis.response.visible_band_hz`:
the anti-alias cut-off ``0.4 fs``). A mode of the model above it (a spindle/tool mode in a 1 kHz
record) is held as given; :func:`fit_above_band_compliance` measures the one thing the records tell
of it, its compliance in the band, as the alternative the structure causes must beat.

Every candidate is fitted on top of the re-fitted cutting coefficients
(:mod:`~planner.diagnosis.coefficients`), the baseline it must beat; the force candidates live in
:mod:`~planner.diagnosis.forcefits`. Force candidates are validated with the time-domain simulator
(:func:`~planner.diagnosis.forcemodel.simulated_harmonics` with the fitted
:class:`stability.simulate.Effects`); structure candidates by the extended model's response to the
measured force; process damping by the closed-loop spectrum.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from oma.modal import ModalModel
from oma.synthetic import hold_equalised
from stability.simulate import Effects, ProcessDamping

from .coefficients import _units, coefficient_basis, coefficient_start, expand
from .compare import Parts
from .extension import Extension, _failed, _sumsq
from .forcefits import _force_residuals, _initial_thetas, fit_force_sensor, fit_nonlinear, fit_runout
from .response import Delayer, modal_response, unit_mode_response, views_band_hz

__all__ = ["Extension", "CANDIDATES", "fit_candidate", "fit_above_band_compliance"]


def _levenberg_marquardt(fun, x0, *, step, lower=None, upper=None, max_iter=30, tol=1e-10):
    """Minimise ``sum(fun(x)^2)`` over a few parameters (forward-difference Jacobian, Marquardt damping).

    For the structure fits, whose residual vectors are long and parameters few. Returns ``(x,
    cost, n_evaluations, converged)``.
    """
    x = np.asarray(x0, dtype=float)
    step = np.broadcast_to(np.asarray(step, dtype=float), x.shape)
    lo = np.full(x.shape, -np.inf) if lower is None else np.asarray(lower, dtype=float)
    hi = np.full(x.shape, np.inf) if upper is None else np.asarray(upper, dtype=float)
    x = np.clip(x, lo, hi)
    f = fun(x)
    cost = _sumsq(f)
    lam = 1e-3
    n_eval = 1
    converged = False
    for _ in range(max_iter):
        jac = np.empty((f.size, x.size))
        for j in range(x.size):
            xj = x.copy()
            xj[j] += step[j]
            jac[:, j] = (fun(xj) - f) / step[j]
        n_eval += x.size
        jtj = jac.T @ jac
        g = jac.T @ f
        improved = False
        for _ in range(8):
            dx = -np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-30), g)
            xn = np.clip(x + dx, lo, hi)
            fn_ = fun(xn)
            n_eval += 1
            cn = _sumsq(fn_)
            if cn < cost:
                improved = True
                rel = (cost - cn) / max(cost, 1e-300)
                x, f, cost = xn, fn_, cn
                lam = max(lam / 5.0, 1e-9)
                break
            lam *= 10.0
        if not improved or rel < tol:
            converged = True
            break
    return x, cost, n_eval, converged


# --------------------------------------------------------------------------------- structure
def _structure_objective(parts: Parts, predictions, basis_model=None) -> float:
    st = parts.structure
    return float(sum(_sumsq(st.fit_residual(i, p, basis_model=basis_model)) for i, p in enumerate(predictions)))


def fit_delay(parts: Parts) -> Extension:
    st = parts.structure
    if not st.views:
        return _failed("channel_delay", "structure", "no displacement")
    delayers = [Delayer(p, v.sample_rate_hz) for p, v in zip(st.baseline, st.views)]

    def cost(tau):
        return _structure_objective(parts, [d(tau) for d in delayers])

    # the structure's response is slow (robot modes): a 4 ms grid brackets the minimum
    grid = np.linspace(-0.1, 0.1, 51)
    costs = np.array([cost(t) for t in grid])
    k = int(np.argmin(costs))
    res = optimize.minimize_scalar(cost, bounds=(grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]),
                                   method="bounded", options={"xatol": 1e-6})
    tau = float(res.x)
    pred = [d(tau) for d in delayers]
    # standard error from the cost's curvature, sigma^2 = 2 s^2 / cost'' with s^2 the residual
    # variance per element (an underestimate where the tracker's rounding is correlated)
    h = 2e-4
    c0, cp, cm = float(res.fun), cost(tau + h), cost(tau - h)
    curv = (cp + cm - 2.0 * c0) / h**2
    n_el = sum(st.fit_residual(i, p).size for i, p in enumerate(pred))
    tau_sigma = math.sqrt(2.0 * c0 / max(n_el - 1, 1) / curv) if curv > 0 else float("inf")
    return Extension("channel_delay", "structure", {"delay_s": tau, "delay_s_sigma": tau_sigma}, bool(res.success),
                     "bounded 1-D search",
                     pred, None, None, {"kind": "delay", "delay_grid_s": grid, "cost": costs})


_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def _sym_columns(y):
    """Regressor columns of a symmetric 3x3 matrix acting on y (3, n): shape (3, n, 6)."""
    out = np.zeros((3, y.shape[1], 6))
    for c, (a, b) in enumerate(_SYM):
        out[a, :, c] = y[b]
        if a != b:
            out[b, :, c] = y[a]
    return out


def _sym_matrix(m):
    out = np.zeros((3, 3))
    for v, (a, b) in zip(m, ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
        out[a, b] = out[b, a] = v
    return out


def _sym_normal_equations(y, target, q, axes):
    """Normal equations of ``target ~ M y`` over a symmetric 3x3 ``M``, the columns projected off ``q``.

    Parameters
    ----------
    y : ndarray, shape (3, n)
        Force channels through a mode of unit static gain.
    target : ndarray, shape (n_axes * n,)
        Residual of the measured axes, already orthogonal to ``q``.
    q : ndarray, shape (n_axes * n, m)
        Orthonormal nuisance columns (the structure's free responses).
    axes : ndarray of int
        Measured displacement axes.

    Returns
    -------
    gram : ndarray, shape (6, 6)
    rhs : ndarray, shape (6,)
        Built from 3x3 products of ``y`` without forming the (3 n, 6) design matrix.
    """
    n = y.shape[1]
    s = y @ y.T
    r = np.zeros((3, n))
    r[axes] = target.reshape(axes.size, n)
    t = r @ y.T
    qr = np.zeros((3, n, q.shape[1]))
    qr[axes] = q.reshape(axes.size, n, q.shape[1])
    p = np.einsum("anm,jn->amj", qr, y)  # (3, m, 3): Q_a^T y_j
    measured = np.zeros(3, dtype=bool)
    measured[axes] = True
    entries = [[(a, b)] + ([(b, a)] if a != b else []) for a, b in _SYM]
    gram = np.zeros((6, 6))
    rhs = np.zeros(6)
    qa = np.zeros((q.shape[1], 6))
    for c, ec in enumerate(entries):
        for ra, yi in ec:
            if measured[ra]:
                rhs[c] += t[ra, yi]
                qa[:, c] += p[ra, :, yi]
        for d, ed in enumerate(entries):
            acc = 0.0
            for ra, yi in ec:
                for rb, yj in ed:
                    if ra == rb and measured[ra]:
                        acc += s[yi, yj]
            gram[c, d] = acc
    return gram - qa.T @ qa, rhs


def fit_unmodeled_mode(parts: Parts) -> Extension:
    st = parts.structure
    if not st.views:
        return _failed("unmodeled_mode", "structure", "no displacement")
    targets = [st.fit_residual(i, p) for i, p in enumerate(st.baseline)]
    held = [hold_equalised(v.force[:, :v.split], axis=-1) for v in st.views]   # once for every trial mode

    def solve(fn, zeta):
        gram = np.zeros((6, 6))
        g = np.zeros(6)
        bb = 0.0
        for i, v in enumerate(st.views):
            y = unit_mode_response(fn, zeta, v.force[:, :v.split], v.sample_rate_hz, held=held[i])
            gi, ri = _sym_normal_equations(y, targets[i], st._basis(i, None), st.axes[i])
            gram += gi
            g += ri
            bb += float(np.sum(targets[i] ** 2))
        m = np.linalg.solve(gram + 1e-12 * np.trace(gram) * np.eye(6), g)
        return bb - float(g @ m), m

    # the new mode's frequency inside the band every record shows (response.visible_band_hz):
    # above it the anti-alias filter leaves nothing to identify it by
    band = views_band_hz(st.views)
    # (1) a grid over the frequency (damping 3 %), then over the damping; (2) Nelder-Mead
    grid = np.geomspace(1.0, band, 64)
    costs = np.array([solve(f, 0.03)[0] for f in grid])
    k = int(np.argmin(costs))
    zetas = np.geomspace(0.005, 0.3, 9)
    zc = np.array([solve(grid[k], z)[0] for z in zetas])

    def obj(x):
        return solve(math.exp(x[0]), math.exp(x[1]))[0]

    x0 = [math.log(grid[k]), math.log(zetas[int(np.argmin(zc))])]
    best = optimize.minimize(obj, x0, method="Nelder-Mead",
                             bounds=[(math.log(0.5), math.log(band)), (math.log(1e-3), math.log(0.9))],
                             options={"xatol": 1e-3, "fatol": 1e-10 * abs(costs[k]), "maxiter": 60,
                                      "initial_simplex": [x0, [x0[0] + 0.03, x0[1]], [x0[0], x0[1] + 0.3]]})
    fn, zeta = math.exp(best.x[0]), math.exp(best.x[1])
    _, m = solve(fn, zeta)
    evals, evecs = np.linalg.eigh(_sym_matrix(m))
    j = int(np.argmax(np.abs(evals)))
    lam, u = float(evals[j]), evecs[:, j]
    u = u * np.sign(u[np.argmax(np.abs(u))])
    if not lam > 0 or not 0 < zeta < 1:
        return Extension("unmodeled_mode", "structure", {"natural_frequency_hz": fn}, False,
                         "no mode with positive stiffness fits the residual", [], None, None,
                         {"kind": "mode_search", "freq_hz": grid, "cost": costs})
    mdl = st.model
    ext = ModalModel(np.append(mdl.natural_frequency_hz, fn), np.append(mdl.damping_ratio, zeta),
                     np.append(mdl.stiffness_N_m, 1.0 / lam), np.vstack([mdl.directions, u]),
                     residual_compliance_m_N=mdl.residual_compliance_m_N)
    pred = [st.response(i, ext) for i in range(len(st.views))]
    params = {"natural_frequency_hz": fn, "damping_ratio": zeta, "stiffness_N_m": 1.0 / lam,
              "direction": [float(c) for c in u]}
    return Extension("unmodeled_mode", "structure", params, bool(best.success), str(best.message), pred, ext, None,
                     {"kind": "mode_search", "freq_hz": grid, "cost": costs})


def _perpendicular(u):
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def fit_cross_coupling(parts: Parts) -> Extension:
    st = parts.structure
    if not st.views:
        return _failed("cross_coupling", "structure", "no displacement")
    mdl = st.model
    # only a mode the records resolve can be turned: one above their band (a spindle/tool mode in
    # a 1 kHz record) shows only as a static compliance, and turning it would trade that
    # compliance between the axes, whatever its true direction (response.resolved_modes)
    band = views_band_hz(st.views)
    candidates = [r for r in range(mdl.n_modes) if mdl.natural_frequency_hz[r] <= band]
    if not candidates:
        return _failed("cross_coupling", "structure", f"no mode of the model inside the records' band "
                       f"(<= {band:.4g} Hz)")
    targets = [st.fit_residual(i, p) for i, p in enumerate(st.baseline)]
    best = None
    for r in candidates:
        u0 = mdl.directions[r]
        k = float(mdl.stiffness_N_m[r])
        ys = [unit_mode_response(mdl.natural_frequency_hz[r], mdl.damping_ratio[r], v.force, v.sample_rate_hz)
              for v in st.views]
        # (1) the mode's term u u^T / k as a free symmetric matrix: linear least squares
        gram = np.zeros((6, 6))
        g = np.zeros(6)
        for i, (v, y) in enumerate(zip(st.views, ys)):
            yf = y[:, :v.split]
            q = st._basis(i, None)
            own = (np.outer(u0, u0) @ yf / k)[st.axes[i]].ravel()
            gi, ri = _sym_normal_equations(yf, targets[i] + own - q @ (q.T @ own), q, st.axes[i])
            gram += gi
            g += ri
        m = np.linalg.solve(gram + 1e-12 * np.trace(gram) * np.eye(6), g)
        evals, evecs = np.linalg.eigh(_sym_matrix(m))
        u_ls = evecs[:, int(np.argmax(evals))]
        u_ls = u_ls if u_ls @ u0 >= 0 else -u_ls
        # (2) refine the direction with the stiffness kept
        e1, e2 = _perpendicular(u0)

        def direction(x, u0=u0, e1=e1, e2=e2):
            u = u0 + x[0] * e1 + x[1] * e2
            return u / np.linalg.norm(u)

        def preds(x, u0=u0, ys=ys, k=k):
            u = direction(x)
            return [p + (np.outer(u, u) - np.outer(u0, u0)) @ y / k for p, y in zip(st.baseline, ys)]

        def fun(x):
            return np.concatenate([st.fit_residual(i, p) for i, p in enumerate(preds(x))])

        x0 = np.array([u_ls @ e1, u_ls @ e2]) / max(float(u_ls @ u0), 0.2)
        x, cost, _, ok = _levenberg_marquardt(fun, x0, step=1e-4, max_iter=30)
        if best is None or cost < best[1]:
            best = (r, cost, direction(x), preds(x), ok)
    r, _, u, pred, ok = best
    u0 = mdl.directions[r]
    angle = math.degrees(math.acos(min(abs(float(u @ u0)), 1.0)))
    dirs = np.array(mdl.directions)
    dirs[r] = u
    ext = ModalModel(mdl.natural_frequency_hz, mdl.damping_ratio, mdl.stiffness_N_m, dirs,
                     residual_compliance_m_N=mdl.residual_compliance_m_N)
    params = {"mode_index": int(r), "mode_frequency_hz": float(mdl.natural_frequency_hz[r]), "rotation_deg": angle,
              "direction": [float(c) for c in u]}
    return Extension("cross_coupling", "structure", params, bool(ok), "Levenberg-Marquardt", pred, ext, None,
                     {"kind": "coupling"})


def fit_above_band_compliance(parts: Parts) -> Extension | None:
    """What the records do tell of the model's modes above their band: the compliance of each in it.

    Not a cause (the records cannot tell such a mode's frequency, damping or direction,
    :func:`~planner.diagnosis.response.resolved_modes`), but an alternative the structure causes
    must beat: the records see a mode above their band only by its response in the band, nearly
    its static compliance, and a structure cause that explains no more of the disagreement than a
    change of that compliance is not told apart from it. Each such mode's response to the measured
    force (:func:`~planner.diagnosis.response.band_limited_mode_response`) is scaled by a factor
    ``a_r >= 0`` fitted by linear least squares on the fit halves (the free responses projected
    out, as in every structure fit); ``a_r = 1`` is the model, ``0`` a mode the records lack.

    Returns
    -------
    Extension or None
        ``parameters``: ``mode_frequency_hz`` and ``compliance_factor`` (lists); ``None`` when the
        model has no mode above the band or the records no displacement.
    """
    st = parts.structure
    if not st.views:
        return None
    mdl = st.model
    above = np.flatnonzero(np.asarray(mdl.natural_frequency_hz, dtype=float) > views_band_hz(st.views))
    if above.size == 0:
        return None
    single = [ModalModel(mdl.natural_frequency_hz[[r]], mdl.damping_ratio[[r]], mdl.stiffness_N_m[[r]],
                         mdl.directions[[r]]) for r in above]
    contributions, design, targets = [], [], []
    for i, v in enumerate(st.views):
        q = st._basis(i, None)
        sl = v.half("fit")
        c_i = [modal_response(m, v.force, v.sample_rate_hz) for m in single]
        contributions.append(c_i)
        cols = [c[st.axes[i], sl].ravel() for c in c_i]
        design.append(np.column_stack([c - q @ (q.T @ c) for c in cols]))
        targets.append(st.fit_residual(i, st.baseline[i]))
    # the change b_r = a_r - 1 of each mode's compliance, a_r >= 0
    res = optimize.lsq_linear(np.vstack(design), np.concatenate(targets), bounds=(-1.0, np.inf))
    change = res.x
    pred = [p + sum(b * c for b, c in zip(change, c_i)) for p, c_i in zip(st.baseline, contributions)]
    params = {"mode_frequency_hz": [float(mdl.natural_frequency_hz[r]) for r in above],
              "compliance_factor": [float(1.0 + b) for b in change]}
    return Extension("above_band_compliance", "structure", params, bool(res.success), str(res.message), pred)


def _drift_segments(n, fs, segment_s=0.05):
    """Segment starts and mid-times (s) of piecewise-constant modal parameters: 50 ms keeps the
    staircase error of a 10 % drift below 1 % of the response (tests)."""
    step = max(int(round(segment_s * fs)), 1)
    starts = np.arange(0, n, step)
    mids = (starts + np.minimum(starts + step, n)) / 2.0 / fs
    return starts, mids


def fit_pose_drift(parts: Parts) -> Extension:
    """Natural frequencies that change along the record, in two forms fitted on the fit half: a
    gradual drift ``s0 (1 + r t / T)`` and a step ``s0 (1 + r [t >= t_s])`` (the arm crossing a
    joint's backlash or a configuration change); the form that fits the fit half better predicts
    the validation half (a ramp extrapolates, a step stays). ``relative_change`` is the change over
    the record of the form chosen. A step inside the validation half leaves nothing to fit."""
    st = parts.structure
    if not st.views:
        return _failed("pose_drift", "structure", "no displacement")

    def segments(v, n, t_step):
        """Segment starts and the scale's time argument: 50 ms segments for a ramp, two for a step."""
        if t_step is None:
            return _drift_segments(n, v.sample_rate_hz)
        k = int(round(t_step * v.sample_rate_hz))
        return (np.array([0, k]), np.array([0.0, t_step])) if 0 < k < n else (np.array([0]), np.array([0.0]))

    def scale(x, mids, duration, t_step):
        if t_step is None:
            return (1.0 + x[0]) * (1.0 + x[1] * mids / duration)
        return (1.0 + x[0]) * (1.0 + x[1] * (mids >= t_step))

    def make_fun(t_step):
        def fun(x):
            out = []
            for i, v in enumerate(st.views):
                n = v.n_samples
                starts, mids = segments(v, n, t_step)
                keep = starts < v.split
                pred = np.full((3, n), np.nan)
                pred[:, :v.split] = modal_response(st.model, v.force[:, :v.split], v.sample_rate_hz,
                                                   frequency_scale=scale(x, mids[keep], n / v.sample_rate_hz,
                                                                         t_step),
                                                   segment_starts=starts[keep])
                out.append(st.fit_residual(i, pred))
            return np.concatenate(out)
        return fun

    bounds = dict(lower=[-0.5, -0.6], upper=[0.5, 0.6])
    grid = np.linspace(-0.3, 0.3, 9)
    fun = make_fun(None)
    costs = np.array([_sumsq(fun([0.0, g])) for g in grid])
    x0 = [0.0, float(grid[int(np.argmin(costs))])]
    x, cost, _, ok = _levenberg_marquardt(fun, x0, step=1e-4, max_iter=20, **bounds)
    t_step = None
    # the step: its time and sign on a grid over the fit half (of the shortest record), then its
    # size by Levenberg-Marquardt, then the time refined
    v0 = min(st.views, key=lambda v: v.split)
    t_fit = v0.split / v0.sample_rate_hz
    trials = [(_sumsq(make_fun(float(ts))([0.0, g])), float(ts), g)
              for ts in np.linspace(0.1, 0.9, 9) * t_fit for g in (-0.12, -0.05, 0.05, 0.12)]
    c_s, ts, g0 = min(trials)
    # the best trial step, sized by Levenberg-Marquardt, against the ramp
    xs, cs, _, oks = _levenberg_marquardt(make_fun(ts), [0.0, g0], step=1e-4, max_iter=12, **bounds)
    if cs < cost:
        x, cost, ok, t_step = xs, cs, oks, ts
        for tr in ts + np.linspace(-0.1, 0.1, 9) * t_fit:
            if not 0 < tr < t_fit:
                continue
            xr, cr, _, okr = _levenberg_marquardt(make_fun(float(tr)), x, step=1e-4, max_iter=4, **bounds)
            if cr < cost:
                x, cost, ok, t_step = xr, cr, okr, float(tr)
        # the chosen step time's size carried on to convergence (the trials stop after 4 iterations;
        # a cause is named only when its fit succeeded)
        x, cost, _, ok = _levenberg_marquardt(make_fun(t_step), x, step=1e-4, max_iter=20, **bounds)
    pred = []
    for v in st.views:
        n = v.n_samples
        starts, mids = segments(v, n, t_step)
        pred.append(modal_response(st.model, v.force, v.sample_rate_hz,
                                   frequency_scale=scale(x, mids, n / v.sample_rate_hz, t_step),
                                   segment_starts=starts))
    # standard errors from the Jacobian at the optimum (forward differences, as the fit's own)
    fun_best = make_fun(t_step)
    f0 = fun_best(x)
    jac = np.column_stack([(fun_best(x + np.eye(2)[j] * 1e-4) - f0) / 1e-4 for j in range(2)])
    s2 = _sumsq(f0) / max(f0.size - 2, 1)
    try:
        change_sigma = float(math.sqrt(max(np.linalg.inv(jac.T @ jac)[1, 1] * s2, 0.0)))
    except np.linalg.LinAlgError:
        change_sigma = float("inf")
    params = {"relative_change": float(x[1]), "relative_change_sigma": change_sigma,
              "initial_frequency_scale": float(1.0 + x[0]),
              "form": "gradual" if t_step is None else "step"}
    if t_step is not None:
        params["step_time_s"] = t_step
    return Extension("pose_drift", "structure", params, bool(ok), "Levenberg-Marquardt", pred, None, None,
                     {"kind": "drift", "grid_relative_change": grid, "grid_cost": costs})


# --------------------------------------------------------------------------------- stability
def fit_process_damping(parts: Parts) -> Extension:
    sp = parts.stability

    def cost(c):
        logs = [sp.predicted_log(i, "fit", process_damping_N_m=c) for i in range(len(sp.views))]
        return sp.evaluate("fit", logs).residual_power

    # (1) the closed-loop force spectrum: the notches process damping digs at the modes
    grid = np.concatenate([[0.0], np.geomspace(1e4, 1e9, 16)])
    costs = np.array([cost(c) for c in grid])
    k = int(np.argmin(costs))
    c_spec = 0.0
    if k > 0:
        lo = math.log(grid[max(k - 1, 1)])
        hi = math.log(grid[min(k + 1, grid.size - 1)])
        res = optimize.minimize_scalar(lambda lc: cost(math.exp(lc)), bounds=(lo, hi), method="bounded",
                                       options={"xatol": 5e-3})
        c_spec = float(math.exp(res.x))
    c = c_spec
    msg = "closed-loop force spectrum" if k > 0 else "no process damping fits the force spectrum better than none"
    evidence = {"kind": "pd_search", "coefficient_N_m": grid, "cost": costs, "spectral_estimate_N_m": c_spec}
    # (2) the force harmonics: the flank force also acts on the forced vibration at the tooth
    # harmonics, and the simulator predicts it exactly; a parabola through the whitened residual
    # sums of simulated cuts refines C where the harmonics carry the effect (a drop of the fit
    # half's chi-square by more than 9, three standard deviations of one parameter). Only tried
    # when the spectrum itself asks for process damping (its residual falls by more than 9
    # variances of a line, 1.5 for the correlation of neighbouring lines).
    noise = float(np.mean(sp.evaluate("fit", parts.base_logs["fit"]).s)) if len(sp.views) else 1.0
    if c_spec > 0 and (costs[0] - cost(c_spec)) > 9.0 * noise * 1.5:
        thetas = _initial_thetas(parts)

        # the coefficients may re-adjust at every trial (linear least squares on the four columns
        # of Ktc, Krc, Kac and the edge scale): the harmonics tell C only by what a change of the
        # coefficients cannot mimic
        coef0 = parts.views[0].coefficients
        units = _units(parts.views[0], coef0)
        basis = coefficient_basis(parts, units)
        cols = []
        n_c = len(coefficient_start(coef0, units))
        for k in range(n_c):
            xk = np.zeros(n_c)
            xk[k] = 1.0
            cols.append(_force_residuals(parts, lambda i, xk=xk: -np.tensordot(expand(xk, coef0, units), basis[i],
                                                                                axes=1), thetas)
                        - _force_residuals(parts, lambda i: 0.0 * basis[i][0], thetas))
        design = np.column_stack(cols)

        def chi2(cc):
            eff = Effects(process_damping=ProcessDamping(cc)) if cc > 0 else Effects()
            preds = [parts.force.simulate(v, eff) for v in parts.views] if cc > 0 else parts.force.baseline
            r = _force_residuals(parts, lambda i: preds[i], thetas)
            beta, *_ = np.linalg.lstsq(design, -r, rcond=None)
            return _sumsq(r + design @ beta), preds

        trial = [0.0, 0.6 * c_spec, c_spec, 1.6 * c_spec]
        vals = [chi2(cc)[0] for cc in trial]
        kb = int(np.argmin(vals))
        if kb == 0:
            c_h, v_h = 0.0, vals[0]
        else:
            # a bounded search in log C between the neighbours of the best trial (the chi-square is
            # not a parabola over this range)
            lo_c = trial[kb - 1] if kb > 1 else 0.3 * c_spec
            hi_c = trial[kb + 1] if kb + 1 < len(trial) else 3.0 * c_spec
            res_h = optimize.minimize_scalar(lambda lc: chi2(math.exp(lc))[0], bounds=(math.log(lo_c), math.log(hi_c)),
                                             method="bounded", options={"xatol": 0.02, "maxiter": 12})
            c_h, v_h = float(math.exp(res_h.x)), float(res_h.fun)
        # the harmonics decide when they tell C apart: their chi-square separates the spectral
        # estimate from their own optimum by more than 9 (then they are the sharper measurement;
        # at low speed the averaged closed loop of the spectrum is off by tens of percent)
        if min(vals[2], vals[0]) - v_h > 9.0 or vals[2] - min(v_h, vals[0]) > 9.0:
            c = c_h if v_h <= vals[0] else 0.0
            msg = "closed-loop force spectrum, decided by the force harmonics"
        evidence.update({"harmonic_trials_N_m": np.array(trial + [c_h]), "harmonic_chi2": np.array(vals + [v_h])})
    pred = [sp.predicted_log(i, "val", process_damping_N_m=c) for i in range(len(sp.views))]
    other = {}
    if c > 0:
        # the simulator's view of the extended model on the held-out force harmonics
        other["force"] = [parts.force.simulate(v, Effects(process_damping=ProcessDamping(c))) for v in parts.views]
    return Extension("process_damping", "stability", {"process_damping_coefficient_N_m": c}, True, msg, pred,
                     None, Effects(process_damping=ProcessDamping(c)) if c > 0 else None, evidence, other)


#: The candidates, in the order of cli.md.
CANDIDATES = {
    "runout": fit_runout,
    "force_sensor_dynamics": fit_force_sensor,
    "channel_delay": fit_delay,
    "process_damping": fit_process_damping,
    "unmodeled_mode": fit_unmodeled_mode,
    "cross_coupling": fit_cross_coupling,
    "pose_drift": fit_pose_drift,
    "nonlinear_cutting": fit_nonlinear,
}


def fit_candidate(cause: str, parts: Parts) -> Extension:
    """Fit one candidate cause on the fit halves of prepared parts."""
    if cause not in CANDIDATES:
        raise ValueError(f"cause must be one of {', '.join(CANDIDATES)}, not {cause!r}")
    return CANDIDATES[cause](parts)
