"""Which speeds a learned limit is needed at: where a cut could beat the best plan found.

Any cut the setup allows at spindle speed ``n`` removes at most

    MRR_max(n) = ap_max * ae * fz_max * teeth * n / 60

(``ap_max`` the top of ``limits.axial_depth_m``, ``ae`` the cut's radial depth, ``fz_max`` the top
of ``limits.feed_per_tooth_m`` or else the cut's feed: the bounds of :func:`planner.optimize.plan`;
stability, power, torque, force and the surface error only lower it). So once a plan removing
``MRR*`` is found, no speed below ``n* = 60 MRR* / (ap_max ae fz_max teeth)`` can hold a better
one, whatever the limit there. The chance limit's table is what costs at low speeds: the SDM
takes ~20 steps per period of the mode, so a tooth period costs ``f_mode / f_tooth`` times that
(at 500 rpm with 2 teeth and a 720 Hz mode, 43 mode periods per tooth period), and over the kr500
example's 500-24 000 rpm almost all of a 20-minute table was below 10 000 rpm. The table is
therefore built from the top speed down: over the top octave first (``first_ratio``), a plan on
it gives ``MRR*``, and the table is extended downward until it holds every speed at which
``plan`` over the setup's whole range reads the limit for a pocket that reaches above ``n*``
(:func:`_lowest_speed_read`); the plan is made again whenever an extension changed the limit
(its table check covers the new range). Below the tabulated range no depth is certified
(:class:`ChanceLimit`: 1 nm), so ``plan`` over the whole range finds nothing there, and above it
the same samples, cusps and pockets as with the whole table wherever a better cut could lie.

``learn --suggest`` (``mrr``) uses the same bound for its lobes (:func:`lobes_for_improvement`):
a test cut whose ``ap * rpm`` cannot exceed the incumbent has no expected improvement.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace

import numpy as np

from .posterior import Posterior
from .predictive import ChanceLimit, ProbabilityLobes, _table, lobes_from_table

__all__ = ["SpeedRange", "mrr_per_rpm", "chance_limit_for_plan", "lobes_for_improvement"]

log = logging.getLogger(__name__)

#: The plan over the whole range may remove up to this share less than the plan that set the
#: bound (its samples of the limit are coarser than over the part): the bound's speed is lowered
#: by it, so that a cut below the tabulated range is beaten by the final plan too.
BOUND_SLACK = 0.02


def mrr_per_rpm(setup) -> float:
    """The largest removal rate any cut the setup allows can reach per rpm of spindle speed,
    ``ap_max ae fz_max teeth / 60`` (m^3/s per rpm; module notes)."""
    from planner.plan_results import plan_bounds

    b = plan_bounds(setup)
    return float(b.ap[1] * setup.cut.radial_depth_m * b.fz[1] * setup.tool.teeth / 60.0)


@dataclass(frozen=True)
class SpeedRange:
    """The speeds a learned limit (a chance limit, or lobes) was tabulated at, and why no others
    were needed.

    Attributes
    ----------
    rpm_range : (float, float)
        The tabulated range, rpm.
    setup_rpm : (float, float)
        The setup's speed range, rpm.
    best_mrr_m3_s : float
        The removal rate of the best plan found on the way (0: none made), or of the incumbent
        test cut, m^3/s.
    below_mrr_m3_s : float
        The most any cut the setup allows below ``rpm_range[0]`` can remove, m^3/s.
    plans, tables : int
        Plans made to find the range, and tables built (the first and each extension).
    timings_s : dict
        Wall time of the tables (new speeds only), their checks and the plans, s.
    bound_by, best_is : str
        What bounds the removal rate below, and what ``best_mrr_m3_s`` is (for :meth:`note`).
    """

    rpm_range: tuple[float, float]
    setup_rpm: tuple[float, float]
    best_mrr_m3_s: float
    below_mrr_m3_s: float
    plans: int
    tables: int
    timings_s: dict
    bound_by: str = "the largest depth and feed"
    best_is: str = "the plan found above"

    @property
    def restricted(self) -> bool:
        return self.rpm_range[0] > self.setup_rpm[0] * (1 + 1e-12)

    def note(self) -> str:
        if not self.restricted:
            return "the whole speed range tabulated"
        return (f"speeds below {self.rpm_range[0]:.0f} rpm not tabulated: no cut there can remove more than "
                f"{1e6 * self.below_mrr_m3_s:.4g} cm^3/s ({self.bound_by}), less than {self.best_is} "
                f"({1e6 * self.best_mrr_m3_s:.4g} cm^3/s)")

    def to_dict(self) -> dict:
        return {"rpm_range": list(self.rpm_range), "rpm_range_note": self.note(),
                "rpm_range_best_mrr_m3_s": self.best_mrr_m3_s, "rpm_range_below_mrr_m3_s": self.below_mrr_m3_s,
                "rpm_range_plans": self.plans, "timings_s": dict(self.timings_s)}


def chance_limit_for_plan(posterior: Posterior, structure, setup, *, probability: float = 0.95, settings=None,
                          first_ratio: float = 2.0, step_ratio: float = 1.25,
                          **limit_options) -> tuple[ChanceLimit, SpeedRange]:
    """The chance limit for :func:`planner.optimize.plan` of ``setup``, tabulated only where a cut
    could beat the best plan (module notes).

    Parameters
    ----------
    posterior : Posterior
    structure : ModalModel
        The structure ``plan`` is given (its surface-error and force models).
    setup : stability.setup.Setup
        With ``limits.spindle_rpm`` and ``limits.axial_depth_m`` (as ``plan`` requires).
    probability : float
    settings : planner.plan_results.PlanSettings, optional
        Those of the final ``plan`` (its speed samples locate the pockets; default as ``plan``).
    first_ratio : float
        The first table spans ``[hi / first_ratio, hi]`` (the whole range when narrower).
    step_ratio : float
        An extension reaches this factor below the speed that had to be covered.
    **limit_options
        Passed to :class:`ChanceLimit` (``method``, ``max_samples``, ``check``, ``check_speeds``).

    Returns
    -------
    limit : ChanceLimit
        Over :attr:`SpeedRange.rpm_range`; no depth (1 nm) below it.
    speeds : SpeedRange
    """
    from planner.optimize import plan
    from planner.plan_results import PlanSettings

    if not (first_ratio > 1 and step_ratio > 1):
        raise ValueError(f"first_ratio and step_ratio must be > 1, found {first_ratio}, {step_ratio}")
    settings = settings or PlanSettings()
    per_rpm = mrr_per_rpm(setup)
    lo, hi = (float(v) for v in setup.limits.spindle_rpm)
    tab_lo = max(lo, hi / first_ratio)
    limit, width, best, plans, tables = None, None, 0.0, 0, 0
    timings = {"tables": 0.0, "checks": 0.0, "plans": 0.0}
    while True:
        limit = ChanceLimit(posterior, setup, (tab_lo, hi), probability=probability, known=limit, **limit_options)
        tables += 1
        timings["tables"] += limit.timings_s["table"]
        timings["checks"] += limit.timings_s["check"]
        if tab_lo <= lo:
            break
        if limit.boundary_width != width:  # the first table, or a check that changed the limit: plan again
            t0 = time.perf_counter()
            part = replace(setup, limits=replace(setup.limits, spindle_rpm=(tab_lo, hi)))
            result = plan(part, structure, settings=settings, stability_limit=limit)
            timings["plans"] += time.perf_counter() - t0
            plans, width = plans + 1, limit.boundary_width
            best = float(result.mrr_m3_s) if result.mrr_m3_s is not None else 0.0  # a verified cut
        floor = (1.0 - BOUND_SLACK) * best / per_rpm  # no cut below removes as much
        need = _lowest_speed_read(limit, (lo, hi), floor, settings) if floor > lo else lo
        log.info("table %.0f-%.0f rpm: best %.4g m^3/s, none better below %.0f rpm, needed from %s rpm",
                 tab_lo, hi, best, floor, need)
        if need is not None and need >= tab_lo:
            break
        tab_lo = max(lo, min(tab_lo, floor) / step_ratio)
    return limit, SpeedRange(rpm_range=limit.rpm_range, setup_rpm=(lo, hi), best_mrr_m3_s=best,
                             below_mrr_m3_s=per_rpm * limit.rpm_range[0], plans=plans, tables=tables,
                             timings_s=timings)


def _lowest_speed_read(limit: ChanceLimit, setup_rpm, floor_rpm: float, settings) -> float | None:
    """The lowest speed whose limit ``plan`` over ``setup_rpm`` reads for a pocket that may reach
    above ``floor_rpm``; None when that is below the limit's tabulated range.

    ``plan`` samples a given limit at ``settings.n_rpm_sdm`` speeds over its range
    (:func:`planner.pockets.sampled_pockets`) and breaks it into pockets at the cusps (local
    maxima of the samples, each refined between its neighbours); a pocket's limit is the PCHIP
    of the samples (each piece reads two neighbours each side), and runs of narrow pockets are
    merged. So every pocket from the highest cusp at or below ``floor_rpm`` whose pocket above is
    not narrow (no run crosses it) is built exactly as over the whole table when the samples from
    three below that cusp up are tabulated; pockets below it remove less than the plan.
    """
    lo, hi = setup_rpm
    r = np.linspace(lo, hi, settings.n_rpm_sdm)
    tab = r >= limit.rpm_range[0]
    d = np.zeros(r.size)
    d[tab] = limit(r[tab])
    peak = np.flatnonzero((d[1:-1] > d[:-2]) & (d[1:-1] >= d[2:])) + 1
    above = np.r_[peak[1:], r.size - 1]  # the next cusp up (or the range's end)
    for p, q in zip(peak[::-1], above[::-1]):
        if r[p + 1] > floor_rpm:
            continue
        if p < 3 or not tab[p - 3]:
            return None
        # the pocket above, at its narrowest (each cusp lies within a sample of its peak)
        a, b = r[p + 1], r[q] if q == r.size - 1 else r[max(q - 1, p + 1)]
        if (b - a) / (0.5 * (a + b)) >= settings.min_pocket_rel_width:
            return float(r[p - 3])
    return None


def lobes_for_improvement(posterior: Posterior, setup, rpm_range, *, n_rpm: int = 150, method: str | None = None,
                          max_samples: int = 400, confidence: float = 0.95,
                          first_ratio: float = 2.0) -> tuple[ProbabilityLobes, SpeedRange]:
    """The probability lobes of :func:`planner.learn.predictive.probability_lobes` (same speeds,
    samples and table) at the speeds where a test cut can improve the best proven-stable removal
    rate, for ``suggest_cuts(..., criterion='mrr')`` with its default depths and the setup's
    limits (:func:`planner.learn.suggest.allowed_depths`).

    A cut improves only when its ``ap * rpm`` exceeds the incumbent (the best allowed one proven
    stable with ``confidence``): at a speed where the largest allowed depth times the speed does
    not, every cut has zero expected improvement. So the lobes are tabulated from the top down
    (the top ``first_ratio`` of the range first, then down to the lowest speed that could beat
    the incumbent found, until that is tabulated). The suggestions from them are those from the
    whole range, but for the depths considered (from the lobes' quantiles, now over these speeds)
    and for picks without expected improvement (fewer such cuts than asked: over the whole range
    those are at its lowest speeds, and the caller should recompute there). Their table is not
    checked against direct limits (``probability_lobes(..., check=0)``): they carry the error
    ``learn`` measured at its training cuts, and the speeds that can win are the high ones, where
    the table is most accurate (the kr500 example above 16 000 rpm: 0.001 in log).

    Returns
    -------
    lobes : ProbabilityLobes
        At the speeds of ``probability_lobes(posterior, setup, rpm_range, n_rpm=n_rpm)`` from
        ``speeds.rpm_range[0]`` up.
    speeds : SpeedRange
    """
    from .suggest import allowed_depths, best_proven_mrr

    if not first_ratio > 1:
        raise ValueError(f"first_ratio must be > 1, found {first_ratio}")
    lo, hi = float(rpm_range[0]), float(rpm_range[1])
    rpm = np.geomspace(lo, hi, int(n_rpm))  # the speeds of probability_lobes
    post = posterior.thinned(max_samples)
    ae, mill = float(setup.cut.radial_depth_m), setup.cut.milling
    least, most, _ = allowed_depths(setup, rpm, post.reference)
    top = np.where(most >= least, most * rpm, 0.0)  # the largest allowed ap * rpm per speed (inf: no bound)
    tab_lo, table, tables, spent = max(lo, hi / first_ratio), None, 0, 0.0
    while True:
        k = rpm >= tab_lo * (1 - 1e-12)
        t0 = time.perf_counter()
        table = _table(post, setup, rpm[k], np.full(k.sum(), ae), np.full(k.sum(), mill == "down"), method=method,
                       grid=None, known=table, desc="probability lobes: limit table", for_samples=True)
        spent += time.perf_counter() - t0
        tables += 1
        lobes = lobes_from_table(post, table, rpm[k], radial_depth_m=ae, milling=mill)
        incumbent = best_proven_mrr(lobes, allowed_depth_m=(least[k], most[k]), confidence=confidence)
        could = top > incumbent
        if k.all() or not could[~k].any():
            break
        tab_lo = float(rpm[could].min())
        log.info("lobes %.0f-%.0f rpm: a cut at %.0f rpm could beat the incumbent", rpm[k][0], hi, tab_lo)
    per = ae * setup.cut.feed_per_tooth_m * setup.tool.teeth / 60.0  # ap * rpm -> m^3/s
    below = float(top[~k].max()) * per if (~k).any() else 0.0
    return lobes, SpeedRange(rpm_range=(float(rpm[k][0]), hi), setup_rpm=(lo, hi), best_mrr_m3_s=incumbent * per,
                             below_mrr_m3_s=below, plans=0, tables=tables, timings_s={"tables": spent},
                             bound_by="the largest depth the setup allows, at its feed",
                             best_is="the best cut proven stable above")
