"""Plots of :class:`planner.robot.posture.PostureResult` (matplotlib imported here only)."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_posture", "plot_mode_map"]


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


def plot_mode_map(x_m, y_m, frequency_hz, *, path_xy_m=None, poses_xy_m=None, ax=None):
    """Filled contours of the lowest tool-tip mode (Hz) over the x-y grid (mm), the path and the
    identified poses on top. Returns fig, ax."""
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(6.4, 5.0), constrained_layout=True)
    else:
        fig = ax.figure
    xs, ys = np.asarray(x_m) * 1e3, np.asarray(y_m) * 1e3
    cs = ax.contourf(xs, ys, frequency_hz, levels=14, cmap="viridis")
    fig.colorbar(cs, ax=ax, label="lowest tool-tip mode (Hz)")
    if path_xy_m is not None:
        p = np.asarray(path_xy_m) * 1e3
        ax.plot(p[:, 0], p[:, 1], color="w", lw=2.0, label="toolpath")
    if poses_xy_m is not None:
        p = np.asarray(poses_xy_m) * 1e3
        ax.scatter(p[:, 0], p[:, 1], marker="o", facecolors="none", edgecolors="r", s=50, label="identified poses")
    ax.set_xlabel("x (mm, machine)")
    ax.set_ylabel("y (mm, machine)")
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="upper right", fontsize="small")
    ax.set_title("calibrated robot: lowest tool-tip mode, tool axis +Z")
    return fig, ax
