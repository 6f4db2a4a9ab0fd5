"""Which test cut next: expected improvement of the best stable material removal rate.

Candidates are cuts at the setup's own engagement (the production cut) on a grid of speeds and
depths. The *incumbent* is the best MRR the posterior already guarantees, the largest
``ap * rpm`` with P(stable) >= ``confidence`` (0.95); a candidate's expected improvement is

    EI(c) = P(stable at c) * max(0, MRR(c) - MRR_incumbent),

the gain in the best proven-stable removal rate if the test cut at ``c`` comes out stable (the
expected-improvement rule of Jones, Schonlau & Welch, J. Global Optim. 13, 1998, for a pass/fail
outcome; Karandikar et al. choose test cuts in the same spirit). ``N`` cuts are picked greedily,
each at least ``min_speed_gap`` (relative) away in speed from those already picked, so that one
test does not make the next redundant.
"""

from __future__ import annotations

import numpy as np

from .outcomes_io import CutTable
from .predictive import ProbabilityLobes

__all__ = ["suggest_cuts"]


def suggest_cuts(lobes: ProbabilityLobes, n: int, *, depth_range_m=None, n_depth: int = 60,
                 confidence: float = 0.95, min_speed_gap: float = 0.03) -> tuple[CutTable, np.ndarray, float]:
    """The ``n`` test cuts of largest expected improvement.

    Parameters
    ----------
    lobes : ProbabilityLobes
        The posterior's limits over speed at the production engagement.
    n : int
    depth_range_m : (float, float), optional
        Depths considered (default: from half the lowest 95 % depth to twice the highest 5 % one).

    Returns
    -------
    cuts : CutTable
        Suggested cuts, no outcome.
    expected_improvement : ndarray, shape (n,)
        In units of ``ap * rpm`` (m rpm; multiply by ``ae fz N / 60`` for m^3/s).
    incumbent : float
        Best ``ap * rpm`` with P(stable) >= ``confidence`` (0 when none).
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, found {n}")
    lo_q = lobes.quantiles.get(0.95, np.quantile(lobes.limits, 0.05, axis=0))
    hi_q = lobes.quantiles.get(0.05, np.quantile(lobes.limits, 0.95, axis=0))
    if depth_range_m is None:
        depth_range_m = (0.5 * float(np.min(lo_q)), 2.0 * float(np.max(hi_q)))
    depth = np.geomspace(depth_range_m[0], depth_range_m[1], n_depth)
    p = lobes.probability_stable(depth)  # (n_depth, n_rpm)
    mrr = depth[:, None] * lobes.rpm[None, :]
    safe = p >= confidence
    incumbent = float(mrr[safe].max()) if safe.any() else 0.0
    ei = p * np.maximum(0.0, mrr - incumbent)
    picked_rpm, picked_ap, gains = [], [], []
    for _ in range(n):
        score = ei.copy()
        for r in picked_rpm:
            score[:, np.abs(lobes.rpm / r - 1.0) < min_speed_gap] = -1.0
        i, j = np.unravel_index(int(np.argmax(score)), score.shape)
        if score[i, j] < 0:
            break
        picked_rpm.append(float(lobes.rpm[j]))
        picked_ap.append(float(depth[i]))
        gains.append(float(ei[i, j]))
    k = len(picked_rpm)
    cuts = CutTable(np.array(picked_rpm), np.array(picked_ap), np.full(k, lobes.radial_depth_m),
                    np.full(k, lobes.milling == "down"), np.full(k, -1), np.ones(k), np.full(k, np.nan),
                    np.zeros(k, bool))
    return cuts, np.array(gains), incumbent
