"""Shared inputs of the atlas tests: the example cell's robot (KR 500 R2800-2 with a 150 kg
spindle, the robot tests' file) and setup, small regions, and a serial reference run."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from robot_helpers import REPO, write_robot_file

SETUP = REPO / "examples" / "kr500_acetal" / "setup.yaml"


def robot_file(directory) -> Path:
    return write_robot_file(directory)


def small_region(step_m: float = 0.3, rotations=(-90.0, 0.0, 90.0)):
    from planner.atlas import Region

    return Region([1.5, -0.6, 0.4], [2.4, 0.6, 0.7], step_m, rotations)


def stability_bound_setup():
    """The example setup with the speed range of a robot's low-speed work (1500-6000 rpm), depths up
    to 0.5 m and no power, torque or force limit, so that the stability limit (not the spindle or the
    depth bound) decides the best cut."""
    from stability.setup_io import read_setup

    setup = read_setup(SETUP)
    return replace(setup, limits=replace(setup.limits, spindle_rpm=(1500.0, 6000.0), axial_depth_m=(0.0005, 0.5),
                                         spindle_power_W=None, spindle_torque_N_m=None, max_force_N=None))


def same_table(a: dict, b: dict) -> bool:
    """Equal columns, bit for bit (NaN equal to NaN)."""
    if a.keys() != b.keys():
        return False
    for k in a:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        if x.dtype.kind == "f":
            if not np.array_equal(x.view(np.int64), y.view(np.int64)):
                return False
        elif not np.array_equal(x, y):
            return False
    return True
