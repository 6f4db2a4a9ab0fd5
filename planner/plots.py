"""Plots for the planner and the demo. matplotlib is imported only inside the functions; each
function takes results, computes no physics, and returns ``(fig, ax)`` or the figure."""

from __future__ import annotations

__all__ = ["plot_record"]


def plot_record(record):
    """Forces (N) and tool-tip displacement (um) of a record against time, one row per axis."""
    import matplotlib.pyplot as plt

    t = record.time
    fig, axes = plt.subplots(3, 2, figsize=(11, 6.5), sharex=True)
    for i, axis in enumerate("XYZ"):
        if record.has("force", axis):
            axes[i, 0].plot(t, record.signal("force", axis), lw=0.6)
        axes[i, 0].set_ylabel(f"F{axis.lower()} [N]")
        if record.has("displacement", axis):
            axes[i, 1].plot(t, 1e6 * record.signal("displacement", axis), lw=0.6, color="C1")
        axes[i, 1].set_ylabel(f"{axis.lower()} [um]")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(record.name or "record")
    fig.tight_layout()
    return fig
