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
under :data:`MIN_WEIGHT` (a detection less sure than not) neither back nor contradict.
"""

from __future__ import annotations

import numpy as np

from .likelihood import CHATTER, STABLE
from .outcomes_io import CutTable

__all__ = ["plan_support", "support_warning", "SPEED_TOLERANCE", "RADIAL_TOLERANCE", "MIN_WEIGHT"]

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


def plan_support(cuts: CutTable, spindle_rpm: float, axial_depth_m: float, radial_depth_m: float,
                 down: bool, *, speed_tolerance: float = SPEED_TOLERANCE,
                 radial_tolerance: float = RADIAL_TOLERANCE) -> dict:
    """The test cuts that back or contradict a planned cut (module notes).

    Returns
    -------
    dict
        ``status`` (``backed``, ``contradicted`` or ``extrapolated``; contradicted wins over
        backed), ``speed_tolerance``, ``radial_tolerance``, ``backed_by`` and ``contradicted_by``
        (indices into ``cuts``), ``nearby`` (how many sure marks lie at the plan's milling
        direction, speed and width) and ``deepest_stable_nearby_m`` (the deepest stable one of
        those; None without one).
    """
    rpm, ap, ae = (np.asarray(getattr(cuts, k), dtype=float) for k in ("spindle_rpm", "axial_depth_m",
                                                                        "radial_depth_m"))
    near = ((np.asarray(cuts.weight, dtype=float) >= MIN_WEIGHT) & (np.asarray(cuts.down, dtype=bool) == bool(down))
            & (np.abs(rpm / float(spindle_rpm) - 1.0) <= speed_tolerance)
            & (np.abs(ae / float(radial_depth_m) - 1.0) <= radial_tolerance))
    stable = near & (cuts.outcome == STABLE)
    chatter = near & (cuts.outcome == CHATTER)
    # a relative slack of 1e-9: a test cut written back from the plan's own numbers is the plan
    backed = stable & (ap >= axial_depth_m * (1 - 1e-9))
    contradicted = chatter & (ap <= axial_depth_m * (1 + 1e-9))
    status = "contradicted" if contradicted.any() else "backed" if backed.any() else "extrapolated"
    return {"status": status, "speed_tolerance": float(speed_tolerance), "radial_tolerance": float(radial_tolerance),
            "backed_by": [int(i) for i in np.flatnonzero(backed)],
            "contradicted_by": [int(i) for i in np.flatnonzero(contradicted)],
            "nearby": int(np.sum(stable | chatter)),
            "deepest_stable_nearby_m": float(ap[stable].max()) if stable.any() else None}


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
        return (f"no test cut within {tol} of {spindle_rpm:.0f} rpm at the plan's width was stable at its depth "
                f"({1e3 * axial_depth_m:.2f} mm; {seen}): the plan's P(stable) is the model's "
                "extrapolation from the cuts, which holds only if the prior has every mode the tool has; "
                "cut the plan as a test cut and learn again with its outcome")
    return None
