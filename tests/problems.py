"""Test problems for the cutting-parameter planner (planner/optimize.py), and a reference search.

* Problems with a closed-form optimum (in the spirit of rockit's ``tests/problems.py``): each
  returns a :class:`ClosedForm` with the setup, the structure and the optimum derived by hand in
  its docstring.
* :func:`grid_search`: an exhaustive search over the same constraints built only from the
  stability library (:func:`stability.zoa.envelope` for the limit, :func:`stability.forced.
  forced_sweep` for force, torque and power, the receptance and exact force harmonics for the
  surface error on the whole finished wall, :func:`stability.forced.forced_response` for the final
  check), independent of the planner's analytic models, wall search, pockets and NLP.

The surface-error limit holds on the whole finished wall (formats.md), not at the tool tip alone:
the slice at height ``z`` is finished ``kappa z / Omega`` after the tip, so the wall there is the
steady displacement along the normal at that instant (harmonic ``h`` turned by ``exp(i h N kappa
z)``; :func:`stability.forced.forced_response`'s ``sle_profile_m`` samples it at 21 heights).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize_scalar

from oma.cutting import Cut, CuttingCoefficients, Material, Tool, engagement_angles
from oma.modal import ModalModel
from stability import zoa
from stability.forced import default_harmonics, forced_response, forced_sweep
from stability.oriented import helix_lag_per_m
from stability.setup import Limits, Setup


@dataclass(frozen=True)
class ClosedForm:
    """A planning problem and its optimum (``None`` where the optimum is not unique)."""

    name: str
    setup: Setup
    structure: ModalModel
    mrr_m3_s: float
    spindle_rpm: float | None
    axial_depth_m: float | None
    feed_per_tooth_m: float | None
    active: tuple[str, ...]


def _mrr(setup, rpm, ap, fz):
    return ap * setup.cut.radial_depth_m * fz * setup.tool.teeth * rpm / 60.0


# 1-DOF structure of the Insperger-Stepan / Ding slotting benchmark (as in tests/test_zoa.py),
# flexible along the cut's normal direction (machine y).
FN_HZ, ZETA, MASS_KG = 922.0, 0.011, 0.03993
STIFF_N_M = MASS_KG * (2 * np.pi * FN_HZ) ** 2


def lobe_minimum() -> ClosedForm:
    """Stability-limited optimum at the minimum of lobe 0 of a 1-DOF slot.

    Mode along ``n``, slotting, straight flutes, no edge or axial forces: the mean directional
    factor is ``B_nn = -N Kr / 4`` and the ZOA limit ``a = 1 / (2 B_nn Re G(f))``. Its smallest
    value, at ``r = f / f_n = sqrt(1 + 2 zeta)`` where ``Re G = -1 / (4 k zeta (1 + zeta))``, is
    ``a_min = 8 k zeta (1 + zeta) / (N Kr)``; there ``lambda = B_nn G`` has the argument
    ``atan(r)``, so ``eps = pi + 2 atan(r)`` and lobe 0 has its minimum at
    ``n* = 60 f / (N eps / 2 pi)``. No lobe is lower than ``a_min`` anywhere, so the envelope at
    ``n*`` is ``a_min``. With the speed range ``[0.95 n*, n*]`` (where lobe 0 rises only slowly
    to the left, checked by the test against the exact envelope), feed and depth free and no
    other limit, the optimum is ``n = n*``, ``ap = margin a_min``, ``fz = fz_max``.
    """
    teeth, kr = 2, 2e8
    r = np.sqrt(1 + 2 * ZETA)
    a_min = 8 * STIFF_N_M * ZETA * (1 + ZETA) / (teeth * kr)
    eps = np.pi + 2 * np.arctan(r)
    n_star = 60 * FN_HZ * r / (teeth * eps / (2 * np.pi))
    margin, fz_max = 0.8, 1e-4
    tool = Tool(teeth, 0.01)
    cut = Cut(5e-5, 0.01, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])
    limits = Limits(spindle_rpm=(0.95 * n_star, n_star), axial_depth_m=(1e-5, 1e-2),
                    feed_per_tooth_m=(5e-5, fz_max), stability_margin=margin)
    setup = Setup(tool, cut, Material("benchmark", CuttingCoefficients(6e8, kr)), limits)
    structure = ModalModel([FN_HZ], [ZETA], [STIFF_N_M], [[0, 1, 0]])
    ap = margin * a_min
    return ClosedForm("lobe_minimum", setup, structure, _mrr(setup, n_star, ap, fz_max), n_star, ap, fz_max,
                      ("stability", "rpm_max", "feed_max"))


def _stiff_structure():
    """A stiff, well-damped tool mode along ``n``: its stability limit is far above any depth here."""
    return ModalModel([3000.0], [0.05], [5e9], [[0, 1, 0]])


def power_limited() -> ClosedForm:
    """Spindle power binds: ``MRR* = P_max / Ktc``.

    Without edge forces the mean torque per unit depth is ``(N R / 2 pi) Ktc fz (cos phi_st -
    cos phi_ex)`` and ``cos phi_st - cos phi_ex = 2 ae / D`` for up and down milling alike (the
    helix does not change a mean), so ``P = 2 pi n / 60 * ap * torque = Ktc * (ap ae fz N n / 60)
    = Ktc MRR``: every power-limited point removes ``P_max / Ktc``. The optimum is not unique.
    """
    ktc, p_max = 8e8, 2000.0
    tool = Tool(3, 0.016, np.deg2rad(30.0))
    cut = Cut(1e-4, 0.004, "up", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])
    limits = Limits(spindle_rpm=(3000.0, 15000.0), axial_depth_m=(1e-4, 8e-3),
                    feed_per_tooth_m=(2e-5, 1.5e-4), spindle_power_W=p_max, stability_margin=0.8)
    setup = Setup(tool, cut, Material("no edge", CuttingCoefficients(ktc, 0.3 * ktc, 0.1 * ktc)), limits)
    return ClosedForm("power_limited", setup, _stiff_structure(), p_max / ktc, None, None, None, ("power",))


def force_limited() -> ClosedForm:
    """Peak force binds at the top speed: ``ap fz = F_max / (sqrt(Kt^2 + Kr^2) sin phi_st)``.

    Two straight flutes, down milling with ``ae <= D / 2``: one tooth cuts at a time, on
    ``[phi_st, pi]`` with ``phi_st >= pi / 2``; its chip ``fz sin(phi)`` gives the in-plane
    force ``ap fz sin(phi) sqrt(Kt^2 + Kr^2)`` (no edge forces), largest at entry, where
    ``sin(phi_st) = sqrt(1 - (2 ae / D - 1)^2)``. The removal rate ``ap fz ae N n / 60`` is then
    largest at ``n_max`` with ``ap fz`` at that bound (the split between ``ap`` and ``fz`` is free).
    """
    kt, kr, f_max = 7e8, 2.1e8, 800.0
    tool = Tool(2, 0.012)
    cut = Cut(1e-4, 0.003, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])
    limits = Limits(spindle_rpm=(4000.0, 12000.0), axial_depth_m=(1e-4, 1e-2),
                    feed_per_tooth_m=(2e-5, 2e-4), max_force_N=f_max, stability_margin=0.8)
    setup = Setup(tool, cut, Material("no edge", CuttingCoefficients(kt, kr)), limits)
    st, _ = engagement_angles(tool, cut)
    apfz = f_max / (np.hypot(kt, kr) * np.sin(st))
    mrr = apfz * cut.radial_depth_m * tool.teeth * 12000.0 / 60.0
    return ClosedForm("force_limited", setup, _stiff_structure(), mrr, 12000.0, None, None, ("force", "rpm_max"))


CLOSED_FORM = (lobe_minimum, power_limited, force_limited)


# ------------------------------------------------------------------------------ reference search
@dataclass(frozen=True)
class GridOptimum:
    """Best point of :func:`grid_search` and the size of the grid (speeds x depths x feeds)."""

    mrr_m3_s: float
    spindle_rpm: float
    axial_depth_m: float
    feed_per_tooth_m: float
    evaluated: int


class _Tables:
    """The constraints of one setup on grids, from the stability library's public building blocks.

    Surface error: ``SLE = s n . (G(0) F_0 + 2 Re sum_h G(h f_T) F_h e^{i h N phi_fin})`` (the
    formula of :mod:`stability.forced`) with the receptance read once per speed, so the sum over
    harmonics is a matrix product; on the wall (:meth:`wall`) harmonic ``h`` turns by
    ``e^{i h N kappa z}`` at height ``z``, sampled at heights ``z = s ap`` that resolve the
    harmonics near the modes (``wall_per_turn`` per turn over the depth of the one at twice the
    highest natural frequency: a screen, its sampled maximum low by ~(pi / wall_per_turn)^2 / 2 of
    that harmonic at most; the tip and the top of the wall exactly). Force harmonics: those of a
    straight flute per unit depth, from exact cell means
    (:func:`stability.oriented.engaged_axial_step_mean`) corrected for the cell averaging as in
    :mod:`stability.forced`, times the helix factor
    ``int_0^ap exp(-i h N kappa z) dz`` (the slice at height ``z`` lags by ``kappa z``), at the
    lowest and highest feed (the force is affine in feed). Peak force and torque: a fine angle
    grid plus both sides of every entry and exit angle
    (:func:`stability.oriented.engaged_axial_integral`). Power: :func:`forced_sweep` (mean torque
    linear in depth, affine in feed). The tests check these tables against
    :func:`stability.lobes.predict_point`, and every answer of :func:`grid_search` is re-checked
    with :func:`point_ratio`.
    """

    def __init__(self, model, setup, depths, feeds, rpm_lo, *, wall_per_turn: int = 8):
        from stability.oriented import (engaged_axial_integral, engaged_axial_step_mean, force_coefficients,
                                        torque_coefficients)

        self.model, self.setup, self.wall_per_turn = model, setup, wall_per_turn
        tool, cut, coef = setup.tool, setup.cut, setup.material.cutting_coefficients
        self.depths, self.feeds = depths, feeds
        self.n_h = h_max = default_harmonics(model, tool, rpm_lo)  # enough for every speed >= rpm_lo
        self.fa, self.fb = feeds[0], feeds[-1]
        pitch = 2 * np.pi / tool.teeth
        # 16x the library's cells: its aliasing bound (1e-4 of a harmonic at a jump) falls ~250x
        cells = int(2 ** np.ceil(np.log2(max(16384, 256 * h_max))))
        edges = pitch * np.arange(cells + 1) / cells
        straight = Tool(tool.teeth, tool.diameter_m)
        e = engaged_axial_step_mean(straight, cut, edges[:-1], edges[1:], 1.0)  # (M, 6), per unit depth
        dft = np.fft.fft(e, axis=0)[: h_max + 1] / cells
        x = 2 * np.pi * np.arange(1, h_max + 1) / cells
        kern = np.concatenate([[1.0], (np.exp(1j * x) - 1.0) / (1j * x)])
        unit = dft / kern[:, None]  # (H+1, 6)
        self.theta_1 = tool.teeth * helix_lag_per_m(tool)  # turn of harmonic 1 per unit height, rad/m
        theta = np.arange(h_max + 1) * self.theta_1
        with np.errstate(invalid="ignore", divide="ignore"):
            helix = np.where(theta[None, :] * depths[:, None] > 1e-12,
                             (1 - np.exp(-1j * theta[None, :] * depths[:, None])) / (1j * theta[None, :]),
                             depths[:, None])  # (D, H+1)
        self.harm = [np.einsum("pi,ij,hj,dh->dph", cut.frame.T, force_coefficients(coef, f), unit, helix)
                     for f in (self.fa, self.fb)]  # (D, 3, H+1), machine frame
        self.phi_fin, self.sign = (np.pi, 1.0) if cut.milling == "down" else (0.0, -1.0)
        st, ex = engagement_angles(tool, cut)
        grid = pitch * np.arange(1024) / 1024  # plus the jump angles: the peak to ~1e-6
        self.peak = np.zeros((depths.size, feeds.size, 2))
        fcs = [force_coefficients(coef, f)[:2] for f in feeds]
        tcs = [torque_coefficients(coef, f, tool.diameter_m / 2) for f in feeds]
        for j, a in enumerate(depths):
            lag = helix_lag_per_m(tool) * a
            crit = np.mod(np.array([st, ex, st + lag, ex + lag])[:, None] - pitch * np.arange(tool.teeth), pitch).ravel()
            phi = np.concatenate([grid, crit - 1e-9 * pitch, crit, crit + 1e-9 * pitch])
            ea = engaged_axial_integral(tool, cut, phi, a)
            for k in range(feeds.size):
                f = ea @ fcs[k].T
                self.peak[j, k] = np.max(np.hypot(f[:, 0], f[:, 1])), np.max(ea @ tcs[k])
        p = [forced_sweep(model, tool, replace(cut, feed_per_tooth_m=f), coef, rpm=[1000.0], axial_depth_m=1e-3,
                          harmonics=0).power_W[0] for f in (self.fa, self.fb)]
        self.power_per = np.array(p) / (1000.0 * 1e-3)  # W per (rpm m) at the two feeds

    def _normal_receptance(self, rpm, n_h):
        """``s n . G`` at the harmonics 1..n_h of the tooth frequency, turned to the finishing
        instant of the tip, (R, n_h, 3), and ``s n . G(0)`` (3,), m/N."""
        tool, cut = self.setup.tool, self.setup.cut
        h = np.arange(1, n_h + 1)
        f_tooth = tool.teeth * rpm / 60.0
        g = self.model.receptance((f_tooth[:, None] * h[None, :]).ravel()).reshape(3, 3, rpm.size, n_h)
        wall = self.sign * np.einsum("i,ijrh->rhj", cut.normal_direction, g)  # (R, H, 3)
        wall = wall * np.exp(1j * h * tool.teeth * self.phi_fin)[None, :, None]
        static = self.sign * (cut.normal_direction @ np.real(self.model.receptance([0.0])[:, :, 0]))
        return wall, static

    def _feed_weights(self):
        return (self.feeds - self.fa) / (self.fb - self.fa) if self.fb > self.fa else np.zeros(self.feeds.size)

    def sle(self, rpm):
        """Surface location error at the tool tip, shape (n_rpm, n_depth, n_feed), m."""
        wall, static = self._normal_receptance(rpm, self.n_h)
        t = self._feed_weights()
        out = []
        for fh in self.harm:
            dyn = 2.0 * np.real(wall.reshape(rpm.size, -1)
                                @ fh[:, :, 1:].transpose(2, 1, 0).reshape(-1, self.depths.size))
            out.append(dyn + (static @ fh[:, :, 0].real.T)[None, :])
        return out[0][..., None] * (1 - t) + out[1][..., None] * t

    def wall(self, rpm, cap=None, *, chunk: int = 32):
        """Largest ``|SLE|`` on the finished wall (heights 0 to the depth), shape (n_rpm, n_depth,
        n_feed), m; ``inf`` at depths above ``cap`` (per speed, m: infeasible by stability anyway,
        not evaluated).

        Per block of ``chunk`` speeds: the harmonics its lowest speed needs
        (:func:`stability.forced.default_harmonics`), the depths up to the block's largest cap,
        and heights ``z = s ap`` at fractions ``s`` evenly spaced from 0 to 1 (see the class).
        """
        tool = self.setup.tool
        cap = np.full(rpm.size, np.inf) if cap is None else np.asarray(cap, dtype=float)
        t = self._feed_weights()
        out = np.full((rpm.size, self.depths.size, self.feeds.size), np.inf)
        f_max = float(np.max(self.model.natural_frequency_hz))
        for i0 in range(0, rpm.size, chunk):
            r = rpm[i0:i0 + chunk]
            n_d = int(np.searchsorted(self.depths, np.max(cap[i0:i0 + chunk]), side="right"))
            if n_d == 0:
                continue
            d = self.depths[:n_d]
            n_h = min(self.n_h, default_harmonics(self.model, tool, float(r.min())))
            f_tooth = tool.teeth * float(r.min()) / 60.0
            turns = min(n_h, 2.0 * f_max / f_tooth) * self.theta_1 * d[-1] / (2 * np.pi)
            s = np.linspace(0.0, 1.0, int(np.clip(np.ceil(self.wall_per_turn * turns) + 1, 9, 4097)))
            step = np.exp(1j * self.theta_1 * s[:, None] * d[None, :])  # (Z, D): harmonic 1
            turn = np.empty((n_h,) + step.shape, dtype=complex)
            turn[0] = step
            for h in range(1, n_h):  # e^{i h theta_1 z}, h = 1..n_h
                turn[h] = turn[h - 1] * step
            turn = np.ascontiguousarray(turn.transpose(2, 0, 1))  # (D, H, Z)
            wall, static = self._normal_receptance(r, n_h)
            ends = []
            for fh in self.harm:  # the lowest and the highest feed
                x = np.einsum("rhj,djh->drh", wall, fh[:n_d, :, 1:n_h + 1])  # (D, R, H)
                ends.append(2.0 * np.real(np.matmul(x, turn)) + (fh[:n_d, :, 0].real @ static)[:, None, None])
            for k, w in enumerate(t):  # the surface error is affine in feed
                out[i0:i0 + r.size, :n_d, k] = np.max(np.abs(ends[0] * (1 - w) + ends[1] * w), axis=2).T
        return out

    def worst(self, rpm, limit):
        """Largest value / limit over the constraints, shape (n_rpm, n_depth, n_feed)."""
        lim = self.setup.limits
        t = self._feed_weights()
        margin = lim.stability_margin or 1.0
        out = self.depths[None, :] / (margin * limit[:, None])
        out = np.repeat(out[..., None], self.feeds.size, axis=2)
        if lim.surface_location_error_m is not None:  # on the whole wall; above the cap: unstable anyway
            out = np.maximum(out, self.wall(rpm, margin * limit) / lim.surface_location_error_m)
        per = self.power_per[0] * (1 - t) + self.power_per[1] * t  # W per (rpm m), affine in feed
        if lim.spindle_power_W is not None:
            out = np.maximum(out, rpm[:, None, None] * self.depths[None, :, None] * per[None, None, :]
                             / lim.spindle_power_W)
        if lim.max_force_N is not None:
            out = np.maximum(out, self.peak[None, :, :, 0] / lim.max_force_N)
        if lim.spindle_torque_N_m is not None:  # the MEAN torque (formats.md): power / (2 pi n / 60)
            mean_torque = self.depths[:, None] * per[None, :] * 60.0 / (2.0 * np.pi)
            out = np.maximum(out, mean_torque[None] / lim.spindle_torque_N_m)
        return out


def wall_maximum(fr, tool, cut) -> tuple[float, float]:
    """Largest ``|SLE|`` on the finished wall of a forced response, m, and its height, m.

    The SLE at height ``z`` is the steady displacement (``fr.displacement_at``) along the wall's
    normal at the tip's finishing instant plus ``kappa z / Omega``. Sampled at 16 points per turn
    of the highest harmonic summed over the depth (the tip and the top included); every sampled
    local maximum within 10 % of the largest is then refined by a bounded scalar search (Brent)
    between its neighbours, to 1e-9 of the depth.
    """
    kappa = helix_lag_per_m(tool)
    omega = 2 * np.pi * fr.spindle_rpm / 60.0
    sign = 1.0 if cut.milling == "down" else -1.0
    normal = np.asarray(cut.normal_direction, dtype=float)

    def sle(z):
        return sign * (normal @ fr.displacement_at(fr.finishing_time_s + kappa * np.atleast_1d(z) / omega))

    depth = fr.axial_depth_m
    turns = fr.harmonics * tool.teeth * kappa * depth / (2 * np.pi)
    z = np.linspace(0.0, depth, int(np.clip(np.ceil(16 * turns) + 1, 65, 20001)))
    v = np.abs(sle(z))
    best, at = float(v.max()), float(z[np.argmax(v)])
    inner = np.flatnonzero((v[1:-1] >= v[:-2]) & (v[1:-1] >= v[2:])) + 1
    for k in inner[v[inner] >= 0.9 * best]:
        res = minimize_scalar(lambda x: -abs(float(sle(x)[0])), bounds=(z[k - 1], z[k + 1]), method="bounded",
                              options={"xatol": 1e-9 * depth})
        if -res.fun > best:
            best, at = float(-res.fun), float(res.x)
    return best, at


def point_ratio(model, setup, rpm, ap, fz, limit) -> float:
    """Largest value / limit of the constraints at one point, exact (:func:`forced_response`, the
    library's default harmonics; the surface error on the whole wall, :func:`wall_maximum`), the
    limit depth given."""
    tool, cut, coef, lim = setup.tool, setup.cut, setup.material.cutting_coefficients, setup.limits
    cut = replace(cut, feed_per_tooth_m=fz)
    fr = forced_response(model, tool, cut, coef, spindle_rpm=rpm, axial_depth_m=ap)
    r = [ap / ((lim.stability_margin or 1.0) * limit)]
    if lim.surface_location_error_m is not None:
        r.append(wall_maximum(fr, tool, cut)[0] / lim.surface_location_error_m)
    if lim.spindle_power_W is not None:
        r.append(fr.power_W / lim.spindle_power_W)
    if lim.max_force_N is not None:
        r.append(fr.peak_force_N / lim.max_force_N)
    if lim.spindle_torque_N_m is not None:
        r.append(fr.mean_torque_N_m / lim.spindle_torque_N_m)
    return max(r)


def grid_search(setup, model, *, limit_at=None, n_rpm: int = 2000, n_depth: int = 300, n_feed: int = 5,
                n_refine: int = 4, n_local_rpm: int = 41, n_local_depth: int = 81, n_exact: int = 3,
                bisect: int = 14, wall_per_turn: int = 8) -> GridOptimum:
    """Exhaustive search of the planning problem, in three levels; the surface error bounded on
    the whole finished wall.

    ``limit_at(rpm_array) -> depth_array`` gives the stability limit (default: the exact ZOA
    envelope, :func:`stability.zoa.envelope`, whose lobe cusps are added to every speed grid).

    1. A speed grid x a geometric depth grid x a feed grid (the feed bounds included); the wall
       sampled at ``wall_per_turn`` heights per turn (:class:`_Tables`).
    2. Around the best few (speed, feed) pairs: a 40x finer speed grid x a fine depth grid
       spanning the coarse boundary depth (-2 to +1 coarse steps), at that feed (the harmonics
       those speeds need; the wall sampled 4 times as densely).
    3. For the best (speed, feed) pairs of level 2, ranked by the depth just above the boundary:
       an exact bisection in depth (:func:`point_ratio`) between the largest feasible fine depth
       and the next. Where the exact wall exceeds the limit at that fine depth (the tables sample
       the wall), the bracket steps down the fine grid first (at most 8 steps).

    The best depth for a speed and feed is the largest feasible one; it is not assumed that every
    smaller depth is feasible too (with a helix the surface error is not monotone in depth).
    """
    tool, cut, coef, lim = setup.tool, setup.cut, setup.material.cutting_coefficients, setup.limits
    feeds = np.linspace(*lim.feed_per_tooth_m, n_feed)
    curves = zoa.limit_curves(model, tool, cut, coef, zoa.default_chatter_frequencies(model)) if limit_at is None else None

    def search(tables, rpm):
        if limit_at is None:
            env = zoa.envelope(model, tool, cut, coef, rpm, curves=curves)
            rpm, limit = np.asarray(env.rpm), np.asarray(env.depth_limit_m)
        else:
            limit = np.asarray(limit_at(rpm), dtype=float)
        ok = tables.worst(rpm, limit) <= 1.0
        d = tables.depths
        n_ok = np.where(ok.any(axis=1), d.size - np.argmax(ok[:, ::-1], axis=1), 0)  # (R, F): 1 + index
        low = np.where(n_ok > 0, d[np.maximum(n_ok - 1, 0)], 0.0)
        high = np.where(n_ok > 0, d[np.minimum(n_ok, d.size - 1)], 0.0)
        return rpm, limit, low, high, rpm.size * d.size * tables.feeds.size

    lo, hi = lim.spindle_rpm
    depths = np.geomspace(*lim.axial_depth_m, n_depth)
    rpm, limit, low, high, evaluated = search(_Tables(model, setup, depths, feeds, lo, wall_per_turn=wall_per_turn),
                                              np.linspace(lo, hi, n_rpm))
    mrr = low * feeds[None, :] * rpm[:, None]
    step = (hi - lo) / (n_rpm - 1)
    centres = []  # (rpm, feed index, coarse depth index)
    for flat in np.argsort(mrr, axis=None)[::-1]:
        i, k = np.unravel_index(flat, mrr.shape)
        if mrr[i, k] <= 0:
            break
        if all(abs(rpm[i] - c) > 2 * step for c, _, _ in centres):
            centres.append((rpm[i], k, int(np.searchsorted(depths, low[i, k]))))
        if len(centres) == n_refine:
            break
    cand = []  # (upper bound of MRR, rpm, limit, low depth, high depth, feed)
    for c, k, j in centres:
        fine = np.geomspace(depths[max(j - 2, 0)], depths[min(j + 1, depths.size - 1)], n_local_depth)
        local = np.unique(np.clip(np.linspace(c - step, c + step, n_local_rpm), lo, hi))
        r2, l2, lw2, hg2, ev = search(_Tables(model, setup, fine, feeds[k:k + 1], local[0],
                                              wall_per_turn=4 * wall_per_turn), local)
        evaluated += ev
        for i in np.flatnonzero(lw2[:, 0] > 0):
            cand.append((hg2[i, 0] * feeds[k] * r2[i], r2[i], l2[i], lw2[i, 0], hg2[i, 0], feeds[k]))
    cand.sort(key=lambda t: -t[0])
    best = GridOptimum(0.0, np.nan, np.nan, np.nan, evaluated)
    for _, r, limit_r, a_lo, a_hi, f in cand[:n_exact]:
        ratio = a_hi / a_lo if a_hi > a_lo else 1.0
        for _ in range(8 if ratio > 1.0 else 0):  # the tables sample the wall: step down to an exact feasible depth
            if point_ratio(model, setup, r, a_lo, f, limit_r) <= 1.0:
                break
            a_hi, a_lo = a_lo, a_lo / ratio
        if a_hi > a_lo:
            for _ in range(bisect):
                mid = np.sqrt(a_lo * a_hi)
                if point_ratio(model, setup, r, mid, f, limit_r) <= 1.0:
                    a_lo = mid
                else:
                    a_hi = mid
        if point_ratio(model, setup, r, a_lo, f, limit_r) > 1.0:  # grid said feasible, exact says no
            continue
        m = _mrr(setup, r, a_lo, f)
        if m > best.mrr_m3_s:
            best = GridOptimum(float(m), float(r), float(a_lo), float(f), evaluated)
    return best
