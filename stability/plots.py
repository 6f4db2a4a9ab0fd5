"""Plots of stability and forced-vibration results.

Each function takes results (no physics is computed here), draws on the given axes or on a new
figure, and returns ``(fig, ax)``. matplotlib is imported inside the functions only, so importing
:mod:`stability` never loads it.

* :func:`plot_lobes`: one or more lobe diagrams together (typically ZOA and SDM); the ZOA's
  individual lobes thin, its envelope bold; SDM boundary points styled by type, flip (period
  doubling) and Hopf boundaries distinguished.
* :func:`plot_forced_sweep`: surface location error and peak force versus spindle speed.
* :func:`plot_operating_point`: force and surface-normal displacement over one tooth period.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_lobes", "plot_forced_sweep", "plot_operating_point", "KIND_STYLE"]

#: Line style of each SDM boundary type: (colour, line style, marker, label).
KIND_STYLE = {
    "hopf": ("tab:blue", "-", "o", "SDM Hopf boundary"),
    "flip": ("tab:red", "--", "s", "SDM flip (period-doubling) boundary"),
    "fold": ("tab:green", ":", "^", "SDM fold boundary"),
}
_MM = 1e3


def _axes(ax, nrows=1):
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(nrows, 1, sharex=True, figsize=(7.0, 3.2 * nrows + 0.8), squeeze=True,
                               layout="constrained")
        return fig, ax
    if nrows == 1:
        return ax.figure, ax
    axes = np.asarray(ax).ravel()
    if axes.size != nrows:
        raise ValueError(f"ax must hold {nrows} axes, found {axes.size}")
    return axes[0].figure, axes


def plot_lobes(diagram, *more, ax=None, show_lobes: bool = True):
    """Lobe diagram(s): limit depth (mm) versus spindle speed (rpm).

    Parameters
    ----------
    diagram, *more : LobeDiagram
        Diagrams to draw on the same axes (e.g. ZOA and SDM of the same cut).
    ax : matplotlib Axes, optional
    show_lobes : bool
        Draw the individual ZOA lobes under the envelope.

    Returns
    -------
    fig, ax
    """
    fig, ax = _axes(ax)
    top = 0.0
    for d in (diagram, *more):
        depth = np.asarray(d.depth_limit_m, dtype=float)
        finite = depth[np.isfinite(depth)]
        if finite.size:
            top = max(top, float(finite.max()))
        if d.method == "zoa":
            if show_lobes and d.lobe_rpm.size:
                ax.plot(d.lobe_rpm, d.lobe_depth_m * _MM, color="0.75", lw=0.6, label="ZOA lobes")
            ax.plot(d.rpm, depth * _MM, color="k", lw=1.8, label="ZOA envelope")
            cusp = np.asarray(d.is_intersection)
            if cusp.any():
                ax.plot(d.rpm[cusp], depth[cusp] * _MM, "kv", ms=3, ls="none", label="ZOA lobe intersections")
        else:
            kind = np.asarray(d.kind)
            for k, (colour, ls, marker, label) in KIND_STYLE.items():
                sel = kind == k
                if not sel.any():
                    continue
                y = np.where(sel, depth, np.nan) * _MM
                ax.plot(d.rpm, y, color=colour, ls=ls, marker=marker, ms=3, lw=1.4, label=label)
    ax.set_xlabel("spindle speed (rpm)")
    ax.set_ylabel("axial depth limit (mm)")
    if top > 0:
        ax.set_ylim(0.0, 1.1 * top * _MM)
    ax.set_title("stability lobes (stable below the boundary)")
    ax.legend(loc="best", fontsize="small")
    ax.grid(True, alpha=0.3)
    return fig, ax


def plot_forced_sweep(sweep, ax=None):
    """Surface location error (um) and peak force (N) versus spindle speed, at the sweep's depth.

    Parameters
    ----------
    sweep : ForcedSweep
    ax : pair of matplotlib Axes, optional

    Returns
    -------
    fig, (ax_sle, ax_force)
    """
    fig, (a1, a2) = _axes(ax, nrows=2)
    rpm = sweep.spindle_rpm
    a1.plot(rpm, np.asarray(sweep.surface_location_error_m) * 1e6, color="tab:blue", label="SLE")
    a1.axhline(sweep.static_sle_m * 1e6, color="tab:blue", ls=":", label="static deflection part")
    a1.axhline(0.0, color="0.5", lw=0.6)
    a1.set_ylabel("surface location error (um)\n(+ = material left on)")
    a1.legend(loc="best", fontsize="small")
    a1.set_title(f"forced vibration at axial depth {sweep.axial_depth_m * _MM:g} mm")
    a2.plot(rpm, sweep.peak_force_N, color="tab:red")
    a2.set_ylabel("peak force in f-n plane (N)")
    a2.set_xlabel("spindle speed (rpm)")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
    return fig, (a1, a2)


def plot_operating_point(point, ax=None):
    """Force, and the displacement away from the finished wall, over one tooth period of a point.

    Parameters
    ----------
    point : OperatingPoint
    ax : pair of matplotlib Axes, optional

    Returns
    -------
    fig, (ax_force, ax_disp)
    """
    fig, (a1, a2) = _axes(ax, nrows=2)
    fr = point.forced
    t_ms = fr.time_s * 1e3
    mag = np.linalg.norm(fr.force_N, axis=0)
    for i, name in enumerate("XYZ"):
        a1.plot(t_ms, fr.force_N[i], lw=1.0, label=f"F{name}")
    a1.plot(t_ms, mag, color="k", lw=1.4, label="|F|")
    a1.set_ylabel("force on tool (N)")
    a1.legend(loc="best", fontsize="small", ncol=4)
    state = "stable" if point.stable else "UNSTABLE (forced response not steady)"
    a1.set_title(f"{point.spindle_rpm:g} rpm, depth {point.axial_depth_m * _MM:g} mm: {state}")
    a2.plot(t_ms, fr.wall_displacement_m * 1e6, color="tab:blue", label="away from the finished wall")
    a2.plot([fr.finishing_time_s * 1e3], [point.surface_location_error_m * 1e6], "ko",
            label=f"SLE {point.surface_location_error_m * 1e6:.3g} um (wall generated)")
    a2.axhline(0.0, color="0.5", lw=0.6)
    a2.set_ylabel("tool-tip displacement (um)\n(+ = material left on)")
    a2.set_xlabel("time in tooth period (ms)")
    a2.legend(loc="best", fontsize="small")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
    return fig, (a1, a2)
