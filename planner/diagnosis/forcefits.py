"""Force-side candidate causes (runout, force-sensor dynamics, size effect), fitted on the force
harmonics of the fit halves on top of the re-fitted cutting coefficients (see
:mod:`~planner.diagnosis.causes` for the table of all candidates)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy import optimize

from oma.cutting import CuttingCoefficients
from stability.simulate import Effects, ForceSensorDynamics, NonlinearCutting

from .coefficients import _units, coefficient_basis, coefficient_bounds, coefficient_start, expand, standard_errors
from .compare import Parts
from .extension import Extension, _failed
from .forcemodel import ToothRadiiRunout, sensor_gain
from .parts import align_angle, rotate

__all__ = ["fit_runout", "fit_force_sensor", "fit_nonlinear"]


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


#: Evaluations the best start of a force fit may take beyond its first 80 to converge.
MAX_POLISH_EVALUATIONS = 400


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
    if not best.success and best.status == 0:
        # the best start stopped at its evaluation budget (a weakly determined parameter, e.g. a
        # sensor resonance above the compared harmonics): carried on to convergence, since a cause
        # is named only when its fit succeeded
        more = optimize.least_squares(fun, best.x, bounds=(lo, hi), x_scale="jac", max_nfev=MAX_POLISH_EVALUATIONS)
        if more.cost <= best.cost:
            best = more
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
    fr, zeta = math.exp(x[0]), math.exp(x[1])
    effects = Effects(force_sensor=ForceSensorDynamics(fr, zeta))
    # the sensor filters only what is measured: the simulated cut is the baseline's, and its
    # measured harmonics are multiplied by the sensor's response (exact for a linear sensor; the
    # simulator applies the same filter in the time domain)
    pred = [predict_joint(x, i) for i in range(len(views))]
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
