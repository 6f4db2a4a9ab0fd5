"""Toolpaths for the benchmarks, made from the example's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np


def resampled(base, n: int):
    """The path resampled to ``n`` points: positions (and joint angles, when it has them)
    interpolated, the planned cut of the nearest original point."""
    t = np.linspace(0.0, base.n_points - 1.0, n)
    k = np.arange(base.n_points)
    near = np.rint(t).astype(int)

    def interp(a):
        return None if a is None else np.column_stack([np.interp(t, k, a[:, j]) for j in range(a.shape[1])])

    return replace(base, positions_m=interp(base.positions_m), joints_deg=interp(base.joints_deg),
                   spindle_rpm=base.spindle_rpm[near], feed_per_tooth_m=base.feed_per_tooth_m[near],
                   radial_depth_m=base.radial_depth_m[near], axial_depth_m=base.axial_depth_m[near],
                   milling=base.milling[near])
