"""Figures of an atlas (they take an :class:`~planner.atlas.run.AtlasResult`, compute no physics).

The region is drawn over its two longest axes; a box's third axis is shown as panels (at most
four levels, evenly chosen, labelled). Positions without a stable cut at any rotation are grey;
unreachable ones are blank. The best placement is marked with a star on its panel.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_mrr_map", "plot_best_rotation"]

_AXES = ("x", "y", "z")


def _layout(result, max_panels: int = 4):
    shape = result.region.shape
    axes = result.region.axes_m
    order = sorted(range(3), key=lambda k: (-shape[k], k))
    u, v, w = order[0], order[1], order[2]
    levels = np.unique(np.linspace(0, shape[w] - 1, min(shape[w], max_panels)).round().astype(int))
    return u, v, w, axes, levels


def _panels(result, values, *, cmap, label, title, vmin=None, vmax=None, fig=None):
    import matplotlib.pyplot as plt

    u, v, w, axes, levels = _layout(result)
    shape = result.region.shape
    grid = np.asarray(values, float).reshape(shape)
    reach = np.any(np.asarray(result.columns["reachable"]).reshape(result.n_points, -1), axis=1).reshape(shape)
    if fig is None:
        fig, ax = plt.subplots(1, levels.size, figsize=(4.2 * levels.size + 1.0, 4.0), squeeze=False,
                               constrained_layout=True)
        ax = ax[0]
    else:
        ax = np.atleast_1d(fig.axes)
    finite = grid[np.isfinite(grid)]
    vmin = vmin if vmin is not None else (finite.min() if finite.size else 0.0)
    vmax = vmax if vmax is not None else (finite.max() if finite.size else 1.0)
    if vmax <= vmin:
        vmax = vmin + (abs(vmin) * 1e-3 or 1.0)
    best = result.best
    image = None
    for a, lev in zip(ax, levels):
        sl = [slice(None)] * 3
        sl[w] = lev
        z = grid[tuple(sl)]
        r = reach[tuple(sl)]
        if u < v:  # the slice's axes are in index order: make rows v and columns u
            z, r = z.T, r.T
        du = (axes[u][1] - axes[u][0]) if axes[u].size > 1 else result.region.step_m
        dv = (axes[v][1] - axes[v][0]) if axes[v].size > 1 else result.region.step_m
        extent = (axes[u][0] - du / 2, axes[u][-1] + du / 2, axes[v][0] - dv / 2, axes[v][-1] + dv / 2)
        grey = np.where(r & ~np.isfinite(z), 1.0, np.nan)
        a.imshow(grey, origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=2.5, aspect="equal")
        image = a.imshow(np.ma.masked_invalid(z), origin="lower", extent=extent, cmap=cmap, vmin=vmin, vmax=vmax,
                         aspect="equal", interpolation="nearest")
        a.set_xlabel(f"{_AXES[u]} (m)")
        a.set_ylabel(f"{_AXES[v]} (m)")
        a.set_title(f"{_AXES[w]} = {axes[w][lev]:.3f} m", fontsize=9)
        if best is not None and abs(best[f"{_AXES[w]}_m"] - axes[w][lev]) < 1e-9:
            a.plot(best[f"{_AXES[u]}_m"], best[f"{_AXES[v]}_m"], marker="*", ms=14, mfc="white", mec="black")
    fig.colorbar(image, ax=list(ax), label=label, shrink=0.9)
    fig.suptitle(title, fontsize=10)
    return fig, ax


def plot_mrr_map(result, *, fig=None):
    """The best stable removal rate (cm^3/min) at each position's best rotation."""
    mrr = result.per_point("mrr_m3_s") * 6e7
    title = "best stable MRR at each position's best tool rotation\n(grey: no stable cut; star: best placement)"
    return _panels(result, mrr, cmap="viridis", label="MRR (cm$^3$/min)", title=title, fig=fig)


def plot_best_rotation(result, *, fig=None):
    """The tool rotation (deg) with the largest stable MRR (then stability reserve) per position."""
    rot = result.per_point("rotation_deg")
    return _panels(result, rot, cmap="twilight", label="best rotation about the tool axis (deg)",
                   title=("best tool rotation per position\n(largest MRR; ties: largest stability reserve, "
                          "then largest limit over the speed range)"),
                   vmin=-180.0, vmax=180.0, fig=fig)
