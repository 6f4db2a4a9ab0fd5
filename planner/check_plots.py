"""Plot of a toolpath check: the path in the x-y plane coloured by stability margin, violations marked.

Takes a :class:`planner.check.ToolpathCheck` (no physics is computed here), draws on the given axes
or a new figure, and returns ``(fig, ax)``. matplotlib is imported inside the function only, so
importing :mod:`planner.check` never loads it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_toolpath_check", "VIOLATION_STYLE"]

#: Marker of each violation kind: (marker, colour, size, label).
VIOLATION_STYLE = {
    "chatter": ("x", "tab:red", 46, "chatter"),
    "surface_error": ("s", "tab:orange", 40, "surface error"),
    "force": ("^", "tab:purple", 40, "force"),
    "power": ("v", "tab:brown", 40, "power"),
    "torque": ("D", "tab:olive", 34, "torque"),
    "pose_out_of_range": ("o", "0.35", 70, "pose out of range"),
    "unreachable": ("X", "k", 50, "unreachable"),
    "joint_limit": ("P", "tab:blue", 46, "joint limit"),
    "singularity": ("*", "tab:pink", 70, "singularity"),
}
_MM = 1e3


def plot_toolpath_check(check, ax=None, *, cmap: str = "RdYlGn", margin_range: tuple[float, float] | None = None):
    """The path in the x-y plane (mm), each point coloured by its stability margin.

    The colour scale is centred (yellow) on the smallest margin that passes the chatter test,
    ``1 / allowed_fraction``: red points chatter (or lie within the planning margin), green points
    are stable with room to spare. Violations are marked on top, one marker per kind (hollow circle
    for a pose outside the identified span).

    Parameters
    ----------
    check : ToolpathCheck
    ax : matplotlib Axes, optional
    cmap : str
        Diverging colour map.
    margin_range : (float, float), optional
        Colour-scale limits of the margin; default ``(0, 2 / allowed_fraction)``.

    Returns
    -------
    fig, ax
    """
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    if ax is None:
        fig, ax = plt.subplots(figsize=(7.0, 5.0), layout="constrained")
    else:
        fig = ax.figure
    xy = np.asarray(check.positions_m)[:, :2] * _MM
    centre = 1.0 / check.allowed_fraction
    lo, hi = margin_range if margin_range is not None else (0.0, 2.0 * centre)
    if not lo < centre < hi:
        raise ValueError(f"margin_range must contain the pass threshold {centre:g}, found {margin_range}")
    margin = np.asarray(check.stability_margin, dtype=float)
    shown = np.clip(np.where(np.isfinite(margin), margin, hi), lo, hi)
    ax.plot(xy[:, 0], xy[:, 1], color="0.75", lw=1.0, zorder=1)
    points = ax.scatter(xy[:, 0], xy[:, 1], c=shown, cmap=cmap, norm=TwoSlopeNorm(centre, lo, hi), s=14,
                        zorder=2)
    bar = fig.colorbar(points, ax=ax)
    bar.set_label("stability margin (limit depth / planned depth)")
    bar.ax.axhline(centre, color="k", lw=0.8)
    counts = check.counts()
    for kind, (marker, colour, size, label) in VIOLATION_STYLE.items():
        mask = check.flagged(kind)
        if not mask.any():
            continue
        if kind == "pose_out_of_range":  # hollow, around the point's colour
            style = {"facecolors": "none", "edgecolors": colour, "linewidths": 1.0}
        elif marker in ("x", "+"):  # unfilled markers take one colour
            style = {"color": colour, "linewidths": 1.4}
        else:
            style = {"color": colour, "edgecolors": "k", "linewidths": 0.4}
        ax.scatter(xy[mask, 0], xy[mask, 1], marker=marker, s=size, zorder=3, label=f"{label} ({counts[kind]})",
                   **style)
    if any(counts.values()):
        ax.legend(loc="best", fontsize="small", title="violations")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal", adjustable="datalim")
    total = len(check.violations)
    ax.set_title(f"toolpath check ({check.method.upper()}): {check.n_points} points, "
                 f"{total} violation{'s' if total != 1 else ''}")
    return fig, ax
