"""Plots of :class:`planner.robot.posture.PostureResult` (matplotlib imported here only)."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_posture"]


def plot_posture(result, ax=None):
    """The path (x-y of the toolpath's frame, mm) coloured by stability margin with the toolpath's
    rotation (left) and the chosen one (right), on one colour scale; unreachable points marked.

    Returns
    -------
    fig, axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    else:
        axes = np.atleast_1d(ax)
        fig = axes[0].figure
    xy = np.asarray(result.toolpath.positions_m)[:, :2] * 1e3
    both = np.concatenate([result.margin_before, result.margin_after])
    both = both[np.isfinite(both)]
    lo, hi = (float(both.min()), float(both.max())) if both.size else (0.0, 1.0)
    for a, margin, title, low in ((axes[0], result.margin_before, "before", result.min_margin_before),
                                  (axes[-1], result.margin_after, "after posture", result.min_margin_after)):
        a.plot(xy[:, 0], xy[:, 1], color="0.8", lw=1.0, zorder=1)
        pts = a.scatter(xy[:, 0], xy[:, 1], c=margin, cmap="viridis", vmin=lo, vmax=hi, s=14, zorder=2)
        bad = ~np.isfinite(margin)
        if bad.any():
            a.scatter(xy[bad, 0], xy[bad, 1], marker="x", color="r", s=30, zorder=3, label="no pose")
            a.legend(loc="best", fontsize="small")
        a.set_title(f"{title}: smallest margin {low:.3g}")
        a.set_xlabel("x (mm)")
        a.set_aspect("equal", adjustable="datalim")
    axes[0].set_ylabel("y (mm)")
    fig.colorbar(pts, ax=list(axes), label="stability margin (limit depth / planned depth)")
    return fig, axes
