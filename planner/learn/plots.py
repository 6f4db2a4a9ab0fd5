"""Plots of what ``learn`` found (matplotlib imported here only)."""

from __future__ import annotations

import numpy as np

from .likelihood import CHATTER, STABLE, UNCERTAIN

__all__ = ["plot_probability_lobes"]


def plot_probability_lobes(lobes, ax=None, *, cuts=None):
    """P(stable) over speed and depth, the 5 / 50 / 95 % contours, and the test cuts at this
    engagement (o stable, x chatter, ? uncertain). Returns (figure, axes)."""
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(8, 4.5))
    else:
        fig = ax.figure
    top = 1.3 * float(np.max(lobes.quantiles[min(lobes.levels)]))
    depth = np.linspace(top / 200, top, 120)
    p = lobes.probability_stable(depth)
    mesh = ax.pcolormesh(lobes.rpm, 1e3 * depth, p, shading="auto", cmap="RdYlGn", vmin=0, vmax=1)
    fig.colorbar(mesh, ax=ax, label="P(stable)")
    styles = {0.05: ":", 0.5: "-", 0.95: "--"}
    for lev in lobes.levels:
        ax.plot(lobes.rpm, 1e3 * lobes.quantiles[lev], "k", ls=styles.get(lev, "-."), lw=1.2,
                label=f"P(stable) = {100 * lev:g} %")
    if cuts is not None and cuts.n_cuts:
        same = np.isclose(cuts.radial_depth_m, lobes.radial_depth_m) & (cuts.down == (lobes.milling == "down"))
        for code, marker, name in ((STABLE, "o", "stable"), (CHATTER, "x", "chatter"), (UNCERTAIN, "$?$", "uncertain")):
            sel = same & (cuts.outcome == code)
            if sel.any():
                ax.scatter(cuts.spindle_rpm[sel], 1e3 * cuts.axial_depth_m[sel], marker=marker, c="k", s=30,
                           label=f"test cut: {name}")
    ax.set_xlabel("spindle speed (rpm)")
    ax.set_ylabel("axial depth (mm)")
    ax.set_ylim(0, 1e3 * top)
    ax.set_title(f"posterior stability, a_e = {1e3 * lobes.radial_depth_m:.2f} mm, {lobes.milling} milling")
    ax.legend(loc="upper left", fontsize=8)
    return fig, ax
