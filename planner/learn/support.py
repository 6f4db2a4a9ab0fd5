"""What the test cuts themselves say about a planned cut (``plan`` with a learned posterior).

The chance constraint's P(stable) is the posterior's: the model fitted to the cuts, evaluated at
the plan. Where no test cut was stable at or beyond the plan near its speed, that probability is
the model's extrapolation, and it holds only as far as the model does. A mode the prior lacks is
the case that matters: 30 random cuts are explained as well with it as without it by every
statistic tried, while the 5-95 % band misses the true limit at 12-73 % of the speeds (docs/learn.md,
sessions 15-16). And a chatter mark near the plan at or below its depth and engagement is direct
evidence against the plan, which the posterior may have put down to a wrong mark.

So each marked cut is compared with the plan under the one monotonicity a stability chart has at
a fixed speed and engagement: a cut stable at a depth is stable at any shallower one, and a cut
that chatters chatters at any deeper one (the lowest limit; a stable island above it, which
low-immersion flip lobes can have, is not counted on). Only at the plan's engagement and speed: the
limit is not monotone in the radial depth (the benchmark tool, down milling: at 45 of 60 speeds over
6-24 krpm the limit at 0.5 D is above that at 0.25 D, up to 4.8 times), and it moves with speed,
steeply between lobes, so "near" is within :data:`SPEED_TOLERANCE` and :data:`RADIAL_TOLERANCE`.

- ``backed``: a stable test cut of the plan's milling direction, speed and width, at least as
  deep: the plan has been cut, or something harder at its speed has.
- ``contradicted``: a chatter test cut of the plan's milling direction, speed and width, at most
  as deep: the cuts say the plan chatters, whatever the posterior concluded.
- ``extrapolated``: neither.

Marks only: ``uncertain`` marks (near the boundary by definition) and detected outcomes weighted
under :data:`MIN_WEIGHT` (a detection less sure than not) neither back nor contradict. A stable mark
that the posterior doubts backs nothing either: a chatter cut far above the limit marked stable
would otherwise back any plan below it. The functions' default level is :data:`~.update.SUSPECT_LABEL`
(the ``suspect_labels`` of ``learn``: more likely wrong than right); ``plan`` trusts a mark only as
far as its own level, a probability of being wrong at most ``1 - P`` (0.05 at P >= 0.95: on the
benchmark with a fifth of the marks flipped, the level 0.5 let a flipped mark of probability 0.48
back a cut that chattered). A chatter mark contradicts whatever the posterior thinks of it: that
is the point of the check.

Where the plan is not backed, :func:`best_backed` plans again on the test cuts alone: the largest
removal rate at the speed and up to the depth of a stable test cut (at the plan's engagement), under
every other limit of the setup. It is what the cuts prove, to run while the plan is tried.
"""

from __future__ import annotations

import numpy as np

from .likelihood import CHATTER, STABLE
from .outcomes_io import CutTable
from .update import SUSPECT_LABEL

__all__ = ["plan_support", "support_warning", "best_backed", "describe_best_backed", "doubted_marks", "doubt_level",
           "at_engagement", "SPEED_TOLERANCE", "RADIAL_TOLERANCE", "MIN_WEIGHT"]

#: Largest relative speed difference between a test cut and the plan for the cut to speak for the
#: plan: a test cut of the plan's own speed, typed by hand to two or three significant digits, is
#: within it. A judgement, held narrow because the limit moves with speed: on the benchmark tool
#: (900 Hz, 2 flutes, 0.5 D down, 6-24 krpm) ``|d ln a_lim / d ln n|`` is 6.3 in the median over
#: the speeds, 12 at the 90th percentile and 40 at a lobe's cusp, so a cut 1 % off the plan's
#: speed already sees a limit about 6 % different.
SPEED_TOLERANCE = 0.01
#: Largest relative difference of radial depth between a test cut and the plan (the same stepover,
#: typed to two or three significant digits).
RADIAL_TOLERANCE = 0.02
#: Smallest label weight of a detected outcome that backs or contradicts a plan (a mark weighs 1).
MIN_WEIGHT = 0.5


def doubted_marks(mislabelled, n_cuts: int, max_doubt: float = SUSPECT_LABEL) -> np.ndarray:
    """Mask of the marks whose probability of being wrong (``mislabelled``; NaN or None: not known,
    taken as sure) exceeds ``max_doubt``."""
    if mislabelled is None:
        return np.zeros(n_cuts, dtype=bool)
    return np.nan_to_num(np.asarray(mislabelled, dtype=float)) > max_doubt


def doubt_level(probability: float) -> float:
    """The largest probability of being wrong at which ``plan`` at P(stable) >= ``probability``
    counts a stable mark: ``1 - probability`` (module notes)."""
    return round(1.0 - float(probability), 12)


def describe_best_backed(alt: dict) -> str:
    """One line for :func:`best_backed`'s cut with its ``share_of_plan`` (``plan``'s output, the demo)."""
    return (f"{alt['spindle_rpm']:.0f} rpm, axial depth {1e3 * alt['axial_depth_m']:.2f} mm, feed "
            f"{1e3 * alt['feed_per_tooth_m']:.3f} mm/tooth: MRR {1e6 * alt['mrr_m3_s']:.2f} cm^3/s "
            f"({100 * alt['share_of_plan']:.0f} % of the plan's; cut {alt['backed_by']})")


def at_engagement(cuts: CutTable, radial_depth_m: float, down: bool,
                  radial_tolerance: float = RADIAL_TOLERANCE) -> np.ndarray:
    """Mask of the cuts at an engagement: the milling direction, the radial depth within
    ``radial_tolerance``."""
    ae = np.asarray(cuts.radial_depth_m, dtype=float)
    return ((np.asarray(cuts.down, dtype=bool) == bool(down))
            & (np.abs(ae / float(radial_depth_m) - 1.0) <= radial_tolerance))


def _sure(cuts: CutTable, mislabelled, radial_depth_m: float, down: bool, radial_tolerance: float,
          max_doubt: float = SUSPECT_LABEL) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the sure stable marks (not doubted) and sure chatter marks at the engagement."""
    at = (np.asarray(cuts.weight, dtype=float) >= MIN_WEIGHT) & at_engagement(cuts, radial_depth_m, down,
                                                                               radial_tolerance)
    doubted = doubted_marks(mislabelled, cuts.n_cuts, max_doubt)
    return at & (cuts.outcome == STABLE) & ~doubted, at & (cuts.outcome == CHATTER)


def plan_support(cuts: CutTable, spindle_rpm: float, axial_depth_m: float, radial_depth_m: float,
                 down: bool, *, mislabelled=None, max_doubt: float = SUSPECT_LABEL,
                 speed_tolerance: float = SPEED_TOLERANCE,
                 radial_tolerance: float = RADIAL_TOLERANCE) -> dict:
    """The test cuts that back or contradict a planned cut (module notes).

    ``mislabelled``: the posterior's probability that each mark is wrong (NaN or None: not known);
    a stable mark above ``max_doubt`` backs nothing.

    Returns
    -------
    dict
        ``status`` (``backed``, ``contradicted`` or ``extrapolated``; contradicted wins over
        backed), ``speed_tolerance``, ``radial_tolerance``, ``backed_by`` and ``contradicted_by``
        (indices into ``cuts``), ``doubted`` (stable marks that would back the plan but which the
        posterior doubts beyond ``max_doubt``), ``nearby`` (how many sure marks lie at the plan's milling direction,
        speed and width) and ``deepest_stable_nearby_m`` (the deepest sure stable one of those;
        None without one).
    """
    rpm, ap = (np.asarray(getattr(cuts, k), dtype=float) for k in ("spindle_rpm", "axial_depth_m"))
    at_speed = np.abs(rpm / float(spindle_rpm) - 1.0) <= speed_tolerance
    stable, chatter = (at_speed & m for m in _sure(cuts, mislabelled, radial_depth_m, down, radial_tolerance,
                                                   max_doubt))
    # a relative slack of 1e-9: a test cut written back from the plan's own numbers is the plan
    deep_enough = ap >= axial_depth_m * (1 - 1e-9)
    backed = stable & deep_enough
    doubted = _sure(cuts, None, radial_depth_m, down, radial_tolerance)[0] & at_speed & deep_enough & ~backed
    contradicted = chatter & (ap <= axial_depth_m * (1 + 1e-9))
    status = "contradicted" if contradicted.any() else "backed" if backed.any() else "extrapolated"
    return {"status": status, "speed_tolerance": float(speed_tolerance), "radial_tolerance": float(radial_tolerance),
            "backed_by": [int(i) for i in np.flatnonzero(backed)],
            "contradicted_by": [int(i) for i in np.flatnonzero(contradicted)],
            "doubted": [int(i) for i in np.flatnonzero(doubted)],
            "nearby": int(np.sum(stable | chatter)),
            "deepest_stable_nearby_m": float(ap[stable].max()) if stable.any() else None}


#: Relative width of the speed range ``best_backed`` plans in, below the test cut's own speed (above
#: it at the setup's lowest speed; the planner needs a range, and the answer is at the cut's speed to
#: this precision).
_SPEED_SLIVER = 1e-4


def best_backed(setup, structure, cuts: CutTable, *, mislabelled=None, max_doubt: float = SUSPECT_LABEL,
                method: str = "auto",
                radial_tolerance: float = RADIAL_TOLERANCE) -> dict | None:
    """The largest removal rate the stable test cuts prove (module notes): for each sure stable
    mark at the setup's engagement (milling direction, radial depth within ``radial_tolerance``)
    and speed range, :func:`planner.optimize.plan` at its speed with the depth at most its depth,
    under every other limit of ``setup`` (feed, power, torque, force, surface error with
    ``structure``). Cuts are tried best bound first (their depth at the setup's largest feed)
    until no untried one could beat the best plan; a plan that a chatter mark at its speed
    contradicts is not taken.

    Returns
    -------
    dict or None
        ``spindle_rpm``, ``axial_depth_m``, ``feed_per_tooth_m``, ``mrr_m3_s``,
        ``active_constraints`` (the plan's; ``stability`` there is the test cut's depth) and
        ``backed_by`` (the cut's index); None when no sure stable mark lies at the engagement
        within the setup's speed and depth ranges, or none gives a plan.
    """
    from dataclasses import replace

    from planner.optimize import plan

    lim = setup.limits
    stable, _ = _sure(cuts, mislabelled, setup.cut.radial_depth_m, setup.cut.milling == "down", radial_tolerance,
                      max_doubt)
    rpm, ap = (np.asarray(getattr(cuts, k), dtype=float) for k in ("spindle_rpm", "axial_depth_m"))
    lo, hi = lim.spindle_rpm
    (d_lo, d_hi) = lim.axial_depth_m
    candidates = np.flatnonzero(stable & (rpm >= lo) & (rpm <= hi) & (ap >= d_lo))
    fz_max = (lim.feed_per_tooth_m or (setup.cut.feed_per_tooth_m,) * 2)[1]
    bound = rpm * np.minimum(ap, d_hi) * fz_max * setup.cut.radial_depth_m * setup.tool.teeth / 60.0
    best = None
    for i in sorted(candidates, key=lambda k: -bound[k]):
        if best is not None and bound[i] <= best["mrr_m3_s"]:
            break
        depth, n = min(float(ap[i]), float(d_hi)), float(rpm[i])
        # a sliver of speed at the cut's, inside the setup's range (above it at the range's low end)
        below = n * (1 - _SPEED_SLIVER)
        speeds = (below, n) if below >= lo else (n, min(hi, n * (1 + _SPEED_SLIVER)))
        at = replace(setup, limits=replace(lim, spindle_rpm=speeds, axial_depth_m=(float(d_lo), depth)))
        # the cut's own depth is the stability limit (strictly above it: the plan may reach it)
        result = plan(at, structure, method=method,
                      stability_limit=lambda speed, a=depth: np.full(np.shape(speed), a * (1 + 1e-6)))
        if not result.success:
            continue
        support = plan_support(cuts, result.spindle_rpm, result.axial_depth_m, setup.cut.radial_depth_m,
                               setup.cut.milling == "down", mislabelled=mislabelled, max_doubt=max_doubt,
                               radial_tolerance=radial_tolerance)
        if support["status"] != "backed":
            continue
        if best is None or result.mrr_m3_s > best["mrr_m3_s"]:
            best = {"spindle_rpm": result.spindle_rpm, "axial_depth_m": result.axial_depth_m,
                    "feed_per_tooth_m": result.feed_per_tooth_m, "mrr_m3_s": result.mrr_m3_s,
                    "active_constraints": list(result.active_constraints), "backed_by": int(i)}
    return best


def support_warning(support: dict, cuts: CutTable, spindle_rpm: float, axial_depth_m: float) -> str | None:
    """The warning ``plan`` gives for ``support`` (:func:`plan_support`); None when backed."""
    tol = f"{100 * support['speed_tolerance']:g} %"
    if support["status"] == "contradicted":
        which = "; ".join(f"cut {i} ({cuts.spindle_rpm[i]:.0f} rpm, {1e3 * cuts.axial_depth_m[i]:.2f} mm deep, "
                          f"{1e3 * cuts.radial_depth_m[i]:.2f} mm wide)" for i in support["contradicted_by"])
        return (f"test cut(s) chattered within {tol} of the plan's speed, at its width and at or below its depth: {which}. "
                f"The posterior took the mark(s) for wrong; the cuts say the plan ({spindle_rpm:.0f} rpm, "
                f"{1e3 * axial_depth_m:.2f} mm) chatters: check the marks, or plan under that depth (the setup's "
                "limits.axial_depth_m)")
    if support["status"] == "extrapolated":
        deepest = support["deepest_stable_nearby_m"]
        seen = (f"the deepest stable one there was {1e3 * deepest:.2f} mm" if deepest is not None
                else "none was stable there" if support["nearby"] else "none was cut there")
        doubted = support.get("doubted") or []
        if doubted:
            seen += (f"; cut(s) {', '.join(map(str, doubted))} read stable there, but the posterior doubts the "
                     f"mark(s) (probability of being wrong above {support.get('max_doubt', SUSPECT_LABEL):g}): "
                     "recut to back the plan")
        alt = support.get("best_backed")
        best = (f"; the best cut the stable test cuts prove is {alt['spindle_rpm']:.0f} rpm at "
                f"{1e3 * alt['axial_depth_m']:.2f} mm, {100 * alt['share_of_plan']:.0f} % of the plan's removal rate "
                "(learned.support.best_backed)" if alt else "")
        return (f"no test cut within {tol} of {spindle_rpm:.0f} rpm at the plan's width was stable at its depth "
                f"({1e3 * axial_depth_m:.2f} mm; {seen}): the plan's P(stable) is the model's "
                "extrapolation from the cuts, which holds only if the prior has every mode the tool has; "
                f"cut the plan as a test cut and learn again with its outcome{best}")
    return None
