"""Plots of what ``learn`` found (matplotlib imported here only)."""

from __future__ import annotations

import numpy as np

from .likelihood import CHATTER, STABLE, UNCERTAIN

__all__ = ["plot_probability_lobes", "draw_test_cuts", "draw_best_backed", "shade_untabulated"]


def plot_probability_lobes(lobes, ax=None, *, cuts=None, mislabelled=None):
    """P(stable) over speed and depth, the 5 / 50 / 95 % contours, and the test cuts at this
    engagement (:func:`draw_test_cuts`; ``mislabelled``, each mark's posterior probability of being
    wrong, greys the stable ones it doubts). Returns (figure, axes)."""
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
    draw_test_cuts(ax, cuts, lobes.radial_depth_m, lobes.milling, mislabelled=mislabelled)
    ax.set_xlabel("spindle speed (rpm)")
    ax.set_ylabel("axial depth (mm)")
    ax.set_ylim(0, 1e3 * top)
    ax.set_title(f"posterior stability, a_e = {1e3 * lobes.radial_depth_m:.2f} mm, {lobes.milling} milling")
    ax.legend(loc="upper left", fontsize=8)
    return fig, ax


def draw_test_cuts(ax, cuts, radial_depth_m: float, milling: str, *, mislabelled=None,
                   max_doubt: float | None = None) -> None:
    """The test ``cuts`` at an engagement (radial depth within :data:`.support.RADIAL_TOLERANCE`,
    the milling direction) on depth (mm) over speed (rpm) axes: o stable, x chatter, ? uncertain;
    a stable mark the posterior doubts (``mislabelled`` above ``max_doubt``, by default its suspect
    level: more likely wrong than right) in grey."""
    from .support import at_engagement, doubted_marks
    from .update import SUSPECT_LABEL

    if cuts is None or not cuts.n_cuts:
        return
    name = "stable, taken for wrong" if max_doubt is None else f"stable, doubted (wrong with P > {max_doubt:g})"
    same = at_engagement(cuts, radial_depth_m, milling == "down")
    doubted = doubted_marks(mislabelled, cuts.n_cuts, SUSPECT_LABEL if max_doubt is None else max_doubt)
    for sel, marker, colour, label in ((same & (cuts.outcome == STABLE) & ~doubted, "o", "k", "stable"),
                                      (same & (cuts.outcome == STABLE) & doubted, "o", "0.6", name),
                                      (same & (cuts.outcome == CHATTER), "x", "k", "chatter"),
                                      (same & (cuts.outcome == UNCERTAIN), "$?$", "k", "uncertain")):
        if sel.any():
            ax.scatter(cuts.spindle_rpm[sel], 1e3 * cuts.axial_depth_m[sel], marker=marker, c=colour, s=30,
                       label=f"test cut: {label}", zorder=4)


def shade_untabulated(ax, rpm_range, setup_rpm) -> None:
    """Grey the speeds of ``setup_rpm`` outside ``rpm_range``, where ``plan``'s chance limit was not
    tabulated (``learned.rpm_range``: no cut there could beat the plan) and reads 0."""
    lo, hi = (float(v) for v in setup_rpm)
    a, b = (float(v) for v in rpm_range)
    spans = [(x, y) for x, y in ((lo, a), (b, hi)) if y > x]
    for k, (x, y) in enumerate(spans):
        ax.axvspan(x, y, color="0.9", zorder=0, label="_nolegend_" if k else "not tabulated: no cut there beats the plan")


def draw_best_backed(ax, alt: dict | None) -> None:
    """``plan``'s best cut a stable test cut proves (``learned.support.best_backed``) as a diamond."""
    if not alt:
        return
    ax.plot([alt["spindle_rpm"]], [1e3 * alt["axial_depth_m"]], "D", color="tab:blue", mec="k", ms=9, ls="none",
            zorder=5, label=f"best cut a test proves ({1e6 * alt['mrr_m3_s']:.3g} cm$^3$/s)")
