"""Semi-discretization where the immersion asks for it, kept affordable.

At low radial immersion (``ae / D`` below 0.2, as ``robomill plan --method auto``) the ZOA misses
the flip (period-doubling) lobes, and its limit can be optimistic. An SDM limit costs 0.1-2 s per
(pose, speed) (Insperger & Stepan, 2004; :func:`stability.lobes.lobe_diagram`), three to four orders
of magnitude more than a ZOA row, so the atlas does not compute it everywhere: the map stays ZOA,
and the best rows of the ``n_verify`` most productive positions are checked by SDM at their chosen
speed (one Dask task each: seconds of work, the right size for the scheduler). Their SDM limit
gives the depth and MRR reported in ``sdm_depth_limit_m`` / ``sdm_mrr_m3_s``, and the best placement
is chosen among the verified rows by those values. Positions outside the verified set keep their
ZOA values and are flagged by NaN in the SDM columns.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sdm_chunk", "sdm_cut"]


def sdm_chunk(problem, rows) -> np.ndarray:
    """SDM limit (m) and chatter frequency (Hz) of rows ``(q1..q6 [rad], rpm)``, shape (k, 2)."""
    from oma.modal import ModalModel
    from planner.robot import robot_modal_model
    from stability.lobes import lobe_diagram

    rows = np.atleast_2d(np.asarray(rows, float))
    tool_model = None
    if problem.tool_modes is not None:
        t = problem.tool_modes
        tool_model = ModalModel(t["frequency_hz"], t["damping_ratio"], t["stiffness_N_m"], t["directions"])
    out = np.empty((rows.shape[0], 2))
    for i, row in enumerate(rows):
        model = robot_modal_model(problem.robot, row[:6], tool_model=tool_model, check_limits=False,
                                  min_tip_fraction=problem.min_tip_fraction)
        rpm = float(row[6])
        d = lobe_diagram(model, problem.tool, problem.cut_machine, problem.coefficients, rpm_range=(rpm, 2.0 * rpm),
                         rpm=[rpm], method="sdm")
        out[i] = float(d.depth_limit_m[0]), float(d.chatter_frequency_hz[0])
    return out


def sdm_cut(problem, rpm, sdm_limit):
    """Depth (NaN: none feasible) and MRR of the cut at ``rpm`` under the SDM limit and the bounds."""
    rpm, lim = np.asarray(rpm, float), np.asarray(sdm_limit, float)
    ap = np.minimum(np.minimum(problem.ap_hi_m, problem.power_depth_rpm / rpm), problem.margin * lim)
    ap = np.where(ap >= problem.ap_lo_m, ap, np.nan)
    return ap, problem.mrr_per_depth_rpm * ap * rpm
