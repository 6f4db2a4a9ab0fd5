"""Scale output-only modes with the milling force's tooth-passing harmonics (OMAH).

Operational modal analysis with harmonics (Brandt, Berardengo, Manzoni & Cigada, J. Sound Vib.
407, 2017): a harmonic force of known amplitude, here the tooth-passing lines of the cutting
force, produces a response line ``X(f_h) = G(f_h) F(f_h)``; with frequencies, damping and
directions known from the output-only identification, ``G`` is linear in the inverse modal
stiffnesses ``c_r = 1 / k_r``::

    X_a(f_h) = exp(i h theta) sum_r c_r u_ra (u_r . F(f_h)) / (1 - (f_h/f_r)^2 + 2 i zeta_r f_h/f_r)

``theta`` is the unknown angle of the spindle at the record's first sample (one per record; the
force model knows the force as a function of the tool's angle, not of the record's clock). It is
found by a search over one revolution, the ``c_r`` by non-negative weighted least squares at
each angle (weights: the broadband response level at each line).

Where the force comes from. The tooth-passing lines of the force in a stable cut are those of the
static chip: for vibration that repeats every tooth period, ``q(t) - q(t - T)`` vanishes and the
regenerative chip adds nothing at these lines (formats.md force model). So the linear-plus-edge
model of :func:`oma.synthetic.milling_force` (the same model the simulator in ``stability``
integrates, without its delay term) gives them exactly, and the scaling can live in ``oma``
without importing ``stability`` (the dependency flow stays ``oma <- stability <- planner``).
Runout lines (spindle multiples that are not tooth lines) depend on the unknown runout and are
not used. A coefficient error passes into the stiffness one for one: ``F`` scales with the
coefficients, so ``k`` does.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import optimize

from .._arrays import readonly as _ro
from ..cutting import CuttingCoefficients, Cut, Tool
from ..synthetic import milling_force

__all__ = ["tooth_force_harmonics", "StiffnessScaling", "scale_modes", "line_misfit"]

#: A mode whose statistical relative standard uncertainty of stiffness exceeds this is called
#: too weakly excited by the harmonics to be scaled (the harmonics are too far from it).
MAX_SCALING_UNCERTAINTY = 0.25
#: At most this many reweightings of the lines by their effective variance (noise and the modes'
#: errors), until no stiffness moves by more than ``EFFECTIVE_VARIANCE_TOL`` (relative).
EFFECTIVE_VARIANCE_ITERATIONS = 10
EFFECTIVE_VARIANCE_TOL = 1e-3
#: Floor of the statistical relative sd of a stiffness: on the benchmark's records the well-scaled
#: modes carry mean errors of -1.4 to +1.8 % over 20 records (the 70 Hz mode of the extra-mode case
#: +1.8 %; source not found), which no part of the statistical error describes; without the floor
#: the effective-variance weights left that mode's statistical intervals holding the truth in 70 %
#: of 20 records (z-scores rms 1.67; with the floor 0.98).
STATISTICAL_SD_FLOOR = 0.02


def tooth_force_harmonics(tool: Tool, cut: Cut, coefficients: CuttingCoefficients, orders, *,
                          n_per_rev: int = 2048) -> np.ndarray:
    """Complex amplitudes of the static-chip milling force at spindle orders ``orders``.

    Parameters
    ----------
    tool, cut, coefficients
        The cut (``cut.spindle_rpm`` and ``cut.axial_depth_m`` set) and the force model.
    orders : array_like of int, shape (n_h,)
        Harmonic numbers ``h`` (frequency ``h * rpm / 60``).
    n_per_rev : int
        Samples per revolution of the Fourier series.

    Returns
    -------
    ndarray of complex, shape (3, n_h)
        ``a_h`` with the force ``F(t) = F_0 + sum_h Re(a_h exp(i h Omega t))``, machine frame, N,
        ``t = 0`` when tooth 0 is at immersion angle 0.
    """
    f_spindle = cut.spindle_rpm / 60.0
    t = np.arange(n_per_rev) / (n_per_rev * f_spindle)
    one_rev = milling_force(tool, cut, coefficients, t)
    coef = np.fft.rfft(one_rev, axis=-1) / n_per_rev
    return 2.0 * coef[:, np.asarray(orders, dtype=int)]


@dataclass(frozen=True)
class StiffnessScaling:
    """Stiffness of each mode from the harmonics, with its uncertainty.

    Attributes
    ----------
    stiffness_N_m : ndarray, shape (n_modes,)
        NaN for a mode the lines cannot scale (``c_r = 0`` at the optimum).
    statistical_relative_sd : ndarray, shape (n_modes,)
        Relative standard uncertainty from the response lines' noise, the misfit, and the
        frequency and damping uncertainty of the modes.
    coefficient_relative_sd : float
        Relative standard uncertainty of the cutting coefficients (passes one for one).
    relative_sd : ndarray, shape (n_modes,)
        Both combined (root sum of squares).
    interval_N_m : ndarray, shape (n_modes, 2)
        Log-normal ``level`` interval.
    theta_rad : ndarray, shape (n_records,)
        Spindle angle at each record's start.
    lines_hz : ndarray
        The lines used.
    directions : ndarray, shape (n_modes, 3), optional
        Directions refined by the lines (``direction_sd`` given), else the ones passed in.
    misfit : float
        Reduced chi-square of the fit (1: the lines agree with the model to their noise).
    too_far : ndarray of bool, shape (n_modes,)
        The lines scale this mode poorly (statistical uncertainty above
        :data:`MAX_SCALING_UNCERTAINTY`).
    """

    stiffness_N_m: np.ndarray
    statistical_relative_sd: np.ndarray
    coefficient_relative_sd: float
    relative_sd: np.ndarray
    interval_N_m: np.ndarray
    theta_rad: np.ndarray
    lines_hz: np.ndarray = field(repr=False)
    misfit: float = float("nan")
    too_far: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    directions: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        for name in ("stiffness_N_m", "statistical_relative_sd", "relative_sd", "interval_N_m", "theta_rad",
                     "lines_hz"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "too_far", _ro(self.too_far, bool))

    def to_dict(self) -> list[dict]:
        """Per-mode ``stiffness_uncertainty`` entries."""
        out = []
        for k, s, r, iv, far in zip(self.stiffness_N_m, self.statistical_relative_sd, self.relative_sd,
                                    self.interval_N_m, self.too_far):
            out.append({"stiffness_N_m": _num(k), "relative_sd": _num(r), "statistical_relative_sd": _num(s),
                        "coefficient_relative_sd": float(self.coefficient_relative_sd),
                        "interval_N_m": [_num(v) for v in iv], "harmonics_too_far": bool(far)})
        return out


def _num(x):
    x = float(x)
    return x if np.isfinite(x) else None


def _design(freq_hz, damping, directions, force, lines_hz, orders, theta, axes):
    """Complex design (n_rows, n_modes): rows (axis, line), one block per record."""
    blocks = []
    for f_h, h, F, th in zip(lines_hz, orders, force, theta):
        ratio = f_h[None, :] / freq_hz[:, None]  # (m, n_h)
        d = 1.0 - ratio ** 2 + 2j * damping[:, None] * ratio
        uf = directions @ F  # (m, n_h)
        b = directions[:, axes, None] * (uf / d)[:, None, :] * np.exp(1j * h * th)[None, None, :]  # (m, l, n_h)
        blocks.append(b.reshape(freq_hz.size, -1).T)
    return np.vstack(blocks)


def _solve(design, x, w):
    a = design * w[:, None]
    y = x * w
    a_r = np.vstack([a.real, a.imag])
    y_r = np.concatenate([y.real, y.imag])
    c, rnorm = optimize.nnls(a_r, y_r)
    return c, rnorm ** 2, a_r


def scale_modes(freq_hz, damping_ratio, directions, response, noise, force, lines_hz, orders, *,
                axes=None, freq_se_hz=None, damping_se=None, direction_se_rad=None, coefficient_relative_sd: float = 0.15,
                level: float = 0.95, n_draws: int = 40, rng=0, direction_sd: float | None = None) -> StiffnessScaling:
    """Modal stiffnesses from displacement lines and predicted force lines (module docstring).

    Parameters
    ----------
    freq_hz, damping_ratio : array_like, shape (m,)
    directions : array_like, shape (m, 3)
    response : sequence of complex arrays, shape (l, n_h) per record
        Displacement amplitudes of the lines on the measured axes, m.
    noise : sequence of arrays, shape (l, n_h)
        Standard deviation of each amplitude, m.
    force : sequence of complex arrays, shape (3, n_h)
        Predicted force amplitudes (:func:`tooth_force_harmonics`), N.
    lines_hz : sequence of arrays, shape (n_h,)
    orders : sequence of int arrays, shape (n_h,)
        Spindle orders of the lines (the phase of line ``h`` turns by ``h theta``).
    axes : array_like of bool, shape (3,), optional
        Measured axes (all by default).
    freq_se_hz, damping_se : array_like, shape (m,), optional
        Standard errors of the modes, propagated by Monte Carlo (``n_draws``).
    direction_se_rad : array_like, shape (m,), optional
        Angular standard error of each direction, propagated by the same Monte Carlo (a tilt of
        that rms size in a random direction). This is what makes a weakly forced mode next to a
        strongly forced one (Z at 10.0 Hz beside X at 10.5 Hz, axial force a sixth of the
        feed force) come out with the large uncertainty it has.
    coefficient_relative_sd : float
        Relative standard uncertainty of the cutting coefficients.
    direction_sd : float, optional
        When given, the directions are refined together with the stiffnesses and angles
        (nonlinear least squares), held to the given ones by a prior of this standard deviation
        (rad). The directions of close modes (10.0 and 10.5 Hz, 1 Hz half-power bands) come out
        of SSI tilted by up to 20 degrees; several tooth lines, whose forces point different
        ways, pin them down.
    """
    f = np.asarray(freq_hz, dtype=float)
    z = np.asarray(damping_ratio, dtype=float)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    axes = np.ones(3, bool) if axes is None else np.asarray(axes, bool)
    lines_hz = [np.asarray(v, dtype=float) for v in lines_hz]
    orders = [np.asarray(v, dtype=int) for v in orders]
    x = np.concatenate([np.asarray(r, dtype=complex).ravel() for r in response])
    w = 1.0 / np.maximum(np.concatenate([np.asarray(s, dtype=float).ravel() for s in noise]), np.finfo(float).tiny)
    w = w * np.sqrt(2.0)  # sd of each of Re and Im is the amplitude's sd over sqrt(2)
    n_rec = len(response)
    theta = np.zeros(n_rec)
    grid = np.linspace(0.0, 2.0 * np.pi, 361)[:-1]

    def cost_record(j, th, th_all):
        tt = th_all.copy()
        tt[j] = th
        return _solve(_design(f, z, u, force, lines_hz, orders, tt, axes), x, w)[1]

    for _ in range(3 if n_rec > 1 else 1):
        for j in range(n_rec):
            costs = [cost_record(j, g, theta) for g in grid]
            g0 = grid[int(np.argmin(costs))]
            res = optimize.minimize_scalar(lambda th: cost_record(j, th, theta), bounds=(g0 - 0.02, g0 + 0.02),
                                           method="bounded", options={"xatol": 1e-6})
            theta[j] = res.x
    if direction_sd is not None:
        u, theta = _refine(f, z, u, force, lines_hz, orders, theta, axes, x, w, float(direction_sd))
    design = _design(f, z, u, force, lines_hz, orders, theta, axes)
    c, chi2, a_r = _solve(design, x, w)
    # the modes' own errors (frequency, damping, direction), drawn once: they set the lines'
    # effective weights and give the Monte Carlo part of the stiffness uncertainty
    drawn = []
    if freq_se_hz is not None and damping_se is not None and n_draws > 1:
        gen = np.random.default_rng(rng)
        fse = np.nan_to_num(np.asarray(freq_se_hz, dtype=float))
        zse = np.nan_to_num(np.asarray(damping_se, dtype=float))
        use = np.zeros(f.size) if direction_se_rad is None else np.nan_to_num(np.asarray(direction_se_rad, float))
        for fd, zd, ud in _mode_draws(f, z, u, fse, zse, use, gen, n_draws):
            drawn.append(_design(fd, zd, ud, force, lines_hz, orders, theta, axes))
        drawn = np.array(drawn)
        # effective variance (Orear, Am. J. Phys. 50, 1982): a line's misfit is its noise and the
        # spread the modes' errors give its prediction. A line inside a mode's half-power band
        # (the 24.0 Hz tooth line in the 24.8 Hz / 4 % mode) predicts the response through the
        # steep 1/D_r, so a 10 % damping error moves it by about 10 %; lines above the modes
        # (mass lines) hardly depend on damping. Weighted by noise alone, the in-band line
        # carried the mode's scale and its damping error with it (24.8 Hz mode: 19.6 % worst
        # stiffness error in 20 records, 2.9 % with these weights; docs/output_only.md).
        # Reweighted until the stiffnesses settle (2-4 passes on the benchmark's records; one
        # record's X mode moved 3.8 -> 1.8 -> 1.6e6 N/m over passes 1, 2, 4, truth 1.5e6).
        noise_var = 2.0 / w**2
        for _ in range(EFFECTIVE_VARIANCE_ITERATIONS):
            pred = drawn @ c
            spread = np.mean(np.abs(pred - pred.mean(axis=0)) ** 2, axis=0)
            w = np.sqrt(2.0 / (noise_var + spread))
            c_old = c
            c, chi2, a_r = _solve(design, x, w)
            if np.all(np.abs(c - c_old) <= EFFECTIVE_VARIANCE_TOL * np.maximum(np.abs(c_old), 1e-300)):
                break
    dof = max(a_r.shape[0] - f.size - n_rec, 1)
    misfit = chi2 / dof
    # misfit per axis (rows of the design are (axis, line) per record, Re then Im), and per mode
    # weighted by where the mode moves: a mode the lines cannot explain on one axis (Z beside X)
    # must not inflate the uncertainty of a mode on another axis
    l = int(np.sum(axes))
    resid = (design @ c - x) * w
    axis_of_row = np.concatenate([np.repeat(np.arange(l), v.size) for v in lines_hz])
    axis_misfit = np.array([np.mean(np.abs(resid[axis_of_row == a]) ** 2) / 2.0 if np.any(axis_of_row == a)
                            else 1.0 for a in range(l)]) * (a_r.shape[0] / dof)
    mode_misfit = (u[:, axes] ** 2) @ axis_misfit
    with np.errstate(divide="ignore", invalid="ignore"):
        stiffness = np.where(c > 0, 1.0 / c, np.nan)
        cov = np.linalg.pinv(a_r.T @ a_r)
        rel_ls = np.sqrt(np.diag(cov) * np.maximum(mode_misfit, 1.0)) / c
    rel_mc = np.zeros(f.size)
    if len(drawn):
        draws = np.array([_solve(d, x, w)[0] for d in drawn])
        with np.errstate(divide="ignore", invalid="ignore"):
            logs = np.log(np.where(draws > 0, draws, np.nan))
            rel_mc = np.nanstd(logs, axis=0)
            # a draw that leaves a mode unscaled (c = 0) counts as an unbounded error
            rel_mc = np.where(np.mean(np.isfinite(logs), axis=0) < 0.9, np.inf, rel_mc)
    with np.errstate(over="ignore", invalid="ignore"):
        # an unbounded error stays infinite (nan_to_num's default turns inf into the largest float,
        # which then read as a finite, astronomically large sd in the JSON)
        stat = np.hypot(*(np.nan_to_num(r, nan=np.inf, posinf=np.inf) for r in (rel_ls, rel_mc)))
        stat = np.where(np.isfinite(stiffness), np.maximum(stat, STATISTICAL_SD_FLOOR), np.inf)
        total = np.hypot(stat, float(coefficient_relative_sd))
    from scipy import stats

    zq = stats.norm.ppf(0.5 + 0.5 * level)
    with np.errstate(over="ignore", invalid="ignore"):
        interval = np.column_stack([stiffness * np.exp(-zq * total), stiffness * np.exp(zq * total)])
    return StiffnessScaling(
        stiffness_N_m=stiffness, statistical_relative_sd=stat, coefficient_relative_sd=float(coefficient_relative_sd),
        relative_sd=total, interval_N_m=interval, theta_rad=theta, lines_hz=np.concatenate(lines_hz),
        misfit=float(misfit), too_far=~(stat <= MAX_SCALING_UNCERTAINTY), directions=u,
    )


def line_misfit(scaling: StiffnessScaling, freq_hz, damping_ratio, response, noise, force, lines_hz, orders,
                theta_rad, *, axes=None, freq_se_hz=None, damping_se=None, direction_se_rad=None, n_draws: int = 40,
                rng=0) -> tuple[float, np.ndarray]:
    """How well the scaled modes predict response lines that did not scale them.

    Parameters
    ----------
    scaling : StiffnessScaling
        Stiffnesses (a mode it could not scale contributes nothing), their statistical relative
        uncertainty, and directions.
    freq_hz, damping_ratio : array_like, shape (m,)
    response, noise, force, lines_hz, orders :
        As for :func:`scale_modes`: the other lines.
    theta_rad : sequence of float
        Spindle angle at each of these records' start (``scaling.theta_rad`` of the same records).
    axes : array_like of bool, shape (3,), optional
    freq_se_hz, damping_se, direction_se_rad : array_like, shape (m,), optional
        The modes' standard errors, drawn with the stiffnesses' (``n_draws``, seeded ``rng``) as
        in :func:`scale_modes`.

    Returns
    -------
    misfit : float
        ``|x - G F|^2 / v`` averaged over the lines, ``v`` the line's noise variance plus the
        variance of the prediction over the draws of the modes' errors (effective variance, as in
        :func:`scale_modes`; a stiffness's relative error is taken as at most 100 %: a mode
        scaled with an unbounded one may contribute anything up to its prediction); 1: the lines
        agree with the model (nothing is fitted to them).
    discrepancy : ndarray, shape (l,)
        Per measured axis, ``||x - G F|| / ||G F||`` over the lines.
    """
    f = np.asarray(freq_hz, dtype=float)
    z = np.asarray(damping_ratio, dtype=float)
    axes = np.ones(3, bool) if axes is None else np.asarray(axes, bool)
    if scaling.directions is None:
        raise ValueError("the scaling carries no directions")
    u = np.asarray(scaling.directions, dtype=float)
    lines_hz = [np.asarray(v, dtype=float) for v in lines_hz]
    orders = [np.asarray(v, dtype=int) for v in orders]
    theta = np.asarray(theta_rad, dtype=float)
    x = np.concatenate([np.asarray(r, dtype=complex).ravel() for r in response])
    sd = np.concatenate([np.asarray(s, dtype=float).ravel() for s in noise])
    c = np.where(np.isfinite(scaling.stiffness_N_m), 1.0 / scaling.stiffness_N_m, 0.0)
    pred = _design(f, z, u, force, lines_hz, orders, theta, axes) @ c
    rel = np.where(c > 0, np.minimum(np.nan_to_num(scaling.statistical_relative_sd, nan=np.inf), 1.0), 0.0)
    gen = np.random.default_rng(rng)
    fse = np.zeros(f.size) if freq_se_hz is None else np.nan_to_num(np.asarray(freq_se_hz, dtype=float))
    zse = np.zeros(f.size) if damping_se is None else np.nan_to_num(np.asarray(damping_se, dtype=float))
    use = np.zeros(f.size) if direction_se_rad is None else np.nan_to_num(np.asarray(direction_se_rad, float))
    draws = []
    for fd, zd, ud in _mode_draws(f, z, u, fse, zse, use, gen, n_draws):
        cd = c * np.exp(rel * gen.standard_normal(f.size))  # drawn after each mode draw, from the same generator
        draws.append(_design(fd, zd, ud, force, lines_hz, orders, theta, axes) @ cd)
    spread = np.mean(np.abs(np.array(draws) - pred[None, :]) ** 2, axis=0) if draws else 0.0
    var = sd ** 2 + spread
    misfit = float(np.mean(np.abs(x - pred) ** 2 / np.maximum(var, np.finfo(float).tiny)))
    l = int(np.sum(axes))
    axis_of_row = np.concatenate([np.repeat(np.arange(l), v.size) for v in lines_hz])
    with np.errstate(divide="ignore", invalid="ignore"):
        discrepancy = np.array([np.linalg.norm((x - pred)[axis_of_row == a]) / np.linalg.norm(pred[axis_of_row == a])
                                for a in range(l)])
    return misfit, discrepancy


def _mode_draws(f, z, u, freq_se, damping_se, direction_se, gen, n_draws: int):
    """``n_draws`` draws of the modes' frequencies, damping and directions from their standard
    errors (directions tilted in their tangent plane, renormalised), from the generator ``gen``."""
    tangent = _tangent_basis(u)
    for _ in range(n_draws):
        fd = f + freq_se * gen.standard_normal(f.size)
        zd = np.clip(z + damping_se * gen.standard_normal(f.size), 1e-4, None)
        tilt = np.einsum("mk,mkj->mj", gen.standard_normal((f.size, 2)) * (direction_se / np.sqrt(2.0))[:, None],
                         tangent)
        ud = u + tilt
        yield fd, zd, ud / np.linalg.norm(ud, axis=1, keepdims=True)


def _tangent_basis(u):
    """Two unit vectors orthogonal to each row of ``u`` (m, 3): (m, 2, 3)."""
    out = []
    for v in u:
        a = np.eye(3)[int(np.argmin(np.abs(v)))]
        e1 = np.cross(v, a)
        e1 /= np.linalg.norm(e1)
        out.append([e1, np.cross(v, e1)])
    return np.array(out)


def _refine(f, z, u0, force, lines_hz, orders, theta0, axes, x, w, sd):
    """Directions and angles refined with the stiffnesses (see :func:`scale_modes`)."""
    m = f.size
    basis = _tangent_basis(u0)
    c0 = _solve(_design(f, z, u0, force, lines_hz, orders, theta0, axes), x, w)[0]
    c0 = np.where(c0 > 0, c0, np.max(c0) * 1e-3 + 1e-12)

    def unpack(p):
        d = p[m:3 * m].reshape(m, 2)
        u = u0 + np.einsum("mk,mkj->mj", d, basis)
        return np.exp(p[:m]), u / np.linalg.norm(u, axis=1, keepdims=True), p[3 * m:], d

    def resid(p):
        c, u, th, d = unpack(p)
        r = (_design(f, z, u, force, lines_hz, orders, th, axes) @ c - x) * w
        return np.concatenate([r.real, r.imag, d.ravel() / sd])

    p0 = np.concatenate([np.log(c0), np.zeros(2 * m), theta0])
    sol = optimize.least_squares(resid, p0, method="lm", max_nfev=200 * p0.size)
    _, u, th, _ = unpack(sol.x)
    return u, th


def with_spindle(cut: Cut, spindle_hz: float) -> Cut:
    """The cut at the refined spindle speed."""
    return replace(cut, spindle_rpm=60.0 * float(spindle_hz))
