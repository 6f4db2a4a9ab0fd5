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
                                     linear (variable projection), then its dominant eigenpair.
cross_coupling            structure  one mode's direction turned (two angles), its stiffness kept;
                                     the mode that gains most.
pose_drift                structure  every natural frequency scaled by ``s0 (1 + r t / T)`` along
                                     the record (mass and damping ratio kept), or by a step ``s0 (1
                                     + r [t >= t_s])``; ``r`` is the relative change over the record.
                                     The form that fits the first half better predicts the second.
process_damping           stability  ``C`` of Budak & Tunc's flank force in the closed-loop force
                                     spectrum (:mod:`~planner.diagnosis.closedloop`), refined on
                                     the force harmonics (simulated, the coefficients re-adjusted
                                     at each trial) where the forced vibration carries it.
========================  =========  ==============================================================

Every candidate is fitted on top of the re-fitted cutting coefficients
(:mod:`~planner.diagnosis.coefficients`), the baseline it must beat. Force candidates are validated with the time-domain simulator
(:func:`~planner.diagnosis.forcemodel.simulated_harmonics` with the fitted
:class:`stability.simulate.Effects`); structure candidates by the extended model's response to the
measured force; process damping by the closed-loop spectrum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import optimize

from oma.cutting import CuttingCoefficients
from oma.modal import ModalModel
from stability.simulate import Effects, ForceSensorDynamics, NonlinearCutting, ProcessDamping

from .compare import Parts, align_angle, rotate
from .coefficients import _units, coefficient_basis, coefficient_bounds, coefficient_start, expand, standard_errors
from .forcemodel import ToothRadiiRunout, sensor_gain
from .response import Delayer, modal_response, unit_mode_response

__all__ = ["Extension", "CANDIDATES", "fit_candidate"]


@dataclass(frozen=True)
class Extension:
    """A fitted candidate cause.

    Attributes
    ----------
    cause : str
    part : str
        ``force``, ``structure`` or ``stability``.
    parameters : dict
        Fitted parameters, physical units in the key names.
    success : bool
    message : str
    prediction : list
        The part's prediction on the validation halves (per view), as the part's ``evaluate``
        takes it.
    other_predictions : dict
        Predictions of other parts the extension changes (``{"force": [...]}`` for process
        damping, whose flank force also acts on the forced vibration at the tooth harmonics).
    model : ModalModel or None
        The extended structure model (structure candidates with a single model).
    effects : Effects or None
        The fitted effect as a simulator extension (force candidates).
    evidence : dict
        Named arrays for the plots.
    """

    cause: str
    part: str
    parameters: dict
    success: bool
    message: str
    prediction: list = field(repr=False, default_factory=list)
    model: ModalModel | None = field(repr=False, default=None)
    effects: Effects | None = field(repr=False, default=None)
    evidence: dict = field(repr=False, default_factory=dict)
    other_predictions: dict = field(repr=False, default_factory=dict)


def _failed(cause, part, message) -> Extension:
    return Extension(cause, part, {}, False, message)


def _sumsq(x) -> float:
    """Sum of squares without BLAS ``ddot`` (multithreaded above ~10^4 elements, which costs
    milliseconds per call on a loaded machine)."""
    return float(np.einsum("i,i->", x, x))


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


# ------------------------------------------------------------------------------------- force
def _force_residuals(parts: Parts, predict, thetas):
    """Whitened residuals of the fit halves for per-view predictions and angles."""
    out = []
    for i, th in enumerate(thetas):
        y = parts.force.measured["fit"][i]
        s = parts.force.noise["fit"][i]
        r = (y - rotate(predict(i), th)) / np.sqrt(np.maximum(s, 1e-30))
        out += [r.real.ravel(), r.imag[:, 1:].ravel()]
    return np.concatenate(out)


def _initial_thetas(parts: Parts):
    return [align_angle(parts.force.measured["fit"][i], parts.force.baseline[i],
                        1.0 / np.maximum(parts.force.noise["fit"][i], 1e-30)) for i in range(len(parts.views))]


def _fit_force(parts: Parts, predict_from, x0, lower, upper, *, starts=None):
    """Least squares over the cause's parameters and one angle per view; returns (x, cost)."""
    n_views = len(parts.views)
    th0 = _initial_thetas(parts)

    def fun(z):
        x, th = z[:-n_views], z[-n_views:]
        return _force_residuals(parts, lambda i: predict_from(x, i), th)

    best = None
    for start in (starts if starts is not None else [x0]):
        z0 = np.concatenate([np.asarray(start, dtype=float), th0])
        lo = np.concatenate([lower, np.full(n_views, -np.inf)])
        hi = np.concatenate([upper, np.full(n_views, np.inf)])
        res = optimize.least_squares(fun, np.clip(z0, lo + 1e-12, hi - 1e-12), bounds=(lo, hi), x_scale="jac",
                                     max_nfev=80)
        if best is None or res.cost < best.cost:
            best = res
    return best.x[:-n_views], best


def _harmonic_evidence(parts: Parts, prediction) -> dict:
    v = parts.views[0]
    y = parts.force.measured["val"][0]
    s = parts.force.noise["val"][0]
    base = parts.force.baseline[0]
    th_b = align_angle(y, base, 1.0 / np.maximum(s, 1e-30))
    th_a = align_angle(y, prediction[0], 1.0 / np.maximum(s, 1e-30))
    return {
        "kind": "harmonics",
        "freq_hz": np.arange(y.shape[1]) * v.spindle_hz,
        "measured": np.abs(y),
        "before": np.abs(rotate(base, th_b)),
        "after": np.abs(rotate(prediction[0], th_a)),
        "noise": np.sqrt(s),
    }


def fit_runout(parts: Parts) -> Extension:
    """Runout in a form-free way: a radius offset per tooth (their mean is no runout), fitted to
    the force harmonics. An eccentric tool axis is the special case ``rho_j = A cos(phase - 2 pi
    j / N)``; unequal tooth radii are any other pattern. With two teeth only ``rho_0 - rho_1``
    acts; the amplitude reported is half the spread of the radii, ``(max rho - min rho) / 2``
    (the eccentric axis's ``A |cos(phase)|`` for two teeth)."""
    teeth = int(parts.views[0].tool.teeth)
    if teeth < 2:
        return _failed("runout", "force", "a single tooth has no runout signature")
    scale = 1e-5  # parameters in units of 10 um
    n_par = teeth - 1

    def radii(x):
        rho = np.zeros(teeth)
        rho[1:] = -np.asarray(x) * scale  # tooth 0 is the reference; teeth 1.. sit x lower
        return rho - rho.mean()

    def predict(x, i):
        rho = radii(x)
        return parts.force.analytic(i, chip_increments_m=rho - np.roll(rho, -1))

    starts = [np.full(n_par, 0.5), np.full(n_par, -0.5)]
    x, res = _fit_force(parts, predict, starts[0], np.full(n_par, -20.0), np.full(n_par, 20.0), starts=starts)
    rho = radii(x)
    amp = float(np.max(rho) - np.min(rho)) / 2.0
    try:
        sig = standard_errors(res, n_par) * scale
        # half the spread moves by half an offset's standard error (exact for two teeth)
        amp_sigma = float(np.max(sig)) / 2.0
    except np.linalg.LinAlgError:  # pragma: no cover
        amp_sigma = float("inf")
    effects = Effects(runout=ToothRadiiRunout(0.0, 0.0, tuple(float(r) for r in rho)))
    pred = [parts.force.simulate(v, effects) for v in parts.views]
    params = {"runout_amplitude_m": amp, "runout_amplitude_m_sigma": amp_sigma,
              "tooth_radius_offsets_m": [float(r) for r in rho]}
    return Extension("runout", "force", params, bool(res.success), str(res.message), pred, None, effects,
                     _harmonic_evidence(parts, pred))


def fit_force_sensor(parts: Parts) -> Extension:
    base = parts.force.baseline
    views = parts.views
    f_top = max(v.n_harm * v.spindle_hz for v in views)
    f_lo = min(v.spindle_hz for v in views)

    def predict(x, i):
        v = views[i]
        fh = np.arange(v.n_harm + 1) * v.spindle_hz
        return base[i] * sensor_gain(fh, math.exp(x[0]), math.exp(x[1]))[None, :]

    lower = np.array([math.log(f_lo), math.log(0.002)])
    upper = np.array([math.log(20.0 * f_top), math.log(0.7)])
    # coarse search over the resonance frequency and damping (the spindle angle re-aligned at every
    # trial: a resonance among the harmonics turns their phases), then least squares from the best
    grid = [(f, z) for f in np.geomspace(1.5 * f_lo, 10.0 * f_top, 40) for z in (0.03, 0.1)]

    def grid_cost(fz):
        x = [math.log(fz[0]), math.log(fz[1])]
        cost = 0.0
        for i in range(len(views)):
            y, s = parts.force.measured["fit"][i], parts.force.noise["fit"][i]
            p = predict(x, i)
            wts = 1.0 / np.maximum(s, 1e-30)
            cost += float(np.sum(wts * np.abs(y - rotate(p, align_angle(y, p, wts))) ** 2))
        return cost

    costs = np.array([grid_cost(g) for g in grid])
    order = np.argsort(costs)[:3]
    # then the resonance together with the coefficients (Ktc, Krc, Kac, an edge scale): the
    # baseline's re-fit took part of the sensor's rise across the harmonics as a change of the
    # coefficients, which the resonance must be free to give back
    coef0 = views[0].coefficients
    units = _units(views[0], coef0)
    basis = coefficient_basis(parts, units)
    c0 = coefficient_start(coef0, units)
    c_lo, c_hi = coefficient_bounds(c0)

    def predict_joint(x, i):
        v = views[i]
        fh = np.arange(v.n_harm + 1) * v.spindle_hz
        harm = np.tensordot(expand(x[2:], coef0, units), basis[i], axes=1) + parts.force.correction[i]
        return harm * sensor_gain(fh, math.exp(x[0]), math.exp(x[1]))[None, :]

    starts = [np.concatenate([[math.log(grid[j][0]), math.log(grid[j][1])], c0]) for j in order]
    x, res = _fit_force(parts, predict_joint, starts[0], np.concatenate([lower, c_lo]),
                        np.concatenate([upper, c_hi]), starts=starts)
    predict = predict_joint
    fr, zeta = math.exp(x[0]), math.exp(x[1])
    effects = Effects(force_sensor=ForceSensorDynamics(fr, zeta))
    # the sensor filters only what is measured: the simulated cut is the baseline's, and its
    # measured harmonics are multiplied by the sensor's response (exact for a linear sensor; the
    # simulator applies the same filter in the time domain)
    pred = [predict(x, i) for i in range(len(views))]
    params = {"sensor_frequency_hz": fr, "sensor_damping_ratio": zeta}
    ev = _harmonic_evidence(parts, pred)
    fgrid = np.linspace(0.0, views[0].sample_rate_hz / 2, 400)
    ev.update({"sensor_freq_hz": fgrid, "sensor_gain": np.abs(sensor_gain(fgrid, fr, zeta))})
    return Extension("force_sensor_dynamics", "force", params, bool(res.success), str(res.message), pred, None,
                     effects, ev)


def fit_nonlinear(parts: Parts) -> Extension:
    """Size effect ``K ~ (h / h_ref)^-p`` fitted together with the cutting coefficients (Ktc, Krc,
    Kac, an edge scale; :mod:`~planner.diagnosis.coefficients`), so that ``p`` measures the shape
    of the force pulse the linear-plus-edge model cannot take, whatever the law's exact form (a
    saturating law comes out as its mean log-slope over the chips of the cut)."""
    h0 = float(parts.views[0].cut.feed_per_tooth_m)
    base = parts.views[0].coefficients
    units = _units(parts.views[0], base)
    c0 = coefficient_start(base, units)
    c_lo, c_hi = coefficient_bounds(c0)

    def coef(xc):
        return CuttingCoefficients(*[float(v) for v in expand(xc, base, units) * units])

    # the coefficients hold at h0 (the first record's feed): with them free, where they hold is
    # no second unknown (K (h / h_ref)^-p = K h_ref^p h^-p); with records at several feeds the
    # exponent is pinned by how the force scales between them as well as by the pulse's shape
    def predict(x, i):
        return parts.force.analytic(i, coefficients=coef(x[1:]), exponent_p=float(x[0]), reference_chip_m=h0)

    x0, lo, hi = np.concatenate([[0.2], c0]), np.concatenate([[-0.5], c_lo]), np.concatenate([[0.9], c_hi])
    starts = [x0, np.concatenate([[0.0], x0[1:]])]
    x, res = _fit_force(parts, predict, x0, lo, hi, starts=starts)
    p, href = float(x[0]), h0
    cf = coef(x[1:])
    try:
        p_sigma = float(standard_errors(res, 1)[0])
    except np.linalg.LinAlgError:  # pragma: no cover
        p_sigma = float("inf")
    effects = Effects(nonlinear_cutting=NonlinearCutting(p, href))
    pred = [parts.force.simulate(replace(v, coefficients=cf), effects) for v in parts.views]
    params = {"exponent_p": p, "exponent_p_sigma": p_sigma, "reference_chip_m": href,
              "coefficients": {f: float(getattr(cf, f)) for f in ("Ktc_N_m2", "Krc_N_m2", "Kac_N_m2",
                                                                  "Kte_N_m", "Kre_N_m", "Kae_N_m")}}
    return Extension("nonlinear_cutting", "force", params, bool(res.success), str(res.message), pred, None,
                     effects, _harmonic_evidence(parts, pred))


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
    return Extension("channel_delay", "structure", {"delay_s": tau}, bool(res.success), "bounded 1-D search",
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

    def solve(fn, zeta):
        gram = np.zeros((6, 6))
        g = np.zeros(6)
        bb = 0.0
        for i, v in enumerate(st.views):
            y = unit_mode_response(fn, zeta, v.force[:, :v.split], v.sample_rate_hz)
            gi, ri = _sym_normal_equations(y, targets[i], st._basis(i, None), st.axes[i])
            gram += gi
            g += ri
            bb += float(np.sum(targets[i] ** 2))
        m = np.linalg.solve(gram + 1e-12 * np.trace(gram) * np.eye(6), g)
        return bb - float(g @ m), m

    fs = st.views[0].sample_rate_hz
    # (1) a grid over the frequency (damping 3 %), then over the damping; (2) Nelder-Mead
    grid = np.geomspace(1.0, 0.4 * fs, 64)
    costs = np.array([solve(f, 0.03)[0] for f in grid])
    k = int(np.argmin(costs))
    zetas = np.geomspace(0.005, 0.3, 9)
    zc = np.array([solve(grid[k], z)[0] for z in zetas])

    def obj(x):
        return solve(math.exp(x[0]), math.exp(x[1]))[0]

    x0 = [math.log(grid[k]), math.log(zetas[int(np.argmin(zc))])]
    best = optimize.minimize(obj, x0, method="Nelder-Mead",
                             bounds=[(math.log(0.5), math.log(0.45 * fs)), (math.log(1e-3), math.log(0.9))],
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
    targets = [st.fit_residual(i, p) for i, p in enumerate(st.baseline)]
    best = None
    for r in range(mdl.n_modes):
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
        x, cost, _, ok = _levenberg_marquardt(fun, x0, step=1e-4, max_iter=12)
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
    pred = []
    for v in st.views:
        n = v.n_samples
        starts, mids = segments(v, n, t_step)
        pred.append(modal_response(st.model, v.force, v.sample_rate_hz,
                                   frequency_scale=scale(x, mids, n / v.sample_rate_hz, t_step),
                                   segment_starts=starts))
    params = {"relative_change": float(x[1]), "initial_frequency_scale": float(1.0 + x[0]),
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
