"""Plots of a cutting-parameter plan (:class:`planner.optimize.Plan`).

The function takes results (no physics is computed here), draws on the given axes or on a new
figure, and returns ``(fig, ax)``. matplotlib is imported inside the function only, so importing
:mod:`planner.optimize` never loads it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_plan"]

_MM = 1e3


def plot_plan(plan, ax=None, *, show_lobes: bool = True, limit_label: str | None = None):
    """The lobe diagram with the planned depth line, every pocket's answer and the optimum.

    Parameters
    ----------
    plan : Plan
    ax : matplotlib Axes, optional
    show_lobes : bool
        Draw the individual ZOA lobes under the envelope.
    limit_label : str, optional
        What the limit is when the plan was made against a given one (``stability_limit``, e.g.
        the chance constraint of a posterior), for its legend entry and the title.

    Returns
    -------
    fig, ax

    Notes
    -----
    Depths in mm against spindle speed in rpm: the stability limit (:func:`stability.plots.
    plot_lobes`), ``stability_margin`` times the limit (dashed: the most the plan may use), the
    pocket borders (dotted verticals), each pocket's NLP answer (grey dots; re-checked ones ringed)
    and the recommended point (star), annotated with its removal rate and active constraints.
    """
    from stability.plots import plot_lobes

    fig, ax = plot_lobes(plan.diagram, ax=ax, show_lobes=show_lobes)
    if limit_label:  # the diagram holds a given limit, sampled, not the model's lobes
        for line in ax.get_lines():
            if line.get_label().endswith("envelope"):
                line.set_label(limit_label)
    rpm = np.asarray(plan.diagram.rpm, dtype=float)
    depth = np.asarray(plan.diagram.depth_limit_m, dtype=float)
    ax.plot(rpm, plan.stability_margin * depth * _MM, color="tab:orange", ls="--", lw=1.2,
            label=f"{plan.stability_margin:g} x limit (planning bound)")
    for p in plan.pockets[1:]:
        ax.axvline(p.rpm_range[0], color="0.85", lw=0.5, ls=":", zorder=0)
    sol = np.array([p.solution for p in plan.pockets if p.feasible]).reshape(-1, 3)
    if sol.size:
        ax.plot(sol[:, 0], sol[:, 1] * _MM, "o", color="0.45", ms=4, ls="none", label="pocket optima")
    checked = np.array([p.solution for p in plan.pockets if p.verified]).reshape(-1, 3)
    if checked.size:
        ax.plot(checked[:, 0], checked[:, 1] * _MM, "o", mfc="none", mec="k", ms=8, ls="none",
                label="re-checked (predict_point)")
    if plan.spindle_rpm is not None:
        colour = "tab:green" if plan.success else "tab:red"
        ax.plot([plan.spindle_rpm], [plan.axial_depth_m * _MM], "*", color=colour, ms=16, mec="k", ls="none",
                label="recommended")
        text = (f"{plan.mrr_m3_s * 1e6:.3g} cm$^3$/s, fz {plan.feed_per_tooth_m * _MM:.3g} mm\n"
                f"active: {', '.join(plan.active_constraints) or 'none'}")
        right = plan.spindle_rpm > 0.5 * (rpm[0] + rpm[-1])  # keep the text inside the axes
        ax.annotate(text, (plan.spindle_rpm, plan.axial_depth_m * _MM), xytext=(-10 if right else 10, 10),
                    textcoords="offset points", fontsize="small", ha="right" if right else "left")
    ax.set_title(f"plan ({limit_label or plan.method.upper()}): {plan.status}")
    ax.legend(loc="best", fontsize="small")
    return fig, ax
