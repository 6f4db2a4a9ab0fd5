"""What every chunk of an atlas shares: the robot, the cut in the machine frame, the speed grid and
the depth bounds of the setup's limits, as one frozen, picklable :class:`AtlasProblem`.

The depth bounds that do not depend on the pose are computed here once (:mod:`planner.cut_model`):

* the mean cutting torque per unit depth ``tau = tau_c fz + tau_e`` (formats.md: the spindle's
  torque and power limits bound the MEAN over a revolution), so ``ap <= T_max / tau`` and, at speed
  ``n``, ``ap <= 60 P_max / (2 pi n tau)``;
* the largest depth whose peak resultant force stays within ``max_force_N`` (rigid-tool forces,
  speed- and pose-independent: :meth:`planner.cut_model.CutModel.depth_boundary`).

The feed per tooth is the upper feed bound (or the setup's feed without one): the stability limit
does not depend on it (linear force model), and under the torque, power and force bounds the rate
``ap fz`` they allow, ``fz L / (c fz + e)`` with ``c, e >= 0`` (cutting and edge parts), grows with
``fz``; so the fastest stable cut is always at the largest feed. (With a helix the peak force is
not exactly linear in depth; the bound is still computed exactly at that feed.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from oma._arrays import readonly as _ro
from oma.errors import InputError
from planner.robot.ik import SINGULARITY_THRESHOLD

__all__ = ["AtlasProblem", "build_problem"]


@dataclass(frozen=True)
class AtlasProblem:
    """Plain inputs of :func:`planner.atlas.evaluate.evaluate_chunk` (SI units)."""

    robot: object
    tool_axis: np.ndarray  # (3,) machine frame, tip into spindle
    feed_direction: np.ndarray  # (3,) machine frame
    cut_frame: np.ndarray  # (3, 3) rows f, n, a (machine frame)
    b0: np.ndarray  # (3, 2) average directional matrix per unit depth, N/m^2
    rotations_rad: np.ndarray
    rpm_grid: np.ndarray
    teeth: int
    feed_per_tooth_m: float
    ap_lo_m: float
    ap_hi_m: float  # the speed-independent depth bound
    ap_hi_code: int  # 1 depth_max, 2 force, 3 torque
    power_depth_rpm: float  # ap * n <= this (power); inf without a power limit
    margin: float
    mrr_per_depth_rpm: float  # MRR = this * ap * n
    torque_per_depth_N: float  # mean torque = this * ap
    n_freq: int = 500
    min_tip_fraction: float = 1e-3
    singularity_threshold: float = SINGULARITY_THRESHOLD
    tool_modes: dict | None = None
    tool: object = None  # oma.cutting.Tool
    cut_machine: object = None  # oma.cutting.Cut, directions in the machine frame
    coefficients: object = None  # oma.cutting.CuttingCoefficients

    @property
    def immersion(self) -> float:
        """Radial immersion ``ae / D``."""
        return float(self.cut_machine.radial_depth_m) / float(self.tool.diameter_m)

    def to_dict(self) -> dict:
        return {"tool_axis": self.tool_axis.tolist(), "feed_direction": self.feed_direction.tolist(),
                "rotations_deg": np.degrees(self.rotations_rad).tolist(),
                "rpm_range": [float(self.rpm_grid[0]), float(self.rpm_grid[-1])], "n_rpm": int(self.rpm_grid.size),
                "feed_per_tooth_m": self.feed_per_tooth_m, "axial_depth_range_m": [self.ap_lo_m, self.ap_hi_m],
                "depth_bound": {1: "depth_max", 2: "force", 3: "torque"}[self.ap_hi_code],
                "stability_margin": self.margin, "n_freq": self.n_freq, "min_tip_fraction": self.min_tip_fraction,
                "singularity_threshold": self.singularity_threshold, "tool_modes": self.tool_modes is not None}


def _limits_error(setup_file, field, found="none"):
    return InputError(setup_file, field, "a bound for the atlas (the setup's limits section)", found)


def build_problem(robot, setup, region, *, setup_file=None, rpm_range=None, n_rpm: int = 300, n_freq: int = 500,
                  tool_model=None, min_tip_fraction: float = 1e-3,
                  singularity_threshold: float = SINGULARITY_THRESHOLD) -> AtlasProblem:
    """The :class:`AtlasProblem` of a robot, a setup and a region.

    Parameters
    ----------
    robot : planner.robot.Robot
        With joint stiffness.
    setup : stability.setup.Setup
        Tool, cut (feed and normal directions in the workpiece frame), material with cutting
        coefficients, and limits: ``spindle_rpm`` (unless ``rpm_range`` is given) and
        ``axial_depth_m`` are required; ``feed_per_tooth_m``, ``spindle_power_W``,
        ``spindle_torque_N_m``, ``max_force_N`` and ``stability_margin`` are used when given.
    region : planner.atlas.grid.Region
    setup_file : path, optional
        Named in error messages.
    rpm_range : (float, float), optional
        Overrides ``limits.spindle_rpm``.
    n_rpm : int
        Speeds of the log-spaced grid over the range.
    n_freq : int
        ZOA chatter-frequency grid per pose.
    tool_model : oma.modal.ModalModel, optional
        Pose-independent spindle/tool modes, in series with the robot's (machine-frame directions).
    min_tip_fraction, singularity_threshold : float
        See :mod:`planner.atlas.evaluate`.

    Raises
    ------
    oma.errors.InputError
        A setup without the limits the atlas needs, without cutting coefficients, or a robot without
        joint stiffness.
    """
    from oma.cutting import Cut
    from planner.cut_model import CutModel
    from stability.oriented import average_directional_matrix

    limits = setup.limits
    if setup.material.cutting_coefficients is None:
        raise InputError(setup_file, "material.cutting_coefficients", "cutting coefficients", "none")
    if robot.joint_stiffness_N_m_rad is None:
        raise InputError(robot.file, "joints.stiffness_N_m_rad", "joint stiffness (a calibrated robot)", "none")
    if rpm_range is None:
        if limits.spindle_rpm is None:
            raise _limits_error(setup_file, "limits.spindle_rpm")
        rpm_range = limits.spindle_rpm
    lo, hi = (float(v) for v in rpm_range)
    if not (0 < lo < hi and math.isfinite(hi)):
        raise InputError(setup_file, "limits.spindle_rpm", "0 < MIN < MAX", f"{lo} {hi}")
    if limits.axial_depth_m is None:
        raise _limits_error(setup_file, "limits.axial_depth_m")
    ap_lo, ap_hi = (float(v) for v in limits.axial_depth_m)
    fz = float(limits.feed_per_tooth_m[1]) if limits.feed_per_tooth_m is not None else float(setup.cut.feed_per_tooth_m)
    margin = 1.0 if limits.stability_margin is None else float(limits.stability_margin)
    if int(n_rpm) < 2 or int(n_freq) < 2:
        raise InputError(None, "--n-rpm", "at least 2 speeds and 2 chatter frequencies", f"{n_rpm}, {n_freq}")
    tool, cut, coef = setup.tool, setup.cut, setup.material.cutting_coefficients
    model = CutModel(None, tool, cut, coef)
    tau = model.tau_c * fz + model.tau_e  # mean torque per unit depth, N m / m
    bounds = {1: ap_hi}
    if limits.max_force_N is not None:
        bounds[2] = float(model.depth_boundary(0, float(limits.max_force_N), [fz], ap_lo, ap_hi)[0])
    if limits.spindle_torque_N_m is not None:
        bounds[3] = float(limits.spindle_torque_N_m) / tau
    code = min(bounds, key=lambda c: (bounds[c], c))
    power = math.inf if limits.spindle_power_W is None else 60.0 * float(limits.spindle_power_W) / (2 * math.pi * tau)
    rot = region.rotation
    frame = np.asarray(cut.frame, float) @ rot.T  # rows f, n, a in the machine frame
    tool_modes = None
    if tool_model is not None:
        tool_modes = {"frequency_hz": _ro(np.asarray(tool_model.natural_frequency_hz, float)),
                      "damping_ratio": _ro(np.asarray(tool_model.damping_ratio, float)),
                      "stiffness_N_m": _ro(np.asarray(tool_model.stiffness_N_m, float)),
                      "directions": _ro(np.asarray(tool_model.directions, float))}
    return AtlasProblem(
        robot=robot, tool_axis=_ro(frame[2].copy()), feed_direction=_ro(frame[0].copy()), cut_frame=_ro(frame),
        b0=_ro(average_directional_matrix(tool, cut, coef)), rotations_rad=_ro(np.radians(region.rotations_deg)),
        rpm_grid=_ro(np.geomspace(lo, hi, int(n_rpm))), teeth=int(tool.teeth), feed_per_tooth_m=fz, ap_lo_m=ap_lo,
        ap_hi_m=float(bounds[code]), ap_hi_code=int(code), power_depth_rpm=power, margin=margin,
        mrr_per_depth_rpm=float(cut.radial_depth_m) * fz * tool.teeth / 60.0, torque_per_depth_N=float(tau),
        n_freq=int(n_freq), min_tip_fraction=float(min_tip_fraction),
        singularity_threshold=float(singularity_threshold), tool_modes=tool_modes, tool=tool,
        cut_machine=Cut(fz, float(cut.radial_depth_m), cut.milling, frame[0], frame[1]), coefficients=coef)
