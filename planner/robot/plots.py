"""Figures of the robot model's results (matplotlib imported here only, when a plot is asked for)."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_calibration"]


def plot_calibration(calibration, ax=None):
    """Calibrated joint stiffness with its one-sigma band (hatched: not identifiable from the
    poses) and, on a second axis, the leave-one-pose-out frequency errors.

    Returns
    -------
    (Figure, ndarray of Axes)
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    else:
        axes = np.atleast_1d(ax)
        fig = axes[0].figure
    k = calibration.joint_stiffness_N_m_rad
    sd = calibration.stiffness_sd
    joints = np.arange(1, 7)
    a0 = axes[0]
    for j, ok in zip(joints, calibration.identifiable):
        a0.bar(j, k[j - 1], color="C0" if ok else "none", edgecolor="C0", hatch=None if ok else "//")
    a0.errorbar(joints, k, yerr=[k - k * np.exp(-np.minimum(sd, 3)), k * np.exp(np.minimum(sd, 3)) - k],
                fmt="none", ecolor="k", capsize=3)
    a0.set_yscale("log")
    a0.set_xlabel("joint")
    a0.set_ylabel("stiffness (N m/rad)")
    a0.set_title("calibrated joint stiffness (hatched: not identifiable)")
    if len(axes) > 1:
        a1 = axes[1]
        loo = calibration.leave_one_out
        if loo:
            a1.bar(range(len(loo)), [100 * r["frequency_error"] for r in loo], color="C1")
            a1.set_xticks(range(len(loo)), [str(r["model"]).rsplit("/", 1)[-1] for r in loo], rotation=30,
                          ha="right", fontsize=8)
        a1.set_ylabel("frequency error (%)")
        a1.set_title("each pose predicted without it")
    fig.tight_layout()
    return fig, axes
