"""Cutting parameters that remove material fastest: one CasADi NLP per stable pocket of the lobes.

The problem (robomill issue 5)::

    maximise    MRR = ap ae fz N n / 60                     over n (rpm), ap (m), fz (m)
    subject to  ap <= margin * a_lim(n)                      stability (ZOA or SDM limit)
                |SLE(n, ap, fz; z)| <= tol, 0 <= z <= ap     surface location error on the wall
                peak force (ap, fz) <= F_max
                mean torque = ap tau(fz) <= T_max,  power = 2 pi n / 60 * ap * tau(fz) <= P_max
                the bounds of the setup on n, ap and fz

How each function enters the NLP (smooth inside one pocket):

* **Stability** (:mod:`planner.pockets`): the lower envelope of the lobes is smooth between two
  adjacent lobe crossings, so the speed range is cut into *pockets* there, each with its limit as
  a Chebyshev series of the exact ZOA envelope (or a PCHIP through SDM samples, refined around the
  best pockets' answers); narrow pockets at low speed are merged under the lower convex hull of
  their minima (conservative, and cheap).
* **Surface location error** (:mod:`planner.cut_model`, :mod:`planner.wall`; Schmitz & Mann, IJMTM
  46, 2006): exact and analytic for a modal model, ``SLE(z) = fz S_c(n, ap, z) + S_e(n, ap, z)`` at
  height ``z`` on the finished wall (the limit holds on the whole wall, formats.md, not only at the
  tip), with no interpolation in ``n``, ``ap`` or ``z`` (the harmonics of
  :func:`stability.forced.default_harmonics` at the pocket's lowest speed). ``max_z |SLE|`` is a
  semi-infinite constraint; the NLP bounds ``|SLE|`` at a few heights ``z = s ap`` (the fractions
  ``s`` are parameters: those where the start point's profile peaks) and an exchange adds the
  height of the largest ``|SLE|`` on a dense grid at the answer until none exceeds the limit.
  The surface error is not monotone in depth: with a helix the force harmonics cancel near
  multiples of the axial pitch, so the limit can hold in thin bands of depth only; the start grid
  looks for them.
* **Peak force** does not depend on speed; at one depth the largest feed with the peak within the
  limit is exact (:meth:`planner.cut_model.CutModel.feed_bound`), and the NLP bounds the chip area
  ``ap fz`` by cubic B-splines of it, one per smooth piece in depth
  (:meth:`~planner.cut_model.CutModel.force_area`).
* **Torque and power** are exact (:meth:`~planner.cut_model.CutModel.mean_torque`,
  :meth:`~planner.cut_model.CutModel.power`). The limits bound the MEAN torque and power over a
  revolution (formats.md: a spindle's continuous rating); the peak torque is reported by
  :func:`stability.lobes.predict_point` but constrains nothing.

Every pocket is started from the best point of a grid evaluated with the same functions (a pocket
can hold several local optima of the surface error) and solved by IPOPT (one ``ca.Opti`` per
harmonic count, the pocket as parameters). The best answers are re-checked with
:func:`stability.lobes.predict_point` (the surface error on the whole wall from its forced
response, :func:`wall_error`); a violated constraint is tightened in that pocket by the measured
ratio and the pocket solved again. An answer that cannot be verified is never returned with
``success=True``, nor one at which no constraint binds (the removal rate grows with speed, depth
and feed, so an optimum lies on a constraint or a bound).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from itertools import combinations
from typing import Literal

import casadi as ca
import numpy as np
from scipy.interpolate import PchipInterpolator

from oma._arrays import readonly as _ro
from stability.lobes import OperatingPoint, predict_point
from stability.sdm import as_modal_model

from .cut_model import CutModel
from .plan_results import CONSTRAINTS, Plan, PlanBounds, PlanSettings, PocketResult, plan_bounds
from .pockets import Pocket, build_pockets, cheb_eval, sampled_pockets, sdm_pockets, zoa_pockets
from .wall import local_maxima, wall_error, wall_extremum, wall_points

__all__ = ["PlanSettings", "PocketResult", "Plan", "plan", "wall_error", "CONSTRAINTS"]

log = logging.getLogger(__name__)

_PROCESS = ("stability", "surface_error", "force", "power", "torque")

# Scales of the decision variables: speed / 1e4 rpm, depth / 1 mm, feed / 0.1 mm.
RPM_SCALE, DEPTH_SCALE, FEED_SCALE = 1e4, 1e-3, 1e-4

Method = Literal["auto", "zoa", "sdm"]

TWO_PI = 2.0 * np.pi


# Heights on the wall (fractions of the depth, NLP parameters) at which |SLE| can be bounded: an
# NLP per harmonic count and number of heights on this ladder (each height costs as much as the
# tip's surface error, so the NLP with the fewest heights that serves is taken).
_WALL_SLOTS = (1, 2, 4, 8)
# |SLE| is exceeded at an answer of the NLP when above the limit by this fraction (IPOPT's own
# tolerance is ~1e-8; the exchange adds a height only for a real excess).
_WALL_RTOL = 1e-6


# The cut's physics moved to CutModel; kept importable from here under their former names.
def _feed_bound(cm: CutModel, limit_N: float, depths) -> np.ndarray:
    """:meth:`CutModel.feed_bound`."""
    return cm.feed_bound(limit_N, depths)


def _wall_parts(cm: CutModel, n_harm: int, rpm, ap, frac):
    """:meth:`CutModel.wall_parts`."""
    return cm.wall_parts(rpm, ap, frac, n_harm)


def _wall_function(cm: CutModel, n_harm: int, slots: int) -> ca.Function:
    """:meth:`CutModel.wall_function`."""
    return cm.wall_function(n_harm, slots)


# ------------------------------------------------------------------------------------ the problem
@dataclass(frozen=True)
class _NLP:
    opti: ca.Opti
    x: tuple
    p: tuple


# IPOPT return states taken as converged.
_CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
# Harmonic counts for which NLPs are built (a pocket takes the first >= its default count).
_HARMONIC_LADDER = (32, 64, 128, 256, 512, 1024, 2048)
# Longest Chebyshev series of a pocket's limit (degree 128).
_MAX_COEFFS = 129
# Solver status of a pocket whose answer is its start point (the NLP found nothing better): a grid
# point, not an optimum.
_START_KEPT = "start_point_kept"
# The NLP's answer counts as worse than its start point below this fraction of its removal rate.
_SEED_RTOL = 1e-6


class _Problem:
    """Everything the NLPs share: the cut model, the peak-force bound, the limits."""

    def __init__(self, setup, model, settings: PlanSettings):
        self.setup, self.settings = setup, settings
        self.b: PlanBounds = plan_bounds(setup)
        self.cm = CutModel(model, setup.tool, setup.cut, setup.material.cutting_coefficients)
        self.fixed_feed = self.b.fz[1] <= self.b.fz[0]
        self._nlps: dict[tuple[int, int], _NLP] = {}
        # the largest chip area ap fz with the peak force within the limit, a CasADi spline of ap
        self.force_area = None if self.b.force is None else self.cm.force_area(
            float(self.b.force), self.b.ap, nodes=settings.force_feed_nodes, feed_floor_m=self.b.fz[0])

    def area(self, ap):
        """The largest chip area ``ap fz`` with the peak force within the limit
        (:meth:`CutModel.force_area`) at depths ``ap`` (NumPy array or CasADi symbol), m^2."""
        if isinstance(ap, (ca.MX, ca.SX)):
            return self.force_area(ap)
        u, inv = np.unique(np.asarray(ap, dtype=float), return_inverse=True)
        return np.asarray(self.force_area.map(u.size)(u[None, :])).ravel()[inv].reshape(np.shape(ap))

    # ---- surface error on the wall ----------------------------------------------------------------
    def wall_start(self, n_harm: int, x, factor: float) -> list[float]:
        """Height fractions to bound first: the local maxima of ``|SLE|`` at ``x`` above half the
        limit, largest first (at least the largest)."""
        fn = self.cm.wall_profile(x, n_harm)
        s = np.linspace(0.0, 1.0, wall_points(n_harm, self.cm.teeth * self.cm.kappa, float(x[1])))
        v = np.abs(fn(s))
        peaks = local_maxima(v)
        high = [float(s[k]) for k in peaks if v[k] >= 0.5 * factor * self.b.sle]
        return (high or [float(s[peaks[0]])])[: _WALL_SLOTS[-1] // 2]

    def seed_fractions(self, pocket: Pocket, n_harm: int, ap_max: float) -> np.ndarray:
        """Height fractions of the start grid: four per turn, over the deepest cut, of the harmonic
        that meets the highest mode along the wall's normal at the pocket's lowest speed."""
        f_tooth = self.cm.teeth * pocket.rpm_lo / 60.0
        h = max(1.0, float(np.max(self.cm.wall_modes_hz, initial=0.0)) / f_tooth)
        turns = h * self.cm.teeth * self.cm.kappa * ap_max / TWO_PI
        return np.linspace(0.0, 1.0, int(np.clip(np.ceil(4 * turns) + 1, 5, 33)))

    # ---- constraints and start points -------------------------------------------------------------
    def masks(self, pocket: Pocket, rpm, ap, fz, factors, sle_worst=None) -> dict[str, np.ndarray]:
        """Which constraints hold at points ``(rpm, ap, fz)`` (arrays of one shape), as the NLP sees
        them (back-off factors included); ``sle_worst``: the largest ``|SLE|`` on the wall there."""
        b = self.b
        rpm, ap, fz = (np.asarray(v, dtype=float) for v in np.broadcast_arrays(rpm, ap, fz))
        out = {"stability": ap <= factors["stability"] * b.margin * pocket.limit(rpm)}
        if b.sle is not None:
            out["surface_error"] = np.asarray(sle_worst) <= factors["surface_error"] * b.sle
        if b.force is not None:
            out["force"] = ap * fz <= factors["force"] * self.area(ap)
        if b.torque is not None:
            out["torque"] = self.cm.mean_torque(ap, fz) <= factors["torque"] * b.torque
        if b.power is not None:
            out["power"] = self.cm.power(rpm, ap, fz) <= factors["power"] * b.power
        return out

    def seed(self, pocket: Pocket, n_harm: int, factors):
        """Best point of a pocket's start grid (or the least violating one) and the constraint masks.

        Speeds at Chebyshev points of the pocket (its ends included), depths geometric from the
        lowest depth up to the stability cap at each speed, feeds evenly spaced; the surface error
        at :meth:`seed_fractions` of each depth. Because ``|SLE| <= tol`` can hold only in thin
        bands of depth (with a helix the force harmonics cancel near multiples of the axial
        pitch), the crossings in depth of the band edges (``max |SLE|`` at ``0.999 tol``) and of
        ``0``, ``+-0.999 tol`` by the SLE at the tip and at the top of the wall, at every speed
        and feed, are extra depths.
        """
        s, b = self.settings, self.b
        x = np.cos(np.pi * np.arange(s.seed_speeds) / (s.seed_speeds - 1))[::-1]
        rpm = np.clip(0.5 * (pocket.rpm_lo + pocket.rpm_hi) + 0.5 * (pocket.rpm_hi - pocket.rpm_lo) * x,
                      pocket.rpm_lo, pocket.rpm_hi)
        cap = np.clip(factors["stability"] * b.margin * pocket.limit(rpm), b.ap[0], b.ap[1])
        t = np.linspace(0.0, 1.0, s.seed_depths)
        ap = b.ap[0] * (cap[:, None] / b.ap[0]) ** t[None, :]  # (I, J)
        fz = np.array(b.fz[:1]) if self.fixed_feed else np.linspace(b.fz[0], b.fz[1], s.seed_feeds)
        shape = ap.shape + (fz.size,)
        pts = [np.broadcast_to(rpm[:, None, None], shape).ravel(), np.broadcast_to(ap[..., None], shape).ravel(),
               np.broadcast_to(fz, shape).ravel()]
        worst = None
        if b.sle is not None:
            frac = self.seed_fractions(pocket, n_harm, float(cap.max()))
            s_c, s_e = self.cm.wall_parts(rpm, ap, frac, n_harm)  # (I, J, Z)
            sle = fz * s_c[..., None] + s_e[..., None]  # (I, J, Z, K)
            big = np.max(np.abs(sle), axis=2)  # (I, J, K)
            tol = 0.999 * factors["surface_error"] * b.sle
            xs = [[], [], []]
            for g0, level in [(big, tol)] + [(sle[:, :, z], v) for z in (0, -1) for v in (-tol, 0.0, tol)]:
                g = g0 - level
                i, j, k = np.nonzero(np.sign(g[:, :-1]) * np.sign(g[:, 1:]) < 0)
                w = g[i, j, k] / (g[i, j, k] - g[i, j + 1, k])
                xs[0].append(rpm[i])
                xs[1].append(ap[i, j] + w * (ap[i, j + 1] - ap[i, j]))
                xs[2].append(fz[k])
            xs = [np.concatenate(v) for v in xs]
            worst = big.ravel()
            if xs[0].size:
                xc, xe = self.cm.wall_parts(xs[0], xs[1][:, None], frac, n_harm)  # (P, 1, Z)
                worst = np.concatenate([worst, np.max(np.abs(xs[2][:, None] * xc[:, 0] + xe[:, 0]), axis=1)])
                pts = [np.concatenate([p, v]) for p, v in zip(pts, xs)]
        masks = self.masks(pocket, *pts, factors, sle_worst=worst)
        ok = np.logical_and.reduce(list(masks.values()))
        mrr = pts[0] * pts[1] * pts[2]
        if ok.any():
            idx = int(np.argmax(np.where(ok, mrr, -np.inf)))
        else:  # the point meeting most constraints, then the smallest removal rate
            idx = int(np.argmax(sum(m.astype(int) for m in masks.values()) - mrr / mrr.max()))
        return np.array([pts[0][idx], pts[1][idx], pts[2][idx]]), bool(ok.any()), masks

    # ---- the NLP ---------------------------------------------------------------------------------
    def harmonics(self, pocket: Pocket) -> int:
        """Harmonics for a pocket: the default at its lowest speed, rounded up to a short ladder so
        that few NLPs are built (more harmonics only add accuracy)."""
        need = self.cm.harmonics_at(pocket.rpm_lo)
        return int(next((h for h in _HARMONIC_LADDER if h >= need), need))

    def nlp(self, n_harm: int, slots: int = 1) -> _NLP:
        """The pocket NLP with ``n_harm`` harmonics and ``slots`` heights on the wall, built once;
        the pocket is a set of parameters.

        Scaled variables ``rpm / 1e4``, ``ap / 1 mm``, ``fz / 0.1 mm``; parameters: the pocket's
        speed interval, the Chebyshev coefficients of its limit depth (zero-padded), the back-off
        factor of each process constraint, and the heights on the wall at which ``|SLE|`` is
        bounded (fractions of the depth) with a switch each (1: bounded, 0: a free slot).
        Objective: ``-MRR`` scaled to order one.
        """
        if (n_harm, slots) in self._nlps:
            return self._nlps[n_harm, slots]
        b, s = self.b, self.settings
        opti = ca.Opti()
        xn, xa, xf = opti.variable(), opti.variable(), opti.variable()
        rpm_lo, rpm_hi = opti.parameter(), opti.parameter()
        coef = opti.parameter(_MAX_COEFFS)
        fac = opti.parameter(len(_PROCESS))
        frac, on = opti.parameter(slots), opti.parameter(slots)
        factor = dict(zip(_PROCESS, ca.vertsplit(fac)))
        rpm, ap, fz = RPM_SCALE * xn, DEPTH_SCALE * xa, FEED_SCALE * xf
        opti.subject_to(opti.bounded(rpm_lo / RPM_SCALE, xn, rpm_hi / RPM_SCALE))
        opti.subject_to(opti.bounded(b.ap[0] / DEPTH_SCALE, xa, b.ap[1] / DEPTH_SCALE))
        if self.fixed_feed:
            opti.subject_to(xf == b.fz[0] / FEED_SCALE)
        else:
            opti.subject_to(opti.bounded(b.fz[0] / FEED_SCALE, xf, b.fz[1] / FEED_SCALE))
        x_cheb = (2.0 * rpm - (rpm_lo + rpm_hi)) / (rpm_hi - rpm_lo)
        limit = cheb_eval(ca.vertsplit(coef), x_cheb)
        opti.subject_to(xa <= factor["stability"] * b.margin * limit / DEPTH_SCALE)
        if b.sle is not None:
            s_c, s_e = self.cm.wall_function(n_harm, slots)(rpm, ap, frac)
            opti.subject_to(opti.bounded(-1.0, on * (fz * s_c + s_e) / (factor["surface_error"] * b.sle), 1.0))
        if b.force is not None:
            opti.subject_to(xa * xf <= factor["force"] * self.area(ap) / (DEPTH_SCALE * FEED_SCALE))
        if b.torque is not None:
            opti.subject_to(self.cm.mean_torque(ap, fz) / (factor["torque"] * b.torque) <= 1.0)
        if b.power is not None:
            opti.subject_to(self.cm.power(rpm, ap, fz) / (factor["power"] * b.power) <= 1.0)
        scale = (b.rpm[1] / RPM_SCALE) * (b.ap[1] / DEPTH_SCALE) * (b.fz[1] / FEED_SCALE)
        opti.minimize(-xn * xa * xf / scale)
        # mu_init: every solve starts from the best point of a seed grid, close to an optimum
        opti.solver("ipopt", {"print_time": False, "expand": True},
                    {"print_level": 0, "sb": "yes", "max_iter": s.max_iter, "mu_init": 1e-3})
        nlp = _NLP(opti, (xn, xa, xf), (rpm_lo, rpm_hi, coef, fac, frac, on))
        self._nlps[n_harm, slots] = nlp
        return nlp

    def surrogate_ok(self, pocket, n_harm, x, factors, rtol=1e-6, *, wall=None) -> bool:
        """Whether ``x`` meets the pocket's constraints (as the NLP sees them, the surface error on
        the whole wall; ``wall``: its largest ``|SLE|`` at ``x`` if known) to ``rtol``."""
        if self.b.sle is not None and wall is None:
            wall = self.cm.wall_max(x, n_harm)[0]
        m = self.masks(pocket, np.array([x[0]]), np.array([x[1] * (1 - rtol)]), np.array([x[2]]),
                       {k: v * (1 + rtol) for k, v in factors.items()}, sle_worst=wall)
        return all(bool(v.all()) for v in m.values())

    def _ipopt(self, nlp: _NLP, pocket: Pocket, factors, heights, start):
        """IPOPT on ``pocket`` from ``start``, then once more from its last iterate if it stopped
        short. Returns (answer, status)."""
        opti, (xn, xa, xf) = nlp.opti, nlp.x
        p_lo, p_hi, p_coef, p_fac, p_frac, p_on = nlp.p
        slots = p_frac.shape[0]
        opti.set_value(p_lo, pocket.rpm_lo)
        opti.set_value(p_hi, pocket.rpm_hi)
        opti.set_value(p_coef, np.pad(pocket.coeffs, (0, _MAX_COEFFS - pocket.coeffs.size)))
        opti.set_value(p_fac, [factors[k] for k in _PROCESS])
        opti.set_value(p_frac, np.pad(np.asarray(heights, dtype=float), (0, slots - len(heights))))
        opti.set_value(p_on, [1.0] * len(heights) + [0.0] * (slots - len(heights)))
        for _ in range(2):
            opti.set_initial(xn, start[0] / RPM_SCALE)
            opti.set_initial(xa, start[1] / DEPTH_SCALE)
            opti.set_initial(xf, start[2] / FEED_SCALE)
            try:
                sol = opti.solve()
                x = np.array([sol.value(xn) * RPM_SCALE, sol.value(xa) * DEPTH_SCALE, sol.value(xf) * FEED_SCALE])
            except RuntimeError:  # not converged: the last iterate, judged by the caller
                x = np.array([opti.debug.value(xn) * RPM_SCALE, opti.debug.value(xa) * DEPTH_SCALE,
                              opti.debug.value(xf) * FEED_SCALE])
            status = str(opti.stats().get("return_status", "unknown"))
            if status in _CONVERGED or not np.all(np.isfinite(x)):
                break
            start = x
        return x, status

    def solve_pocket(self, pocket: Pocket, factors):
        """Seed grid, then IPOPT from its best point; with a surface-error limit, an exchange: the
        height of the largest ``|SLE|`` on the wall at the answer is bounded too and the NLP solved
        again, until none exceeds the limit. Returns (seed, answer, feasible, status, masks)."""
        n_harm = self.harmonics(pocket)
        seed, seed_ok, masks = self.seed(pocket, n_harm, factors)
        limits = [pocket.rpm_lo, self.b.ap[0], self.b.fz[0]], [pocket.rpm_hi, self.b.ap[1], self.b.fz[1]]
        heights = [] if self.b.sle is None else self.wall_start(n_harm, seed, factors["surface_error"])
        start, wall = seed, None
        while True:
            slots = next(k for k in _WALL_SLOTS if k >= len(heights))
            x, status = self._ipopt(self.nlp(n_harm, slots), pocket, factors, heights, start)
            if self.b.sle is None or not np.all(np.isfinite(x)):
                break
            wall, at = self.cm.wall_max(np.clip(x, *limits), n_harm)
            if wall <= factors["surface_error"] * self.b.sle * (1 + _WALL_RTOL) or len(heights) == _WALL_SLOTS[-1]:
                break
            heights.append(at)
            start = x
        x = np.clip(x, *limits)
        ok = bool(np.all(np.isfinite(x))) and self.surrogate_ok(pocket, n_harm, x, factors, wall=wall)
        # never worse than the seed grid (a start point on the optimum, e.g. at a corner of the
        # bounds, comes back from IPOPT within its tolerance, ~1e-8: that is the NLP's answer)
        if (seed_ok and (not ok or np.prod(x) < (1 - _SEED_RTOL) * np.prod(seed))
                and self.surrogate_ok(pocket, n_harm, seed, factors)):
            x, ok, status = seed, True, _START_KEPT
        return seed, x, ok, status, masks

    # ---- re-check ---------------------------------------------------------------------------------
    def ratios(self, point: OperatingPoint) -> dict[str, float]:
        """Value / limit of every process constraint at a predicted point (> 1: violated); the
        surface error on the whole wall (:func:`wall_error`)."""
        b = self.b
        stab = point.axial_depth_m / (b.margin * point.depth_limit_m)
        # unstable at a depth below the limit found (SDM: several crossings; ZOA: exactly at it)
        out = {"stability": stab if point.stable else max(stab, 1.0 + 10 * self.settings.recheck_rtol)}
        if b.sle is not None:
            out["surface_error"] = wall_error(point, self.setup.tool, self.setup.cut)[0] / b.sle
        if b.force is not None:
            out["force"] = point.peak_force_N / b.force
        if b.torque is not None:
            out["torque"] = point.mean_torque_N_m / b.torque
        if b.power is not None:
            out["power"] = point.power_W / b.power
        return out


def _mrr(setup, x) -> float:
    return float(x[1] * setup.cut.radial_depth_m * x[2] * setup.tool.teeth * x[0] / 60.0)


def _diagnose(masks_all: list[dict[str, np.ndarray]]) -> str | None:
    """Name the constraint (or pair) that no grid point meets; None if the grid has a feasible point."""
    names = [n for n in _PROCESS if any(n in m for m in masks_all)]
    for n in names:
        if not any(m[n].any() for m in masks_all if n in m):
            return n
    for a, c in combinations(names, 2):
        if not any((m[a] & m[c]).any() for m in masks_all if a in m and c in m):
            return f"{a}+{c}"
    return None


def _refine_sdm(prob, pockets, results, samples, sdm_limit, setup, settings: PlanSettings) -> None:
    """Local refinement of the sampled SDM limit around the best pockets' answers (in place).

    Between samples the limit is a PCHIP interpolant, cautious on the flanks of a cusp, where
    optima sit. Each round adds the SDM limit at the answer and a quarter of the local sample
    spacing on either side, rebuilds those pockets' series and solves them again.
    """
    ones = {k: 1.0 for k in _PROCESS}
    for _ in range(settings.sdm_refine_rounds):
        mrr = np.array([r.mrr_m3_s if r.feasible else -np.inf for r in results])
        if not np.isfinite(mrr).any():
            return
        todo = np.flatnonzero(mrr >= (1.0 - settings.sdm_refine_within) * mrr.max())
        rr, dd = samples
        new = []
        for i in todo:
            n = results[i].solution[0]
            j = np.searchsorted(rr, n)
            gap = rr[min(j, rr.size - 1)] - rr[max(j - 1, 0)]
            h = 0.25 * max(gap, 1e-6 * n)
            new.append(np.clip([n - h, n, n + h], pockets[i].rpm_lo, pockets[i].rpm_hi))
        r_new = np.setdiff1d(np.unique(np.concatenate(new)), rr)
        if r_new.size == 0:
            return
        rr = np.concatenate([rr, r_new])
        dd = np.concatenate([dd, np.where(np.isfinite(d := sdm_limit(r_new)), d, 1.0)])
        order = np.argsort(rr)
        samples[0], samples[1] = rr[order], dd[order]
        pchip = PchipInterpolator(samples[0], samples[1])
        for i in todo:
            p = pockets[i]
            pockets[i] = build_pockets(np.array([p.rpm_lo, p.rpm_hi]), pchip, settings, sampled=True,
                                        merge=False)[0]
            seed, x, ok, status, _ = prob.solve_pocket(pockets[i], ones)
            results[i] = replace(results[i], start=_ro(seed), solution=_ro(x),
                                 mrr_m3_s=_mrr(setup, x) if ok else np.nan, solver_status=status, feasible=ok)


def plan(setup, structure, *, method: Method = "auto", settings: PlanSettings | None = None,
         stability_limit=None) -> Plan:
    """Spindle speed, axial depth and feed per tooth with the largest removal rate.

    Parameters
    ----------
    setup : stability.setup.Setup
        Tool, cut (radial depth, milling, frame; the cut's feed is used when the limits give no feed
        range), material with cutting coefficients, and limits: ``spindle_rpm`` and
        ``axial_depth_m`` ranges are required; every other limit is optional (absent: not
        constrained; no stability margin: 1).
    structure : ModalModel or control.StateSpace
        Tool-tip dynamics, machine frame (the surface-error model needs modes).
    method : {'auto', 'zoa', 'sdm'}
        Stability model; ``'auto'`` takes the SDM below ``settings.sdm_below_immersion`` radial
        immersion, the ZOA otherwise.
    settings : PlanSettings, optional
    stability_limit : callable, optional
        ``rpm_array -> depth_array``, m: a limit to plan against instead of the model's, e.g. the
        depth stable with a stated probability under a learned posterior (the chance constraint,
        :class:`planner.learn.predictive.ChanceLimit`). The margin factor is then not applied
        (the limit carries its own safety); the re-check takes its limit from it too.

    Returns
    -------
    Plan
        ``success`` only when the optimum passed the re-check by
        :func:`stability.lobes.predict_point`.

    Raises
    ------
    SetupError
        No cutting coefficients, or no speed or depth range in the limits.
    ValueError
        An unknown method, or a structure without modes (a measured FRF table).

    References
    ----------
    Altintas & Budak, CIRP Annals 44(1), 1995 (ZOA); Insperger & Stepan, Int. J. Numer. Meth. Eng.
    61, 2004 (SDM); Schmitz & Mann, IJMTM 46, 2006 (surface location error).
    """
    t0 = time.perf_counter()
    if method not in ("auto", "zoa", "sdm"):
        raise ValueError(f"method must be one of 'auto', 'zoa', 'sdm', found {method!r}")
    settings = settings or PlanSettings()
    if hasattr(structure, "freq_hz") and not hasattr(structure, "natural_frequency_hz"):
        raise ValueError("plan needs a modal model: the surface-error model of the NLP is analytic in "
                         "speed; fit a modal model to the measured FRF first")
    if stability_limit is not None:  # a chance constraint replaces the margin factor
        setup = replace(setup, limits=replace(setup.limits, stability_margin=None))
    model = as_modal_model(structure)
    prob = _Problem(setup, model, settings)
    tool, cut, coef, b = setup.tool, setup.cut, setup.material.cutting_coefficients, prob.b
    if method == "auto":
        method = "sdm" if cut.radial_depth_m / tool.diameter_m < settings.sdm_below_immersion else "zoa"
    if stability_limit is not None:
        diagram, pockets, samples, sdm_limit = sampled_pockets(stability_limit, method, b.rpm, settings)
    elif method == "zoa":
        diagram, pockets = zoa_pockets(model, setup, b.rpm, settings)
    else:
        diagram, pockets, samples, sdm_limit = sdm_pockets(model, setup, b.rpm, settings)
    log.info("%d pockets (%s)", len(pockets), method)

    ones = {k: 1.0 for k in _PROCESS}
    results, masks_all = [], []
    for p in pockets:
        seed, x, ok, status, masks = prob.solve_pocket(p, ones)
        masks_all.append(masks)
        results.append(PocketResult((p.rpm_lo, p.rpm_hi), p.kind, _ro(seed), _ro(x),
                                    _mrr(setup, x) if ok else np.nan, status, ok))
    if method == "sdm" or stability_limit is not None:
        _refine_sdm(prob, pockets, results, samples, sdm_limit, setup, settings)

    def predict(x):
        point = predict_point(model, tool, replace(cut, feed_per_tooth_m=float(x[2])), coef,
                              spindle_rpm=float(x[0]), axial_depth_m=float(x[1]),
                              method="zoa" if stability_limit is not None else method,
                              rtol=settings.sdm_rtol, n_freq=settings.n_freq)
        if stability_limit is not None:  # stability re-checked against the given limit
            lim = float(np.asarray(stability_limit(np.array([float(x[0])])))[0])
            point = replace(point, depth_limit_m=lim, stable=bool(float(x[1]) < lim))
        return point

    best, point = _verify(prob, pockets, results, predict, setup, settings)
    common = dict(method=method, stability_margin=b.margin, pockets=tuple(results), diagram=diagram,
                  elapsed_s=time.perf_counter() - t0)
    if best is None:
        culprit = _diagnose(masks_all)
        if culprit is not None:
            msg, status = f"infeasible: {culprit.replace('+', ' and ')} cannot be met within the bounds", "infeasible"
        else:
            tried = [r for r in results if r.verified is False]
            msg = (f"no answer passed the re-check ({len(tried)} pockets tried)" if tried
                   else "the NLP found no feasible point")
            status = "unverified" if tried else "infeasible"
        return Plan(False, status, msg, spindle_rpm=None, axial_depth_m=None, feed_per_tooth_m=None,
                    mrr_m3_s=None, active_constraints=(), infeasible_constraint=culprit, point=None, **common)
    x = results[best].solution
    active = _active(prob, point, x)
    wall_m, wall_height_m = wall_extremum(point, tool, cut)  # where |SLE| on the finished wall is largest
    height = wall_height_m if "surface_error" in active else None  # where the wall binds
    names = [f"surface_error at z = {height * 1e3:.3g} mm" if a == "surface_error" else a for a in active]
    msg = (f"{x[0]:.0f} rpm, depth {x[1] * 1e3:.3g} mm, feed {x[2] * 1e3:.3g} mm/tooth: "
           f"{_mrr(setup, x) * 1e6:.4g} cm^3/s; active: {', '.join(names) or 'none'}")
    status = results[best].solver_status
    converged = status in _CONVERGED and bool(active)
    if status == _START_KEPT:
        msg = f"the NLP found nothing better than its start grid; best verified point {msg}"
    elif status not in _CONVERGED:
        msg = f"IPOPT did not converge ({status}); best verified point {msg}"
    elif not active:  # the removal rate grows with speed, depth and feed: an optimum is on a constraint
        msg = f"no constraint binds, so this is no optimum; best verified point {msg}"
    return Plan(converged, "optimal" if converged else "not_converged", msg, spindle_rpm=float(x[0]),
                axial_depth_m=float(x[1]), feed_per_tooth_m=float(x[2]), mrr_m3_s=_mrr(setup, x),
                active_constraints=active, infeasible_constraint=None, point=point,
                surface_error_height_m=height, surface_error_max_m=wall_m,
                surface_error_max_height_m=wall_height_m, **common)


def _verify(prob: _Problem, pockets, results, predict, setup, settings: PlanSettings):
    """Re-check the pocket answers with ``predict`` (best first, in place) until the best verified
    one beats every answer not yet checked; a violated constraint is tightened in that pocket by
    the measured ratio and the pocket solved again. Returns (index or None, OperatingPoint)."""
    factors = [{k: 1.0 for k in _PROCESS} for _ in pockets]
    best, best_point = None, None
    tol = 1.0 + settings.recheck_rtol
    while True:
        open_ = [i for i, r in enumerate(results) if r.feasible and r.verified is None]
        if not open_:
            break
        i = max(open_, key=lambda k: results[k].mrr_m3_s)
        if best is not None and results[i].mrr_m3_s <= results[best].mrr_m3_s:
            break
        r = results[i]
        for attempt in range(settings.max_backoffs + 1):
            point = predict(r.solution)
            bad = {k: v for k, v in prob.ratios(point).items() if not v <= tol}
            if not bad:
                results[i] = replace(r, verified=True, backoffs=attempt)
                if best is None or results[i].mrr_m3_s > results[best].mrr_m3_s:
                    best, best_point = i, point
                break
            if attempt == settings.max_backoffs:
                results[i] = replace(r, verified=False, backoffs=attempt)
                break
            for k, v in bad.items():
                factors[i][k] *= (1.0 - settings.backoff_slack) / v
            log.info("pocket %.0f-%.0f rpm: re-check violated %s; re-solving", *r.rpm_range, sorted(bad))
            _, x, ok, status, _ = prob.solve_pocket(pockets[i], factors[i])
            r = replace(r, solution=_ro(x), mrr_m3_s=_mrr(setup, x) if ok else np.nan, solver_status=status,
                        feasible=ok)
            if not ok:
                results[i] = replace(r, verified=False, backoffs=attempt + 1)
                break
    return best, best_point


# Relative distance to a limit within which a constraint is reported active: the back-off leaves a
# re-checked constraint up to ~max_backoffs * backoff_slack below its limit.
_ACTIVE_RTOL = 5e-3
# Relative distance to a bound within which it is active (IPOPT stops within ~1e-8 of a bound).
_BOUND_RTOL = 1e-6


def _active(prob: _Problem, point: OperatingPoint, x) -> tuple[str, ...]:
    """Constraints within ``_ACTIVE_RTOL`` of their limit by the re-check, bounds within
    ``_BOUND_RTOL``, in the order of :data:`CONSTRAINTS`."""
    b = prob.b
    active = {k for k, v in prob.ratios(point).items() if v >= 1.0 - _ACTIVE_RTOL}
    for name, value, (low, high) in (("rpm", x[0], b.rpm), ("depth", x[1], b.ap), ("feed", x[2], b.fz)):
        if high <= low:  # a fixed value (no range given) is no active choice
            continue
        if value <= low * (1 + _BOUND_RTOL):
            active.add(f"{name}_min")
        if value >= high * (1 - _BOUND_RTOL):
            active.add(f"{name}_max")
    return tuple(c for c in CONSTRAINTS if c in active)
