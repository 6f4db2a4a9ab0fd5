"""Calibration of the joints' stiffness and damping from modal models identified at several poses,
and the trust region of the calibrated model.

Parameters ``theta = ln k_j`` (six joint stiffnesses, N m/rad) plus, optionally, the reach
correction's ``gamma`` (:mod:`planner.robot.correction`). For each identified model (with
``pose.joints_deg``) the predicted tool-tip modes at its pose are paired with the identified ones
(Hungarian assignment on ``(1 - MAC) + |ln(f_p / f_m)|``, redone after each fit), and the weighted
residuals are ``(ln f_p - ln f_m) / s_f``, ``(ln k_p - ln k_m) / s_k`` and ``(u_p - u_m) / s_u`` (the
direction, sign-aligned), with the identification's standard deviations ``s_f, s_k, s_u`` (by
default 1 % in frequency, 5 % in stiffness, 2 deg in direction: what each measurement can tell).
A weak prior (``prior_sd`` in ``ln k``, around the starting stiffness times one common factor
fitted first) keeps joints the poses
cannot see where they were instead of letting them drift. Solved by
:func:`scipy.optimize.least_squares` (Dumas et al., RCIM 27, 2011, identify joint stiffness the
same way from static tests).

Identifiability comes from the sensitivity, not from a guess: with ``J`` the Jacobian of the
weighted residuals with respect to ``theta`` at the solution, the posterior covariance is
``S = s2 (J^T J + I / prior_sd^2)^-1`` (``s2 = max(1, chi^2 / dof)`` inflates it when the residuals
exceed the stated noise, i.e. when the model is wrong), and joint ``j`` is *identifiable* when
``sqrt(S_jj) <= identifiable_sd`` (default 0.05: 5 % one-sigma).

Damping: each joint's damping ratio ``zeta_j`` enters a mode by its strain-energy fraction
(:mod:`planner.robot.dynamics`), so the identified modal damping ratios are linear in ``zeta``:
a non-negative least squares with a weak pull to the mean measured ratio.

Next pose (optimal experiment design, the A-criterion on the prediction: Atkinson, Donev & Tobias,
*Optimum Experimental Designs*, 2007): candidates are drawn around the calibration poses
(convex combinations plus a spread of the poses' own scale, within the limits); the working region
is a second such sample. The candidate that minimises the mean predicted variance of the dominant
mode's ``ln f`` over the working region, ``mean_w g_w^T (F + J_c^T J_c)^-1 g_w``, is proposed.

Trust (:func:`trust`): a pose is *trusted* when (1) the propagated standard deviation of its
dominant mode's frequency is at most ``trust_sd`` (5 %) and (2) joints 2-5 (those that change the
arm's dynamics; joint 1 only turns it about the vertical and joint 6 turns the tool about its axis)
each lie within the range the calibration poses cover, widened by ``trust_margin_deg`` (10 deg).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, linear_sum_assignment, nnls

from oma.errors import InputError
from oma.modal import ModalModel

from .correction import CORRECTION_JOINTS, correction_factor, reach_m
from .description import KR500_JOINT_STIFFNESS_N_M_RAD, Robot
from .dynamics import mass_matrix, robot_modes

__all__ = ["Calibration", "calibrate", "trust", "trust_poses", "Trust", "parse_correction", "TRUST_JOINTS"]

#: Identified modes beyond the predicted tool-tip modes' band widened by this factor are not paired.
_BAND_FACTOR = 3.0
#: Joints (0-based) whose values decide the trust region (2-5 in the 1-based numbering).
TRUST_JOINTS = (1, 2, 3, 4)


@dataclass(frozen=True, eq=False)
class _Data:
    q: np.ndarray  # (m, 6) rad
    masses: np.ndarray  # (m, 6, 6)
    reach: np.ndarray  # (m,)
    models: tuple


def _stiffness(theta, data: _Data, r_ref):
    k = np.exp(theta[:6])
    gamma = theta[6] if theta.size > 6 else 0.0
    return k[None, :] * correction_factor(data.reach, gamma, r_ref)


def _modes(robot, theta, data, r_ref):
    return robot_modes(robot, data.q, stiffness=_stiffness(theta, data, r_ref), masses=data.masses)


def _match(modes, data, *, min_fraction=1e-3):
    """Pairs (measured mode, predicted mode) per model. Identified modes outside the band of the
    predicted tool-tip modes widened by a factor 3 (e.g. a spindle mode hundreds of Hz up) pair
    with nothing."""
    pairs = []
    compliance = modes.compliance_m_N
    for i, model in enumerate(data.models):
        cand = np.flatnonzero(compliance[i] >= min_fraction * compliance[i].max())
        f_c = modes.frequency_hz[i, cand]
        inside = np.flatnonzero((model.natural_frequency_hz >= f_c.min() / _BAND_FACTOR)
                                & (model.natural_frequency_hz <= f_c.max() * _BAND_FACTOR))
        mac = (model.directions[inside] @ modes.directions[i, cand].T) ** 2
        cost = (1 - mac) + np.abs(np.log(f_c[None, :] / model.natural_frequency_hz[inside, None]))
        rows, cols = linear_sum_assignment(cost)
        pairs.append((inside[rows], cand[cols]))
    return pairs


def _residuals(robot, theta, data, pairs, sig, r_ref):
    modes = _modes(robot, theta, data, r_ref)
    out = []
    for i, (rows, cols) in enumerate(pairs):
        m = data.models[i]
        out.append((np.log(modes.frequency_hz[i, cols]) - np.log(m.natural_frequency_hz[rows])) / sig[0])
        out.append((np.log(modes.stiffness_N_m[i, cols]) - np.log(m.stiffness_N_m[rows])) / sig[1])
        u_p = modes.directions[i, cols]
        u_m = m.directions[rows] * np.sign(np.sum(u_p * m.directions[rows], axis=1))[:, None]
        out.append(((u_p - u_m) / sig[2]).ravel())
    return np.concatenate(out)


def _fit(robot, data, theta0, center, prior_sd, sig, r_ref, use_correction):
    """Least squares from ``theta0`` with the prior centred on ``center`` (ln k; gamma at 0)."""
    theta = theta0.copy() if use_correction else theta0[:6].copy()
    prior = np.r_[np.full(6, prior_sd), 1.0][: theta.size]
    center = np.r_[center[:6], 0.0][: theta.size]
    pairs = None
    for _ in range(4):
        pairs = _match(_modes(robot, theta, data, r_ref), data)

        def fun(t):
            return np.r_[_residuals(robot, t, data, pairs, sig, r_ref), (t - center) / prior]

        sol = least_squares(fun, theta, method="trf", x_scale=1.0, diff_step=1e-6)
        converged = np.max(np.abs(sol.x - theta)) < 1e-6
        theta = sol.x
        if converged:
            break
    new_pairs = _match(_modes(robot, theta, data, r_ref), data)
    jac = sol.jac[: sol.fun.size - theta.size]
    res = sol.fun[: sol.fun.size - theta.size]
    return theta, new_pairs, jac, res, float(sol.cost)


def _global_starts(robot, data, start, sig, r_ref, rng, *, n_samples=1500, n_best=4, half_width=math.log(4.0)):
    """Best ``n_best`` of ``n_samples`` random ``ln k`` around ``start`` (+- ``half_width``), scored
    by the relaxed misfit (each identified mode against its nearest predicted mode, no one-to-one
    pairing): a vectorised global stage before the local fits, which from one start can lock on
    to a wrong pairing of close modes."""
    samples = start[:6] + rng.uniform(-half_width, half_width, (n_samples, 6))
    samples[0] = start[:6]
    m = len(data.models)
    q = np.tile(data.q, (n_samples, 1))
    k = np.repeat(np.exp(samples), m, axis=0) * np.tile(correction_factor(data.reach, 0.0, r_ref), (n_samples, 1))
    modes = robot_modes(robot, q, stiffness=k, masses=np.tile(data.masses, (n_samples, 1, 1)))
    f = np.log(modes.frequency_hz).reshape(n_samples, m, 6)
    kk = np.log(np.where(np.isfinite(modes.stiffness_N_m), modes.stiffness_N_m, 1e300)).reshape(n_samples, m, 6)
    u = modes.directions.reshape(n_samples, m, 6, 3)
    cost = np.zeros(n_samples)
    for i, model in enumerate(data.models):
        df = (f[:, i, None, :] - np.log(model.natural_frequency_hz)[None, :, None]) / sig[0]
        dk = (kk[:, i, None, :] - np.log(model.stiffness_N_m)[None, :, None]) / sig[1]
        dot = np.abs(np.einsum("spk,rk->srp", u[:, i], model.directions))
        du2 = 2 * (1 - np.clip(dot, 0, 1)) / sig[2] ** 2
        cost += np.min(df**2 + dk**2 + du2, axis=2).sum(axis=1)
    best = np.argsort(cost)[:n_best]
    return [np.r_[samples[b], 0.0] for b in best]


def _model_errors(robot, theta, data, pairs, r_ref):
    """Relative RMS frequency and stiffness errors per model."""
    modes = _modes(robot, theta, data, r_ref)
    f_err, k_err = [], []
    for i, (rows, cols) in enumerate(pairs):
        m = data.models[i]
        if len(rows) == 0:
            f_err.append(math.inf)
            k_err.append(math.inf)
            continue
        f_err.append(float(np.sqrt(np.mean((modes.frequency_hz[i, cols] / m.natural_frequency_hz[rows] - 1) ** 2))))
        k_err.append(float(np.sqrt(np.mean((modes.stiffness_N_m[i, cols] / m.stiffness_N_m[rows] - 1) ** 2))))
    return np.array(f_err), np.array(k_err)


@dataclass(frozen=True, eq=False)
class Calibration:
    """Result of :func:`calibrate`.

    Attributes
    ----------
    robot : Robot
        The calibrated robot (stiffness, damping, correction, calibration record for :func:`trust`).
    joint_stiffness_N_m_rad : ndarray, shape (6,)
    stiffness_sd : ndarray, shape (6,)
        Posterior standard deviation of ``ln k`` (relative one-sigma uncertainty).
    identifiable : ndarray of bool, shape (6,)
    singular_values : ndarray
        Of the weighted sensitivity ``J`` (``ln k``, then ``gamma`` if used).
    damping_ratio : ndarray, shape (6,)
    correction : dict or None
    fit_error : ndarray, shape (n_models,)
        Relative RMS frequency error of the matched modes per model.
    fit_error_stiffness : ndarray, shape (n_models,)
    leave_one_out : list of dict
        ``{model, frequency_error, stiffness_error}`` of each model predicted without it.
    next_pose_deg : ndarray, shape (6,)
    next_pose_variance_ratio : float
        Mean prediction variance over the working region with the next pose / without it.
    chi2_dof : float
        Weighted residual sum of squares per degree of freedom (about 1 when the model explains
        the data within the stated noise).
    start_scale : float
        The common factor on the starting stiffness fitted first; the prior's centre is the
        starting stiffness times it.
    warnings : tuple of str
    """

    robot: Robot
    joint_stiffness_N_m_rad: np.ndarray
    stiffness_sd: np.ndarray
    identifiable: np.ndarray
    singular_values: np.ndarray
    damping_ratio: np.ndarray
    correction: dict | None
    fit_error: np.ndarray
    fit_error_stiffness: np.ndarray
    leave_one_out: list
    next_pose_deg: np.ndarray
    next_pose_variance_ratio: float
    chi2_dof: float
    start_scale: float = 1.0
    model_names: tuple = ()
    warnings: tuple = field(default_factory=tuple)

    def plot(self, ax=None):
        """Stiffness with its uncertainty and the leave-one-out errors (:func:`.plots.plot_calibration`)."""
        from .plots import plot_calibration

        return plot_calibration(self, ax=ax)

    def to_dict(self) -> dict:
        return {"joint_stiffness_N_m_rad": self.joint_stiffness_N_m_rad.tolist(),
                "stiffness_sd": self.stiffness_sd.tolist(), "identifiable": [bool(x) for x in self.identifiable],
                "singular_values": self.singular_values.tolist(), "damping_ratio": self.damping_ratio.tolist(),
                "correction": self.correction, "fit_error": self.fit_error.tolist(),
                "fit_error_stiffness": self.fit_error_stiffness.tolist(), "leave_one_out": list(self.leave_one_out),
                "next_pose_deg": self.next_pose_deg.tolist(),
                "next_pose_variance_ratio": self.next_pose_variance_ratio, "chi2_dof": self.chi2_dof,
                "warnings": list(self.warnings)}


#: Two calibration models whose joints all agree within this are at one pose (deg).
SAME_POSE_DEG = 0.01


def _check_models(robot: Robot, models, names):
    if len(models) < 1:
        raise InputError(None, "models", "at least one modal model", "none")
    q = []
    for i, (m, name) in enumerate(zip(models, names)):
        if not isinstance(m, ModalModel):
            raise TypeError(f"models[{i}] is not a ModalModel")
        if m.joints_deg is None:
            raise InputError(name, "pose.joints_deg", "the pose the model was identified at (robot calibrate)",
                             "no pose")
        q.append(robot.check_joints(np.radians(m.joints_deg), file=name, field="pose.joints_deg"))
    q = np.array(q)
    # a model repeated at its pose would count as a new pose: a joint "identifiable" from one pose
    # twice, a leave-one-out error measured on the model's own copy (the session-14 audit)
    for i in range(1, len(q)):
        gap = np.degrees(np.max(np.abs(q[:i] - q[i]), axis=1))
        j = int(np.argmin(gap))
        if gap[j] < SAME_POSE_DEG:
            raise InputError(names[i], "pose.joints_deg", f"a pose apart from {names[j]}'s (by more than "
                             f"{SAME_POSE_DEG:g} deg in some joint)", f"the same pose (within {gap[j]:.3g} deg): "
                             "identify their records together, or leave one out")
    return q


def _data(robot, models, q):
    return _Data(q=q, masses=mass_matrix(robot, q), reach=reach_m(robot, q), models=tuple(models))


def _sample_region(robot, q, n, rng):
    """Poses around the calibration poses: convex combinations plus a spread of their own scale
    (at least 10 deg), within the limits."""
    w = rng.dirichlet(np.ones(len(q)), size=n)
    spread = np.maximum(q.std(axis=0), math.radians(10.0))
    out = w @ q + rng.normal(size=(n, 6)) * spread * 0.5
    return np.clip(out, robot.lower_rad + 1e-3, robot.upper_rad - 1e-3)


def _central_difference(fn, theta, step):
    """``d fn / d theta_j`` for every ``j`` by central differences, stacked on a last axis."""
    cols = []
    for j in range(theta.size):
        plus, minus = theta.copy(), theta.copy()
        plus[j] += step
        minus[j] -= step
        cols.append((fn(plus) - fn(minus)) / (2 * step))
    return np.stack(cols, axis=-1)


def _log_f_dominant_gradient(robot, theta, q, r_ref, step=1e-5):
    """``d ln f_dominant / d theta`` at poses ``q`` (n, p) by central differences."""
    data = _Data(q=q, masses=mass_matrix(robot, q), reach=reach_m(robot, q), models=())
    dom = _modes(robot, theta, data, r_ref).dominant()

    def log_f(t):
        return np.log(np.take_along_axis(_modes(robot, t, data, r_ref).frequency_hz, dom[:, None], 1)[:, 0])

    return _central_difference(log_f, theta, step), data


def _feature_jacobian(robot, theta, data, sig, r_ref, n_modes=3, step=1e-5):
    """Weighted Jacobian of the ``n_modes`` most compliant modes' ln f and ln k at each pose:
    shape (n, 2 n_modes, p)."""
    base = _modes(robot, theta, data, r_ref)
    order = np.argsort(-base.compliance_m_N, axis=1)[:, :n_modes]

    def features(t):
        m = _modes(robot, t, data, r_ref)
        return np.concatenate([np.log(np.take_along_axis(m.frequency_hz, order, 1)) / sig[0],
                               np.log(np.take_along_axis(m.stiffness_N_m, order, 1)) / sig[1]], axis=1)

    return _central_difference(features, theta, step)


def calibrate(robot: Robot, models: Sequence[ModalModel], *, names: Sequence[str] | None = None,
              correction: bool | str = "auto", sigma_frequency: float = 0.01, sigma_stiffness: float = 0.05,
              sigma_direction_deg: float = 2.0, prior_sd: float = 1.0, identifiable_sd: float = 0.05,
              n_candidates: int = 200, n_starts: int = 4, seed: int = 0) -> Calibration:
    """Fit the joint stiffness and damping of ``robot`` to modal models identified at several poses.

    Parameters
    ----------
    robot : Robot
        Its stiffness (or DOMAIN.md's KR 500 values when it has none) is the starting point and
        the prior's centre.
    models : sequence of ModalModel
        Each with ``joints_deg`` (URDF joint values, deg).
    names : sequence of str, optional
        Names of the models (their files) for messages and the report.
    correction : bool or "auto"
        Fit the reach correction (:mod:`.correction`) too; ``"auto"`` (default) keeps it when it
        lowers the leave-one-out frequency error (needs at least 3 models).
    sigma_frequency, sigma_stiffness : float
        Relative standard deviations of identified frequencies and stiffnesses.
    sigma_direction_deg : float
        Standard deviation of identified mode directions, deg.
    prior_sd : float
        Prior standard deviation of ``ln k`` around the starting stiffness.
    identifiable_sd : float
        Largest posterior standard deviation of ``ln k`` for a joint to count as identifiable.
    n_candidates : int
        Candidate poses (and working-region poses) for the next-pose proposal.
    n_starts : int
        Extra starting points of the local fit: the best of a random global sample of ``ln k``
        within a factor 4 of the start (close modes can pair wrongly from one start).
    seed : int
        Of the candidate sample.

    Returns
    -------
    Calibration

    Raises
    ------
    InputError
        A model without ``pose.joints_deg``, or a pose outside the joint limits.
    """
    models = list(models)
    names = [f"models[{i}]" for i in range(len(models))] if names is None else [str(n) for n in names]
    q = _check_models(robot, models, names)
    sig = (sigma_frequency, sigma_stiffness, math.radians(sigma_direction_deg))
    k0 = robot.joint_stiffness_N_m_rad if robot.has_stiffness else np.array(KR500_JOINT_STIFFNESS_N_M_RAD)
    theta0 = np.r_[np.log(k0), 0.0]
    data = _data(robot, models, q)
    r_ref = float(np.mean(data.reach))
    warnings = []
    # a common scale first (the prior's centre may be far off): 1-D search on ln(scale)
    scales = np.linspace(-3, 3, 61)
    costs = [np.sum(_residuals(robot, theta0 + np.r_[np.full(6, s), 0.0], data,
                               _match(_modes(robot, theta0 + np.r_[np.full(6, s), 0.0], data, r_ref), data), sig,
                               r_ref) ** 2) for s in scales]
    start_scale = float(np.exp(scales[int(np.argmin(costs))]))
    start = theta0 + np.r_[np.full(6, np.log(start_scale)), 0.0]
    rng_starts = np.random.default_rng(seed)

    def loo(use_corr, theta_full):
        out = []
        for i in range(len(models)):
            keep = [j for j in range(len(models)) if j != i]
            sub = _Data(q=q[keep], masses=data.masses[keep], reach=data.reach[keep],
                        models=tuple(models[j] for j in keep))
            th = _fit(robot, sub, theta_full, start, prior_sd, sig, r_ref, use_corr)[0]
            one = _Data(q=q[[i]], masses=data.masses[[i]], reach=data.reach[[i]], models=(models[i],))
            pairs = _match(_modes(robot, th, one, r_ref), one)
            f_err, k_err = _model_errors(robot, th, one, pairs, r_ref)
            out.append({"model": names[i], "frequency_error": float(f_err[0]), "stiffness_error": float(k_err[0])})
        return out

    fits = {}
    options = [False, True] if correction == "auto" else [bool(correction)]
    if len(models) < 3 and True in options:
        options = [False]
        if correction is True:
            warnings.append("the reach correction needs at least 3 models; fitted without it")
    # multi-start: close modes can pair wrongly from one start (local minima); the best few of a
    # vectorised global sample, plus the common-scale guess, are refined
    inits = [start] + _global_starts(robot, data, start, sig, r_ref, rng_starts, n_best=n_starts)
    best = min((_fit(robot, data, init, start, prior_sd, sig, r_ref, False) for init in inits), key=lambda f: f[4])
    for use in options:
        theta, pairs, jac, res, _ = best if not use else _fit(robot, data, np.r_[best[0][:6], 0.0], start,
                                                                 prior_sd, sig, r_ref, True)
        fits[use] = (theta, pairs, jac, res, loo(use, np.r_[theta, 0.0][:7]) if len(models) > 1 else [])
    use = options[0]
    if len(options) == 2:
        err = {u: np.median([r["frequency_error"] for r in fits[u][4]]) for u in options}
        use = bool(err[True] < err[False])
    theta, pairs, jac, res, loo_list = fits[use]
    p = theta.size
    dof = max(res.size - p, 1)
    chi2 = float(res @ res / dof)
    prior = np.r_[np.full(6, prior_sd), 1.0][:p]
    fisher = jac.T @ jac
    cov = np.linalg.inv(fisher + np.diag(1 / prior**2)) * max(1.0, chi2)
    sd = np.sqrt(np.diag(cov))[:6]
    identifiable = sd <= identifiable_sd
    sv = np.linalg.svd(jac, compute_uv=False)
    if chi2 > 4:
        warnings.append(f"residuals are {math.sqrt(chi2):.1f} times the stated identification noise: the model "
                        "misses something (uncertainties inflated accordingly)")
    for j in np.flatnonzero(~identifiable):
        warnings.append(f"joint {j + 1}: stiffness not identifiable from these poses (sd {100 * sd[j]:.0f} %); "
                        "kept near its prior")
    k = np.exp(theta[:6])
    modes = _modes(robot, theta, data, r_ref)
    zeta = _fit_damping(modes, data, pairs, np.broadcast_to(k, (len(models), 6)) *
                        correction_factor(data.reach, theta[6] if p > 6 else 0.0, r_ref))
    corr = ({"kind": "reach", "gamma": float(theta[6]), "reference_reach_m": r_ref, "joints": list(CORRECTION_JOINTS)}
            if use else None)
    f_err, k_err = _model_errors(robot, theta, data, pairs, r_ref)
    unpaired = sum(m.n_modes - len(rows) for m, (rows, _) in zip(models, pairs))
    if unpaired:
        warnings.append(f"{unpaired} identified mode(s) outside the robot modes' band (widened by a factor "
                        f"{_BAND_FACTOR:g}) or beyond their number (e.g. spindle/tool modes): left out of the calibration")
    # next pose
    rng = np.random.default_rng(seed)
    cand = _sample_region(robot, q, n_candidates, rng)
    work = _sample_region(robot, q, n_candidates, rng)
    g, _ = _log_f_dominant_gradient(robot, theta, work, r_ref)
    jc = _feature_jacobian(robot, theta, _Data(q=cand, masses=mass_matrix(robot, cand), reach=reach_m(robot, cand),
                                               models=()), sig, r_ref)
    base_info = fisher + np.diag(1 / prior**2)
    current = float(np.mean(np.einsum("wi,ij,wj->w", g, np.linalg.inv(base_info), g)))
    info = base_info[None] + np.einsum("cfi,cfj->cij", jc, jc)
    covs = np.linalg.inv(info)
    score = np.einsum("wi,cij,wj->cw", g, covs, g).mean(axis=1)
    best = int(np.argmin(score))
    record = {"models": list(names), "fit_error": float(np.sqrt(np.mean(f_err**2))),
              "poses_deg": np.degrees(q).tolist(), "parameters": theta.tolist(),
              "covariance": cov.tolist(), "reference_reach_m": r_ref}
    calibrated = robot.with_joints(joint_stiffness_N_m_rad=k, damping_ratio=zeta, damping_N_m_s_rad=None,
                                   correction=corr, calibration=record)
    return Calibration(robot=calibrated, joint_stiffness_N_m_rad=k, stiffness_sd=sd, identifiable=identifiable,
                       singular_values=sv, damping_ratio=zeta, correction=corr, fit_error=f_err,
                       fit_error_stiffness=k_err, leave_one_out=loo_list, next_pose_deg=np.degrees(cand[best]),
                       next_pose_variance_ratio=float(score[best] / current), chi2_dof=chi2,
                       start_scale=start_scale, model_names=tuple(names), warnings=tuple(warnings))


def _fit_damping(modes, data, pairs, k):
    """Joint damping ratios from the identified modal ratios (strain-energy fractions, NNLS)."""
    rows, rhs = [], []
    for i, (r_idx, c_idx) in enumerate(pairs):
        w2 = (2 * np.pi * modes.frequency_hz[i, c_idx]) ** 2
        frac = k[i][None, :] * modes.shapes[i][:, c_idx].T ** 2 / w2[:, None]  # (n_pairs, 6)
        zeta_m = data.models[i].damping_ratio[r_idx]
        rows.append(frac / (0.1 * zeta_m[:, None]))  # 10 % relative uncertainty of identified damping
        rhs.append(1.0 / 0.1 * np.ones_like(zeta_m))
    a = np.vstack(rows)
    b = np.concatenate(rhs)
    mean = float(np.mean(np.concatenate([m.damping_ratio for m in data.models])))
    lam = 1.0 / mean  # weak pull to the mean (1 sigma = the mean itself)
    a = np.vstack([a, lam * 0.3 * np.eye(6)])
    b = np.r_[b, lam * 0.3 * np.full(6, mean)]
    zeta, _ = nnls(a, b)
    return np.clip(zeta, 1e-4, 0.5)


# ------------------------------------------------------------------------------------ trust
@dataclass(frozen=True, eq=False)
class Trust:
    """Whether a prediction at pose ``q`` is covered by the calibration.

    Attributes
    ----------
    trusted : bool
    frequency_sd : float
        Propagated relative standard deviation of the dominant mode's frequency.
    outside_joints : tuple of int
        1-based joints (of 2-5) outside the calibration poses' range widened by the margin.
    warnings : tuple of str
    """

    trusted: bool
    frequency_sd: float
    outside_joints: tuple
    warnings: tuple

    def to_dict(self) -> dict:
        return {"trusted": self.trusted, "frequency_sd": self.frequency_sd, "outside_joints": list(self.outside_joints),
                "warnings": list(self.warnings)}


def _wrap(angle_rad):
    """Angles in [-pi, pi)."""
    return np.mod(np.asarray(angle_rad, float) + np.pi, 2.0 * np.pi) - np.pi


def trust_poses(robot: Robot, q, *, trust_sd: float = 0.05, trust_margin_deg: float = 10.0):
    """The trust rule (module docstring) at many poses ``q`` (rad, (n, 6)), vectorised.

    Returns
    -------
    trusted : ndarray of bool, shape (n,)
    frequency_sd : ndarray, shape (n,)
        Propagated relative one-sigma of the dominant mode's frequency (inf without a calibration
        record).
    outside : ndarray of bool, shape (n, 6)
        Joints (of 2-5) outside the calibration poses' range widened by ``trust_margin_deg``.
    """
    q = np.atleast_2d(np.asarray(q, float))
    n = q.shape[0]
    cal = robot.calibration or {}
    if "poses_deg" not in cal or "covariance" not in cal:
        return np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 6), bool)
    poses = np.radians(np.asarray(cal["poses_deg"], float))
    margin = math.radians(trust_margin_deg)
    # the range of each joint is an arc: angles 2 pi apart are the same pose for the dynamics, so
    # the poses and the query are measured from the poses' circular mean (a wrist at +180 deg and
    # one at -180 deg are the same joint angle)
    centre = np.angle(np.mean(np.exp(1j * poses), axis=0))
    spread = _wrap(poses - centre)
    lo, hi = spread.min(axis=0) - margin, spread.max(axis=0) + margin
    offset = _wrap(q - centre)
    outside = np.zeros((n, 6), bool)
    idx = list(TRUST_JOINTS)
    outside[:, idx] = (offset[:, idx] < lo[idx]) | (offset[:, idx] > hi[idx])
    theta = np.asarray(cal["parameters"], float)
    cov = np.asarray(cal["covariance"], float)
    r_ref = float(cal.get("reference_reach_m", 1.0))
    g, _ = _log_f_dominant_gradient(robot, theta, q, r_ref)
    sd = np.sqrt(np.einsum("ni,ij,nj->n", g, cov, g))
    return ~outside.any(axis=1) & (sd <= trust_sd), sd, outside


def trust(robot: Robot, q, *, trust_sd: float = 0.05, trust_margin_deg: float = 10.0) -> Trust:
    """Decide whether the calibrated model's prediction at ``q`` (rad, (6,)) is trusted (see the
    module docstring), with the reasons as warnings."""
    if "covariance" not in (robot.calibration or {}):
        return Trust(False, math.inf, (), ("the robot was not calibrated by robomill (no calibration record): "
                                           "the model's accuracy is unknown",))
    trusted, sd, outside = trust_poses(robot, np.asarray(q, float).reshape(1, 6), trust_sd=trust_sd,
                                       trust_margin_deg=trust_margin_deg)
    joints = tuple(int(j) + 1 for j in np.flatnonzero(outside[0]))
    warnings = []
    if joints:
        warnings.append("pose outside the calibrated region: joint(s) " + ", ".join(map(str, joints)) +
                        f" beyond the calibration poses' range +- {trust_margin_deg:g} deg")
    if sd[0] > trust_sd:
        warnings.append(f"the dominant mode's frequency is uncertain here ({100 * sd[0]:.1f} % one-sigma, more than "
                        f"{100 * trust_sd:g} %)")
    return Trust(bool(trusted[0]), float(sd[0]), joints, tuple(warnings))


def parse_correction(mapping: dict, root) -> dict:
    """Check an ``x_correction`` mapping of a robot file (see :mod:`.correction`)."""
    node = root.child(mapping, root.where("x_correction"))
    kind = node.choice("kind", ["reach"])
    gamma = node.number("gamma")
    ref = node.positive("reference_reach_m")
    joints = node.sequence("joints", required=False) or list(CORRECTION_JOINTS)
    if not all(isinstance(j, int) and 1 <= j <= 6 for j in joints):
        node.fail("joints", "joint numbers 1..6", str(joints))
    node.done()
    return {"kind": kind, "gamma": gamma, "reference_reach_m": ref, "joints": list(joints)}

