"""Check a planned toolpath point by point: chatter, surface location error, force, power, pose.

For every point of a :class:`~planner.toolpath.Toolpath` (``robomill check``, cli.md):

1. **the model**: the modal model at the point's robot pose, interpolated between the identified
   poses (:class:`planner.poses.PoseModels`); a pose outside their span is a ``pose_out_of_range``
   violation and is still evaluated, with the model at the nearest point of the span (held, not
   extrapolated). With a single model every point uses it and the pose is not checked (a warning
   says so).
2. **the cut frame**: feed ``f`` along the path (:meth:`Toolpath.feed_directions`, projected onto the
   plane normal to the tool axis ``a``), ``n = a x f`` (formats.md).
3. **stability** at the point's spindle speed: the limit depth by the zero-order approximation
   (Altintas & Budak, CIRP Annals 44(1), 1995) or by semi-discretization (Insperger & Stepan, 2004;
   :mod:`stability.sdm`). The point's **stability margin** is ``depth_limit / planned depth`` (> 1:
   stable); a ``chatter`` violation is a planned depth above ``limits.stability_margin`` times the
   limit (the whole limit when no margin is given). For a chatter violation, the **nearest stable
   spindle speed**: the speed closest to the planned one, inside ``limits.spindle_rpm`` (else within
   half to twice the planned speed), at which the planned depth passes that test.
4. **forced vibration** of the stable cut (Schmitz & Mann, IJMTM 46, 2006; :mod:`stability.forced`):
   surface location error at the tool tip and its largest magnitude on the whole finished wall
   (formats.md bounds the wall, not the tip alone), largest resultant force in the cut plane, mean
   cutting power and mean cutting torque over a revolution; ``surface_error`` (on the wall),
   ``force``, ``power`` and ``torque`` violations against ``limits`` (the torque and power limits bound the MEAN over a
   revolution, formats.md; ``torque`` is robomill's extension of cli.md's kinds). They are
   evaluated at every point, also where the cut chatters (where they describe the forced part only).

The speed, depth and feed ranges of :class:`~stability.setup.Limits` are planning bounds, not
violation kinds of cli.md; they are not checked here.

How the work is shared (results are those of :func:`stability.lobes.predict_point` at each point)
----------------------------------------------------------------------------------------------
* Joint angles are rounded to ``pose_resolution_deg`` (0.01 deg) and feed/tool-axis directions to
  ``direction_resolution_deg`` (0.01 deg, component-wise) before anything is computed; every point
  is evaluated at its rounded pose and frame, so equal keys give equal results whatever the order
  of the points. Directions along the machine axes are not changed by the rounding. Pass ``0`` for
  exact values (one evaluation per distinct pose and direction).
* Distinct modal models (after rounding) x cut frames x radial engagement x milling mode form a
  *structure group*, whose limits at all its speeds, and nearest stable speeds, are solved together
  (:mod:`planner.check_stability`).
* Forces, torque and the surface location error: exact force harmonics and the receptance at the
  tooth-passing harmonics, for all distinct (model, frame, force shape, speed) at once
  (:mod:`planner.check_forces`).

Caching is by these keys within one call; :attr:`ToolpathCheck.evaluations` counts what was
computed. ``method='sdm'`` computes one semi-discretization limit per distinct (structure group,
speed) through :func:`stability.lobes.lobe_diagram` (seconds each) and finds the nearest stable
speed on a 200-speed SDM lobe diagram refined by bisection: use it on short paths.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from oma._arrays import readonly as _ro
from oma.cutting import Cut
from oma.modal import ModalModel
from stability.oriented import average_directional_matrix
from stability.setup import Limits

from .check_forces import force_shapes, surface_errors
from .check_stability import stability_sdm, stability_zoa
from .poses import model_list
from .toolpath import Toolpath

__all__ = ["ToolpathCheck", "check_toolpath", "VIOLATION_KINDS", "MODEL_KINDS", "ROBOT_KINDS", "METHODS"]

#: Violation kinds (cli.md), in the order they are listed for one point.
VIOLATION_KINDS = ("unreachable", "joint_limit", "singularity", "chatter", "surface_error", "force", "power",
                   "torque", "pose_out_of_range")
#: The kinds a check with identified models can flag, and those of a check with a robot (cli.md).
MODEL_KINDS = ("chatter", "surface_error", "force", "power", "torque", "pose_out_of_range")
ROBOT_KINDS = ("unreachable", "joint_limit", "singularity", "chatter", "surface_error", "force", "power", "torque")
METHODS = ("zoa", "sdm")

_TWO_PI = 2.0 * math.pi
#: Without an rpm range in the limits, the nearest stable speed is searched in this factor range.
_DEFAULT_RPM_FACTORS = (0.5, 2.0)


# ================================================================================ result type

def _json_float(x):
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True, eq=False)
class ToolpathCheck:
    """Result of :func:`check_toolpath`: per-point predictions and the violations.

    Attributes
    ----------
    method : str
        ``'zoa'`` or ``'sdm'``.
    positions_m : ndarray, shape (n_points, 3)
        Tool-tip positions, machine frame, m.
    spindle_rpm, axial_depth_m : ndarray, shape (n_points,)
        The planned speed (rpm) and depth (m).
    depth_limit_m : ndarray, shape (n_points,)
        Stability limit depth at the planned speed, m (``inf``: no lobe reaches the speed).
    stability_margin : ndarray, shape (n_points,)
        ``depth_limit_m / axial_depth_m``: above 1 stable, below 1 chatter.
    chatter_frequency_hz : ndarray, shape (n_points,)
        Frequency of the limiting lobe, Hz (NaN where none).
    surface_location_error_m : ndarray, shape (n_points,)
        Forced-vibration surface location error at the tool tip, m (positive: material left on).
    wall_surface_error_m : ndarray, shape (n_points,)
        Largest ``|SLE|`` on the whole finished wall (heights 0 to the depth), m: what
        ``limits.surface_location_error_m`` bounds (formats.md); ``>= |surface_location_error_m|``.
    surface_error_height_m : ndarray, shape (n_points,)
        Height above the tool tip at which that largest ``|SLE|`` is, m.
    peak_force_N : ndarray, shape (n_points,)
        Largest resultant force in the cut plane over a revolution, N.
    power_W : ndarray, shape (n_points,)
        Mean cutting power, W.
    mean_torque_N_m : ndarray, shape (n_points,)
        Mean cutting torque over a revolution, N m (what ``limits.spindle_torque_N_m`` bounds).
    in_span : ndarray of bool, shape (n_points,)
        The pose lies in the span of the identified poses (always True with one model); with a
        robot: the pose is one the calibration covers (``robot calibrate``'s trust rule; True when
        the robot has no calibration record, which a note says).
    nearest_stable_rpm : ndarray, shape (n_points,)
        At chatter violations: the nearest spindle speed at which the planned depth passes the
        chatter test (NaN if none in the range); NaN elsewhere.
    violations : tuple of dict
        ``{index, kind, value, limit}`` (cli.md) in point order, kinds in :data:`VIOLATION_KINDS`
        order. With a robot (see :mod:`planner.robot.path`): ``unreachable`` (distance of the
        target from the nearest reachable one is not known: value 1, limit 0), ``joint_limit``
        (the joint furthest outside its range: how far, deg, limit 0), ``singularity`` (the
        singularity measure and its threshold). ``chatter``: planned depth and allowed depth (margin x limit), m, plus
        ``depth_limit_m`` and ``nearest_stable_rpm``; ``surface_error``: the largest ``|SLE|`` on
        the finished wall and the allowed value, m, plus ``height_m`` (where on the wall, above
        the tip); ``force``: N; ``power``: W; ``torque``: mean torque, N m; ``pose_out_of_range``: distance to the identified span
        and the tolerance exceeded (along the span or across it), degrees, plus ``beyond_range``.
    limits : Limits
        The limits checked against.
    allowed_fraction : float
        Fraction of the limit depth that may be planned (``limits.stability_margin`` or 1).
    evaluations : dict
        How much was computed (caching): ``points``, ``models`` (distinct modal models after
        rounding the poses), ``frames``, ``structure_groups`` (frequency grids of the stability
        computation), ``limits`` (speed solves), ``nearest_stable`` (searches), ``force_shapes``,
        ``forced_groups``.
    notes : tuple of str
        What the user should know about how the result was obtained.
    kinds : tuple of str
        The violation kinds this check could flag (:data:`MODEL_KINDS` or :data:`ROBOT_KINDS`).
    joints_deg : ndarray, shape (n_points, 6), or None
        With a robot: the joint angles of each point (given or from inverse kinematics), deg; NaN
        where unreachable.
    """

    method: str
    positions_m: np.ndarray
    spindle_rpm: np.ndarray
    axial_depth_m: np.ndarray
    depth_limit_m: np.ndarray
    stability_margin: np.ndarray
    chatter_frequency_hz: np.ndarray
    surface_location_error_m: np.ndarray
    wall_surface_error_m: np.ndarray
    surface_error_height_m: np.ndarray
    peak_force_N: np.ndarray
    power_W: np.ndarray
    mean_torque_N_m: np.ndarray
    in_span: np.ndarray
    nearest_stable_rpm: np.ndarray
    violations: tuple
    limits: Limits = Limits()
    allowed_fraction: float = 1.0
    evaluations: dict = field(default_factory=dict)
    notes: tuple = ()
    kinds: tuple = MODEL_KINDS
    joints_deg: np.ndarray | None = None

    @property
    def n_points(self) -> int:
        return int(self.positions_m.shape[0])

    @property
    def ok(self) -> bool:
        """No violation at any point."""
        return not self.violations

    def counts(self) -> dict:
        """Number of violations of each kind."""
        out = {k: 0 for k in self.kinds}
        for v in self.violations:
            out[v["kind"]] += 1
        return out

    def flagged(self, kind: str) -> np.ndarray:
        """Boolean mask, shape (n_points,), of the points with a violation of ``kind``."""
        if kind not in VIOLATION_KINDS:
            raise ValueError(f"kind must be one of {', '.join(map(repr, VIOLATION_KINDS))}, found {kind!r}")
        mask = np.zeros(self.n_points, dtype=bool)
        mask[[v["index"] for v in self.violations if v["kind"] == kind]] = True
        return mask

    def to_dict(self, *, per_point: bool = False) -> dict:
        """JSON-ready mapping: ``points`` (count) and ``violations`` (cli.md), with ``method``,
        ``ok``, ``counts``, ``min_stability_margin``, ``allowed_fraction``, ``evaluations``, ``notes``;
        with ``per_point`` also every per-point array (``None`` for inf/NaN)."""
        finite = self.stability_margin[np.isfinite(self.stability_margin)]
        out = {
            "points": self.n_points,
            "violations": [{k: (_json_float(v) if isinstance(v, float) else v) for k, v in item.items()}
                           for item in self.violations],
            "method": self.method,
            "ok": self.ok,
            "counts": self.counts(),
            "min_stability_margin": _json_float(finite.min()) if finite.size else None,
            "allowed_fraction": self.allowed_fraction,
            "evaluations": dict(self.evaluations),
            "notes": list(self.notes),
        }
        if per_point:
            for name in ("depth_limit_m", "stability_margin", "chatter_frequency_hz", "surface_location_error_m",
                         "wall_surface_error_m", "surface_error_height_m", "peak_force_N", "power_W",
                         "mean_torque_N_m", "nearest_stable_rpm", "spindle_rpm", "axial_depth_m"):
                out[name] = [_json_float(x) for x in getattr(self, name)]
            out["in_span"] = [bool(x) for x in self.in_span]
            if self.joints_deg is not None:
                out["joints_deg"] = [[_json_float(x) for x in row] for row in self.joints_deg]
        return out

    def plot(self, ax=None, **kwargs):
        """The path in the x-y plane coloured by stability margin, violations marked (see
        :func:`planner.check_plots.plot_toolpath_check`)."""
        from .check_plots import plot_toolpath_check

        return plot_toolpath_check(self, ax=ax, **kwargs)


# ================================================================================= the check
def _groups(*columns):
    """Distinct rows of the stacked columns (exact equality): the index of each group's first row
    (groups in lexicographic order) and the group of every row. A lexicographic sort and a
    comparison of neighbours, several times faster than ``np.unique(axis=0)`` on float rows."""
    key = np.column_stack([np.asarray(c, dtype=float) for c in columns])
    order = np.lexsort(key.T[::-1])
    ks = key[order]
    new = np.empty(key.shape[0], dtype=bool)
    new[:1] = True
    np.any(ks[1:] != ks[:-1], axis=1, out=new[1:])
    inverse = np.empty(key.shape[0], dtype=int)
    inverse[order] = np.cumsum(new) - 1
    return order[new], inverse


def _quantise(x, resolution):
    return np.round(x / resolution) * resolution if resolution > 0 else np.asarray(x, dtype=float)


@dataclass(frozen=True)
class _Models:
    """Distinct modal models (stacked parameters) and each point's model."""

    fn: np.ndarray  # (n_models, n_modes)
    zeta: np.ndarray
    stiff: np.ndarray
    dirs: np.ndarray  # (n_models, n_modes, 3)
    res: np.ndarray  # (n_models, 3, 3)
    index: np.ndarray  # (n_points,)
    in_span: np.ndarray
    beyond: np.ndarray
    distance_deg: np.ndarray
    span_tol_deg: float
    hull_tol_deg: float

    def model(self, i: int) -> ModalModel:
        return ModalModel(self.fn[i], self.zeta[i], self.stiff[i], self.dirs[i], residual_compliance_m_N=self.res[i])


def _pose_models(toolpath: Toolpath, models: Sequence[ModalModel], resolution: float, notes: list) -> _Models:
    n = toolpath.n_points
    if len(models) == 1:
        m = models[0]
        warnings.warn("one modal model given: every point uses it and the robot pose is not checked "
                      "(pose_out_of_range cannot be flagged)", stacklevel=3)
        notes.append("one modal model: used at every point; poses not checked")
        return _Models(m.natural_frequency_hz[None], m.damping_ratio[None], m.stiffness_N_m[None],
                       m.directions[None], m.residual_compliance_m_N[None], np.zeros(n, dtype=int),
                       np.ones(n, dtype=bool), np.zeros(n, dtype=bool), np.zeros(n), np.inf, np.inf)
    from .poses import PoseModels

    poses = PoseModels.fit(models)
    joints = np.asarray(toolpath.joints_deg, dtype=float)
    exact = poses.evaluate(joints)  # the span test at the exact poses
    if resolution > 0:
        rounded = _quantise(joints, resolution)
        first, inverse = _groups(*rounded.T)
        ev = poses.evaluate(rounded[first])
    else:
        ev, inverse = exact, np.arange(n)
    m = ev.natural_frequency_hz.shape[1]
    params = np.hstack([ev.natural_frequency_hz, ev.damping_ratio, ev.stiffness_N_m,
                        ev.directions.reshape(-1, 3 * m), ev.residual_compliance_m_N.reshape(-1, 9)])
    first, model_of = _groups(*params.T)
    out = ~exact.in_span
    if out.any():
        notes.append(f"{int(out.sum())} point(s) outside the span of the identified poses: flagged "
                     "pose_out_of_range and evaluated with the model at the nearest point of the span")
    return _Models(ev.natural_frequency_hz[first], ev.damping_ratio[first], ev.stiffness_N_m[first],
                   ev.directions[first], ev.residual_compliance_m_N[first], model_of.reshape(-1)[inverse],
                   exact.in_span.copy(), exact.beyond_range.copy(), exact.distance_deg.copy(),
                   poses.span_tol_deg, poses.hull_tol_deg)


def _frames(toolpath: Toolpath, resolution_rad: float):
    """Rounded unit feed directions and tool axes, (n, 3) each, and the rows ``f, n, a``."""
    a = np.broadcast_to(np.asarray(toolpath.tool_axis, dtype=float), toolpath.positions_m.shape)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    f = np.asarray(toolpath.feed_directions(), dtype=float)
    f = f - np.sum(f * a, axis=1, keepdims=True) * a  # feed in the plane of the cut
    length = np.linalg.norm(f, axis=1)
    bad = np.flatnonzero(~(length > 1e-9))
    if bad.size:
        raise ValueError(f"point {bad[0]}: no feed direction across the tool axis (the path runs along the "
                         "tool axis, a plunge, or two points coincide); side-milling checks need one")
    f = f / length[:, None]
    if resolution_rad > 0:
        a = _quantise(a, resolution_rad)
        a = a / np.linalg.norm(a, axis=1, keepdims=True)
        f = _quantise(f, resolution_rad)
        f = f - np.sum(f * a, axis=1, keepdims=True) * a
        f = f / np.linalg.norm(f, axis=1, keepdims=True)
    return f, a


def _limits_fraction(limits: Limits) -> float:
    frac = 1.0 if limits.stability_margin is None else float(limits.stability_margin)
    if not (math.isfinite(frac) and frac > 0):
        raise ValueError(f"limits.stability_margin must be a positive fraction, found {limits.stability_margin!r}")
    return frac


def _rpm_range(limits: Limits, rpm: np.ndarray):
    if limits.spindle_rpm is not None:
        lo, hi = (float(v) for v in limits.spindle_rpm)
        return np.full(rpm.shape, lo), np.full(rpm.shape, hi)
    return rpm * _DEFAULT_RPM_FACTORS[0], rpm * _DEFAULT_RPM_FACTORS[1]


def check_toolpath(toolpath: Toolpath, models: Sequence[ModalModel] | None = None, *,
                   method: Literal["zoa", "sdm"] = "zoa", limits: Limits | None = None, progress: bool = False,
                   pose_resolution_deg: float | None = None, direction_resolution_deg: float = 0.01,
                   n_freq: int = 10_000, robot=None, tool_model: ModalModel | None = None,
                   singularity_threshold: float | None = None) -> ToolpathCheck:
    """Check every point of a toolpath for chatter, surface error, force, power and pose range.

    Parameters
    ----------
    toolpath : Toolpath
        The planned path (positions, poses, speeds, engagements), SI units.
    models : sequence of ModalModel, optional
        Modal models at identified poses (each with ``joints_deg``), interpolated along the path
        (:class:`planner.poses.PoseModels`); or a single model used at every point. Not with
        ``robot``.
    method : {'zoa', 'sdm'}
        Stability limit by the zero-order approximation or by semi-discretization (slow).
    limits : Limits, optional
        Default ``toolpath.limits``. Used: ``stability_margin`` (allowed fraction of the limit
        depth), ``spindle_rpm`` (range of the nearest-stable-speed search), ``max_force_N``,
        ``spindle_power_W``, ``surface_location_error_m`` (on the largest ``|SLE|`` on the
        finished wall).
    progress : bool
        Show a progress bar (tqdm, on standard error).
    pose_resolution_deg : float, optional
        Joint angles are rounded to this before the model is evaluated (0: exact), degrees.
        Default 0.01 with models, :data:`planner.robot.path.POSE_RESOLUTION_DEG` with a robot.
    direction_resolution_deg : float
        Components of the feed direction and tool axis are rounded to this many radians' worth
        (0: exact), degrees.
    n_freq : int
        Chatter-frequency grid of the ZOA (as :func:`stability.zoa.default_chatter_frequencies`).
    robot : planner.robot.Robot, optional
        A calibrated robot (with joint stiffness) instead of ``models``: the joints of every point
        from the path (given, or by inverse kinematics, :func:`planner.robot.path.solve_path`) and
        the robot's modal model at each (:func:`planner.robot.robot_modes`); adds the kinds
        ``unreachable``, ``joint_limit`` and ``singularity``.
    tool_model : ModalModel, optional
        With ``robot``: pose-independent spindle/tool modes, in series with the robot's.
    singularity_threshold : float, optional
        With ``robot``: see :func:`planner.robot.path.solve_path`.

    Returns
    -------
    ToolpathCheck

    Raises
    ------
    ValueError
        Unknown method, no models, no cutting coefficients, a point whose feed runs along the tool
        axis, a bad resolution.
    oma.errors.ModelError
        Several models, one without a pose.

    Warns
    -----
    UserWarning
        A single model: the pose cannot be checked.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, found {method!r}")
    if (models is None) == (robot is None):
        raise ValueError("give either models or a robot")
    toolpath = toolpath.in_machine_frame()
    if robot is None:
        models = model_list(models)
        if not toolpath.has_joints:
            raise ValueError("the toolpath has no joint angles at some points: check it with a robot")
        if pose_resolution_deg is None:
            pose_resolution_deg = 0.01
    elif pose_resolution_deg is None:
        from .robot.path import POSE_RESOLUTION_DEG

        pose_resolution_deg = POSE_RESOLUTION_DEG
    coefficients = toolpath.material.cutting_coefficients
    if coefficients is None:
        raise ValueError("toolpath.material has no cutting coefficients: the forces cannot be predicted")
    for name, value in (("pose_resolution_deg", pose_resolution_deg),
                        ("direction_resolution_deg", direction_resolution_deg)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a number >= 0, found {value!r}")
    if int(n_freq) < 2:
        raise ValueError(f"n_freq must be at least 2, found {n_freq!r}")
    limits = toolpath.limits if limits is None else limits
    fraction = _limits_fraction(limits)
    tool = toolpath.tool
    notes: list[str] = []
    counts = {"points": toolpath.n_points, "models": 0, "frames": 0, "structure_groups": 0, "limits": 0,
              "nearest_stable": 0, "force_shapes": 0, "forced_groups": 0}

    extra, joints_used = {}, None
    if robot is None:
        pm = _pose_models(toolpath, models, float(pose_resolution_deg), notes)
    else:
        from .robot.path import robot_point_models

        pm, extra, joints_used = robot_point_models(robot, toolpath, tool_model=tool_model,
                                                    resolution_deg=float(pose_resolution_deg), notes=notes,
                                                    singularity_threshold=singularity_threshold, counts=counts)
    f, a = _frames(toolpath, math.radians(direction_resolution_deg))
    frame_first, frame_id = _groups(*f.T, *a.T)
    fr = f[frame_first]
    ar = a[frame_first]
    frames = np.stack([fr, np.cross(ar, fr), ar], axis=1)  # rows f, n = a x f, a
    counts["models"], counts["frames"] = int(pm.fn.shape[0]), int(frame_first.size)

    rpm = np.asarray(toolpath.spindle_rpm, dtype=float)
    depth = np.asarray(toolpath.axial_depth_m, dtype=float)
    ae = np.asarray(toolpath.radial_depth_m, dtype=float)
    fz = np.asarray(toolpath.feed_per_tooth_m, dtype=float)
    down = np.asarray(toolpath.milling) == "down"

    # ---- stability: structure groups (model, frame, engagement) and their queries (speed, depth)
    eng_first, eng_id = _groups(ae, down)
    b0 = np.stack([average_directional_matrix(tool, Cut(fz[i], ae[i], "down" if down[i] else "up", [1, 0, 0],
                                                        [0, 1, 0]), coefficients) for i in eng_first])
    sg_first, sg_id = _groups(pm.index, frame_id, eng_id)
    lo, hi = _rpm_range(limits, rpm)
    thr = depth / fraction
    q_first, q_id = _groups(sg_id, rpm, thr, lo, hi)
    q_near = np.ones(q_first.size, dtype=bool)
    args = (sg_id[q_first], rpm[q_first], thr[q_first], lo[q_first], hi[q_first], q_near)
    if method == "zoa":
        q_depth, q_freq, q_nearest = stability_zoa(tool, pm, frames, b0, pm.index[sg_first], frame_id[sg_first],
                                                    eng_id[sg_first], *args, int(n_freq), progress, counts)
    else:
        sg_cut = [(fz[i], ae[i], "down" if down[i] else "up") for i in sg_first]
        q_depth, q_freq, q_nearest = stability_sdm(tool, coefficients, pm, frames, pm.index[sg_first],
                                                    frame_id[sg_first], sg_cut, *args, progress, counts)
    depth_limit, chatter_freq, nearest = q_depth[q_id], q_freq[q_id], q_nearest[q_id]
    chatter = depth_limit < thr
    nearest = np.where(chatter, nearest, np.nan)

    # ---- forced vibration: force shapes (engagement, feed, depth) and forced groups
    fmax = pm.fn.max(axis=1)  # harmonic count of stability.forced.default_harmonics
    harm = np.minimum(2000, np.maximum(32, np.ceil(4.0 * fmax[pm.index] / (tool.teeth * rpm / 60.0)))).astype(int)
    feng_first, feng_id = _groups(ae, down, fz)
    shape_first, shape_id = _groups(feng_id, depth)
    n_shapes = shape_first.size
    h_max = int(harm.max())
    unit_h = np.empty((feng_first.size, 3, h_max + 1), dtype=complex)
    shape_torque, shape_peak = np.empty(n_shapes), np.empty(n_shapes)
    for e, i in enumerate(feng_first):
        mine = np.flatnonzero(feng_id[shape_first] == e)
        cut = Cut(fz[i], ae[i], "down" if down[i] else "up", [1, 0, 0], [0, 1, 0])
        unit_h[e], shape_torque[mine], shape_peak[mine] = force_shapes(tool, coefficients, cut,
                                                                        depth[shape_first[mine]], h_max)
    counts["force_shapes"] = int(n_shapes)
    fg_first, fg_id = _groups(pm.index, frame_id, shape_id, rpm)
    counts["forced_groups"] = int(fg_first.size)
    sle, wall, wall_z = (v[fg_id] for v in surface_errors(
        tool, pm, frames, unit_h, pm.index[fg_first], frame_id[fg_first], feng_id[fg_first], depth[fg_first],
        rpm[fg_first], harm[fg_first], np.where(down[fg_first], 1.0, -1.0)))
    peak = shape_peak[shape_id]
    mean_torque = shape_torque[shape_id]
    power = mean_torque * _TWO_PI * rpm / 60.0

    # ---- violations
    if "unreachable" in extra:  # no pose: no robot model, no stability or surface error there
        lost = extra["unreachable"][0]
        depth_limit, chatter_freq, sle, wall, wall_z = (np.where(lost, np.nan, a) for a in
                                                        (depth_limit, chatter_freq, sle, wall, wall_z))
        chatter = chatter & ~lost
        nearest = np.where(lost, np.nan, nearest)
    with np.errstate(divide="ignore", invalid="ignore"):
        margin = depth_limit / depth
    found = {k: np.zeros(toolpath.n_points, dtype=bool) for k in VIOLATION_KINDS}
    for kind, (mask, _, _) in extra.items():
        found[kind] = mask
    found["chatter"] = chatter
    if limits.surface_location_error_m is not None:
        found["surface_error"] = wall > limits.surface_location_error_m  # on the whole finished wall
    if limits.max_force_N is not None:
        found["force"] = peak > limits.max_force_N
    if limits.spindle_power_W is not None:
        found["power"] = power > limits.spindle_power_W
    if limits.spindle_torque_N_m is not None:
        found["torque"] = mean_torque > limits.spindle_torque_N_m
    if robot is None:  # with a robot, in_span is the calibration's trust: a note, not a violation
        found["pose_out_of_range"] = ~pm.in_span
    violations = []
    for i in np.flatnonzero(np.any(np.stack(list(found.values())), axis=0)):
        i = int(i)
        for kind in ("unreachable", "joint_limit", "singularity"):
            if found[kind][i]:
                violations.append({"index": i, "kind": kind, "value": float(extra[kind][1][i]),
                                   "limit": float(extra[kind][2])})
        if found["chatter"][i]:
            violations.append({"index": i, "kind": "chatter", "value": float(depth[i]),
                               "limit": float(fraction * depth_limit[i]), "depth_limit_m": float(depth_limit[i]),
                               "nearest_stable_rpm": float(nearest[i])})
        if found["surface_error"][i]:
            violations.append({"index": i, "kind": "surface_error", "value": float(wall[i]),
                               "limit": float(limits.surface_location_error_m), "height_m": float(wall_z[i])})
        if found["force"][i]:
            violations.append({"index": i, "kind": "force", "value": float(peak[i]),
                               "limit": float(limits.max_force_N)})
        if found["power"][i]:
            violations.append({"index": i, "kind": "power", "value": float(power[i]),
                               "limit": float(limits.spindle_power_W)})
        if found["torque"][i]:
            violations.append({"index": i, "kind": "torque", "value": float(mean_torque[i]),
                               "limit": float(limits.spindle_torque_N_m)})
        if found["pose_out_of_range"][i]:
            violations.append({"index": i, "kind": "pose_out_of_range", "value": float(pm.distance_deg[i]),
                               "limit": float(pm.hull_tol_deg if pm.beyond[i] else pm.span_tol_deg),
                               "beyond_range": bool(pm.beyond[i])})
    if pose_resolution_deg > 0 and (robot is not None or len(models) > 1):
        notes.append(f"models evaluated at the poses rounded to {pose_resolution_deg:g} deg")
    if direction_resolution_deg > 0:
        notes.append(f"cut frames evaluated with directions rounded to {direction_resolution_deg:g} deg")
    return ToolpathCheck(
        method=method, positions_m=_ro(toolpath.positions_m), spindle_rpm=_ro(rpm), axial_depth_m=_ro(depth),
        depth_limit_m=_ro(depth_limit), stability_margin=_ro(margin), chatter_frequency_hz=_ro(chatter_freq),
        surface_location_error_m=_ro(sle), wall_surface_error_m=_ro(wall), surface_error_height_m=_ro(wall_z),
        peak_force_N=_ro(peak), power_W=_ro(power), mean_torque_N_m=_ro(mean_torque),
        in_span=_ro(pm.in_span, bool),
        nearest_stable_rpm=_ro(nearest), violations=tuple(violations), limits=limits, allowed_fraction=fraction,
        evaluations=counts, notes=tuple(notes), kinds=MODEL_KINDS if robot is None else ROBOT_KINDS,
        joints_deg=None if joints_used is None else _ro(joints_used),
    )
