"""Choose the rotation about the tool axis along a Cartesian toolpath (``robomill posture``, cli.md).

A milling task fixes the tool tip and the tool axis; the rotation of the flange about the tool
axis is free, and with a spindle mounted off the flange axis it moves the whole arm (DOMAIN.md;
Mousavi, Gagnol, Bouzgarrou & Ray, CIRP JMST 2018, stability through the functional redundancy).
:func:`choose_posture` picks it per point to **maximise the smallest stability margin along the
path** (``depth_limit / planned depth``, :func:`planner.check.check_toolpath`), subject to

* every pose reachable, inside the joint limits and not near a singularity (the thresholds of
  :mod:`planner.robot.path`);
* **no configuration flip**: one IK branch (shoulder, elbow, wrist) for the whole path;
* **smoothness** of the flange's orientation: the DP's states are the flange angle ``theta``
  about the tool axis measured from a *fixed* reference (the machine X axis projected across the
  tool axis; Y when the tool axis is within 25 deg of X), which changes by at most one grid step
  between neighbouring stations; among the sequences that reach the best smallest margin the
  smoothest one (squared steps) is taken, larger margins breaking ties. The file's
  ``tool_rotation_deg`` (relative to the feed direction, formats.md) is ``theta + psi`` with
  ``psi`` the angle from the feed to the fixed reference: where the feed turns (a corner), the
  flange does not spin with it.

Method. The path is sampled at ``stations`` points (all points of a short path). At every station
every rotation of a grid (``n_rotations``, default 36: 10 deg) is solved by inverse kinematics for
all branches; the stability margin of every feasible (station, rotation) of the candidate branches
is computed by the check's machinery (one call, vectorised over the distinct poses). Then two
dynamic programmes over the stations (states: the grid rotations; transitions: at most one step):
a bottleneck one for the best achievable smallest margin ``M*``, and a shortest-path one for the
smoothest sequence through states with margin >= ``M*``. Local refinement: the whole sequence
shifted by fractions of a grid step (+-1/4, +-1/2), kept where the smallest station margin grows.
The stations' rotations are interpolated to every point, the joints solved there on the chosen
branch, and the path checked point by point before (the toolpath's own rotation, 0 where not
given) and after.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from oma._arrays import readonly as _ro

from ..toolpath import Toolpath
from .description import Robot
from .path import SINGULARITY_THRESHOLD, singularity_measure

__all__ = ["PostureResult", "choose_posture", "constant_rotation_margins", "feed_to_fixed_deg"]

#: Default number of stations the margins are computed at (a denser path is interpolated).
STATIONS = 64
#: Fractions of a grid step tried in the local refinement.
_REFINE = (-0.5, -0.25, 0.25, 0.5)
#: Branches evaluated for the margin (the ones feasible at most (station, rotation) states).
_MAX_BRANCHES = 2


@dataclass(frozen=True)
class PostureResult:
    """What :func:`choose_posture` chose.

    Attributes
    ----------
    toolpath : Toolpath
        The input path with ``joints_deg`` (NaN rows where unreachable) and ``tool_rotation_deg``.
    rotation_deg : ndarray, shape (n,)
        Chosen rotation about the tool axis relative to the feed (``tool_rotation_deg``), deg.
    flange_angle_deg : ndarray, shape (n,)
        The flange angle about the tool axis from the fixed reference (continuous), deg.
    branch : int
        The IK branch kept (-1: none feasible).
    margin_before, margin_after : ndarray, shape (n,)
        Stability margin per point with the toolpath's rotation (0 where not given) and with the
        chosen one (NaN where unreachable).
    min_margin_before, min_margin_after : float
        Smallest finite margins (NaN if none).
    unreachable : tuple of int
        Points with no feasible pose on the chosen branch at the chosen rotation.
    station_index : ndarray of int, shape (n_stations,)
    rotations_deg : ndarray, shape (n_rotations,)
        The grid.
    station_margin : ndarray, shape (n_stations, n_rotations)
        Margin of every state on the chosen branch (-inf: infeasible).
    evaluations : dict
    notes : tuple of str
    """

    toolpath: object
    rotation_deg: np.ndarray
    flange_angle_deg: np.ndarray
    branch: int
    margin_before: np.ndarray
    margin_after: np.ndarray
    min_margin_before: float
    min_margin_after: float
    unreachable: tuple
    station_index: np.ndarray
    rotations_deg: np.ndarray
    station_margin: np.ndarray
    evaluations: dict = field(default_factory=dict)
    notes: tuple = ()

    def __post_init__(self):
        for name in ("rotation_deg", "flange_angle_deg", "margin_before", "margin_after", "rotations_deg", "station_margin"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "station_index", _ro(self.station_index, int))

    def to_dict(self) -> dict:
        def num(x):
            return float(x) if math.isfinite(x) else None

        return {"points": int(self.rotation_deg.size), "min_margin_before": num(self.min_margin_before),
                "min_margin_after": num(self.min_margin_after), "unreachable": list(self.unreachable),
                "branch": self.branch, "flange_angle_deg_range": [num(np.nanmin(self.flange_angle_deg)),
                                                                  num(np.nanmax(self.flange_angle_deg))],
                "evaluations": dict(self.evaluations), "notes": list(self.notes)}

    def plot(self, ax=None):
        """Path coloured by margin before and after (:func:`planner.robot.posture_plots.plot_posture`)."""
        from .posture_plots import plot_posture

        return plot_posture(self, ax=ax)


@dataclass(frozen=True)
class _FixedFeed(Toolpath):
    """A toolpath whose feed directions are given per point (not from the neighbours): the check's
    input for states that are not consecutive points of a path."""

    feed: np.ndarray | None = None

    def feed_directions(self):
        return np.asarray(self.feed)


def _fixed_feed_toolpath(base, positions, joints_deg, feed, index):
    """A machine-frame toolpath of the cut conditions of ``base`` at ``index`` with given joints and
    feed directions."""
    axis = np.asarray(base.tool_axis, float)
    return _FixedFeed(tool=base.tool, material=base.material,
                      tool_axis=axis[index] if axis.ndim == 2 else axis, positions_m=positions,
                      joints_deg=joints_deg, spindle_rpm=base.spindle_rpm[index],
                      feed_per_tooth_m=base.feed_per_tooth_m[index], radial_depth_m=base.radial_depth_m[index],
                      axial_depth_m=base.axial_depth_m[index], milling=base.milling[index], limits=base.limits,
                      feed=feed)


def _margins(robot, base, index, feed, joints_rad, tool_model, counts):
    """Stability margin at the given (point index, joints) pairs; joints (m, 6) all feasible."""
    from ..check import check_toolpath

    if index.size == 0:
        return np.empty(0)
    tp = _fixed_feed_toolpath(base, base.positions_m[index], np.degrees(joints_rad), feed, index)
    res = check_toolpath(tp, robot=robot, tool_model=tool_model)
    counts["margin_evaluations"] = counts.get("margin_evaluations", 0) + int(index.size)
    counts["robot_poses"] = counts.get("robot_poses", 0) + int(res.evaluations.get("robot_poses", 0))
    return np.asarray(res.stability_margin)


def _feasible(robot, q, reachable, threshold):
    """Within limits and away from singularities, (m,) for joints (m, 6) that are reachable."""
    ok = np.array(reachable, bool)
    inside = np.all((q >= robot.lower_rad - 1e-12) & (q <= robot.upper_rad + 1e-12), axis=-1)
    ok &= inside
    if ok.any():
        sing = np.zeros(ok.shape)
        sing[ok] = singularity_measure(robot, q[ok])
        ok &= sing >= threshold
    return ok


def _ik_grid(robot, pos, axis, feed, rotations_rad):
    """IK of every (point, rotation), rotations (n, R) rad: q (n, R, 8, 6), reachable (n, R, 8)."""
    from .ik import inverse_kinematics

    n, r = rotations_rad.shape
    rep = lambda a: np.repeat(a, r, axis=0)  # noqa: E731
    sol = inverse_kinematics(robot, rep(pos), rep(axis), rotations_rad.reshape(-1), rep(feed))
    return np.asarray(sol.q).reshape(n, r, 8, 6), np.asarray(sol.reachable).reshape(n, r, 8)


def feed_to_fixed_deg(tool_axis, feed) -> np.ndarray:
    """``psi``: the signed angle about the tool axis from the feed direction to the fixed
    reference (machine X across the tool axis, Y when the axis is within 25 deg of X), deg, (n,):
    ``tool_rotation_deg = theta + psi`` for the flange angle ``theta`` from the fixed reference."""
    a = np.asarray(tool_axis, float)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    ref = np.where(np.abs(a[:, :1]) > math.cos(math.radians(25.0)), [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    ref = ref - np.sum(ref * a, axis=1, keepdims=True) * a
    f = np.asarray(feed, float)
    f = f - np.sum(f * a, axis=1, keepdims=True) * a
    return np.degrees(np.arctan2(np.sum(np.cross(f, ref) * a, axis=1), np.sum(f * ref, axis=1)))


def _bottleneck(m, k):
    """Best achievable min over a path through states (S, R), steps of at most ``k`` (circular)."""
    v = m[0].copy()
    for s in range(1, m.shape[0]):
        best = v.copy()
        for d in range(1, k + 1):
            best = np.maximum(best, np.maximum(np.roll(v, d), np.roll(v, -d)))
        v = np.minimum(best, m[s])
    return float(v.max())


def _smoothest(m, k, floor, reward):
    """Smoothest state sequence through states with ``m >= floor`` (steps <= k, circular): minimum
    of sum (step)^2 - reward * margin; returns the state per stage (grid indices, unwrapped)."""
    s_n, r_n = m.shape
    allowed = m >= floor
    cost = np.where(allowed[0], -reward * np.minimum(m[0], 1e6), np.inf)
    back = np.zeros((s_n, r_n), dtype=int)  # step taken into each state
    for s in range(1, s_n):
        best = np.full(r_n, np.inf)
        arg = np.zeros(r_n, dtype=int)
        for d in range(-k, k + 1):
            c = np.roll(cost, d) + d * d  # from state r - d
            better = c < best
            best = np.where(better, c, best)
            arg = np.where(better, d, arg)
        cost = np.where(allowed[s], best - reward * np.minimum(m[s], 1e6), np.inf)
        back[s] = arg
    end = int(np.argmin(cost))
    states = np.empty(s_n, dtype=int)
    states[-1] = end
    for s in range(s_n - 1, 0, -1):
        states[s - 1] = (states[s] - back[s, states[s]]) % r_n
    # unwrap: steps of at most k, so the shortest circular difference is the step
    steps = (np.diff(states) + r_n // 2) % r_n - r_n // 2
    return np.concatenate([[states[0]], states[0] + np.cumsum(steps)])


def _stations(n, stations):
    if stations is None or stations >= n:
        return np.arange(n)
    return np.unique(np.rint(np.linspace(0, n - 1, int(stations))).astype(int))


def _check_rotation(robot, machine, rotation_deg, tool_model, threshold, branch=None):
    """Joints and a full check of the path at the given rotations (deg, per point)."""
    from ..check import check_toolpath
    from .path import solve_path

    n = machine.n_points
    axis = np.broadcast_to(np.asarray(machine.tool_axis, float), (n, 3))
    joints = None if machine.joints_deg is None else np.radians(machine.joints_deg)
    pj = solve_path(robot, machine.positions_m, axis, machine.feed_directions(), np.radians(rotation_deg),
                    joints_rad=joints, branch=branch)
    tp = replace(machine, joints_deg=np.where(pj.reachable[:, None], pj.joints_deg, np.nan))
    if not pj.reachable.any():
        return pj, None
    res = check_toolpath(tp, robot=robot, tool_model=tool_model, singularity_threshold=threshold)
    return pj, res


def constant_rotation_margins(robot: Robot, toolpath, angles_deg, *, tool_model=None, branch=None,
                              singularity_threshold: float | None = None) -> np.ndarray:
    """Smallest margin along the path at each constant flange angle about the tool axis (from the
    fixed reference, :func:`feed_to_fixed_deg`; on a straight path the same as a constant
    ``tool_rotation_deg``): the brute-force reference. ``-inf`` where a point is unreachable,
    outside the limits or singular; shape (R,)."""
    threshold = SINGULARITY_THRESHOLD if singularity_threshold is None else singularity_threshold
    machine = replace(toolpath.in_machine_frame(), joints_deg=None, tool_rotation_deg=None)
    n = machine.n_points
    psi = feed_to_fixed_deg(np.broadcast_to(np.asarray(machine.tool_axis, float), (n, 3)), machine.feed_directions())
    out = np.empty(len(angles_deg))
    for i, r in enumerate(angles_deg):
        pj, res = _check_rotation(robot, machine, float(r) + psi, tool_model, threshold, branch)
        bad = res is None or any(res.counts()[k] for k in ("unreachable", "joint_limit", "singularity"))
        out[i] = -np.inf if bad else float(np.min(res.stability_margin))
    return out


def choose_posture(robot: Robot, toolpath, *, tool_model=None, n_rotations: int = 36,
                   stations: int | None = STATIONS, singularity_threshold: float | None = None,
                   smoothness_steps: int = 1) -> PostureResult:
    """The rotation about the tool axis along the path that maximises the smallest stability margin.

    Parameters
    ----------
    robot : Robot
        Calibrated (joint stiffness), ortho-parallel with a spherical wrist.
    toolpath : Toolpath
        Points and tool axis (part frame with ``workpiece_frame``); joints, where given, are
        ignored (the posture is chosen anew); ``tool_rotation_deg`` is the "before" posture.
    tool_model : ModalModel, optional
        Spindle/tool modes in series with the robot's.
    n_rotations : int
        Grid of rotations over a full turn (36: 10 deg).
    stations : int or None
        Points the margins are computed at (None: every point).
    singularity_threshold : float, optional
        Default :data:`planner.robot.path.SINGULARITY_THRESHOLD`.
    smoothness_steps : int
        Largest change of rotation between neighbouring stations, grid steps.

    Returns
    -------
    PostureResult
    """
    if int(n_rotations) < 2:
        raise ValueError(f"n_rotations must be at least 2, found {n_rotations!r}")
    threshold = SINGULARITY_THRESHOLD if singularity_threshold is None else float(singularity_threshold)
    machine = toolpath.in_machine_frame()
    n = machine.n_points
    counts: dict = {"points": n}
    notes: list[str] = []
    before_rot = np.zeros(n) if machine.tool_rotation_deg is None else np.nan_to_num(machine.tool_rotation_deg)
    free = replace(machine, joints_deg=None)
    _, before = _check_rotation(robot, machine, before_rot, tool_model, threshold)

    grid = np.arange(int(n_rotations)) * 360.0 / int(n_rotations)
    grid = np.where(grid > 180.0, grid - 360.0, grid)
    order = np.argsort(grid)
    grid = grid[order]
    st = _stations(n, stations)
    counts["stations"], counts["rotations"] = int(st.size), int(grid.size)
    axis = np.broadcast_to(np.asarray(machine.tool_axis, float), (n, 3))
    feed_all = machine.feed_directions()
    psi_all = feed_to_fixed_deg(axis, feed_all)
    pos, ax, feed, psi = machine.positions_m[st], axis[st], feed_all[st], psi_all[st]
    q, reach = _ik_grid(robot, pos, ax, feed, np.radians(grid[None, :] + psi[:, None]))  # (S, R, 8, 6)
    s_n, r_n = st.size, grid.size
    feas = np.zeros((s_n, r_n, 8), dtype=bool)
    flat_q = q.reshape(-1, 6)
    flat_ok = _feasible(robot, np.nan_to_num(flat_q), reach.reshape(-1), threshold)
    feas[:] = flat_ok.reshape(s_n, r_n, 8)
    counts["ik_solves"] = int(s_n * r_n)
    # candidate branches: the most stations coverable, then the most feasible states
    covered = feas.any(axis=1).sum(axis=0)
    score = covered * (s_n * r_n + 1) + feas.sum(axis=(0, 1))
    cands = [int(b) for b in np.argsort(-score)[:_MAX_BRANCHES] if score[b] > 0]
    if not cands:
        notes.append("no branch reaches any station within the joint limits away from singularities")
        pj, res = _check_rotation(robot, free, before_rot, tool_model, threshold)
        return _result(machine, toolpath, before_rot, -1, before, res, pj, st, grid, np.full((s_n, r_n), -np.inf),
                       counts, notes, theta=before_rot - psi_all)
    best = None
    for b in cands:
        m = np.full((s_n, r_n), -np.inf)
        ok = feas[:, :, b]
        si, ri = np.nonzero(ok)
        m[si, ri] = _margins(robot, machine, st[si], feed[si], q[si, ri, b], tool_model, counts)
        dead = ~ok.any(axis=1)  # stations no rotation reaches: they do not constrain the choice
        mm = np.where(dead[:, None], np.inf, m)
        top = _bottleneck(mm, int(smoothness_steps))
        key = (-int(dead.sum()), top)
        if best is None or key > best[0]:
            best = (key, b, m, mm, top, dead)
    _, branch, m, mm, top, dead = best
    counts["branches_evaluated"] = len(cands)
    finite = np.isfinite(mm) & (mm > 0)
    reward = 0.1 / max(np.median(mm[finite]), 1e-12) if finite.any() else 0.0
    states = _smoothest(mm, int(smoothness_steps), top, reward)
    step = 360.0 / r_n
    station_rot = grid[0] + states * step  # flange angle theta at the stations
    # local refinement: the whole sequence shifted by a fraction of a step
    shift_best, min_best = 0.0, top
    from .ik import inverse_kinematics

    for frac in _REFINE:
        rot = np.radians(station_rot + frac * step + psi)
        sol = inverse_kinematics(robot, pos, ax, rot, feed)
        qb = np.asarray(sol.q)[:, branch]
        okb = _feasible(robot, np.nan_to_num(qb), np.asarray(sol.reachable)[:, branch], threshold)
        if np.any(okb != ~dead):
            continue
        vals = _margins(robot, machine, st[okb], feed[okb], qb[okb], tool_model, counts)
        if vals.size and vals.min() > min_best:
            shift_best, min_best = frac * step, float(vals.min())
    station_rot = station_rot + shift_best
    if shift_best:
        notes.append(f"refined: rotation sequence shifted by {shift_best:+.3g} deg")
    theta = np.interp(np.arange(n), st, station_rot)
    rotation = theta + psi_all
    pj, after = _check_rotation(robot, free, rotation, tool_model, threshold, branch=branch)
    if dead.any():
        notes.append(f"{int(dead.sum())} station(s) with no feasible rotation on branch {branch}")
    return _result(machine, toolpath, before_rot, branch, before, after, pj, st, grid, m, counts, notes,
                   rotation=rotation, theta=theta)


def _result(machine, toolpath, before_rot, branch, before, after, pj, st, grid, m, counts, notes, rotation=None,
            theta=None):
    n = machine.n_points
    rotation = before_rot if rotation is None else rotation
    nan = np.full(n, np.nan)
    mb = nan if before is None else np.asarray(before.stability_margin)
    ma = nan if after is None else np.asarray(after.stability_margin)
    bad = ~pj.reachable
    if after is not None:
        for kind in ("joint_limit", "singularity"):
            bad = bad | after.flagged(kind)
    joints = np.where(bad[:, None], np.nan, pj.joints_deg)
    out = replace(toolpath, joints_deg=joints, tool_rotation_deg=rotation)

    def low(a):
        a = a[np.isfinite(a)]
        return float(a.min()) if a.size else math.nan

    # a margin from a pose the calibration does not cover is an extrapolation: said, before and after
    # (the choice itself does not avoid such poses; the session-14 audit found a posture that moved
    # 240 points out of the covered region without a word)
    covered = {k: None if r is None else ~np.asarray(r.in_span, bool) & ~bad for k, r in (("before", before),
                                                                                         ("after", after))}
    if covered["after"] is not None and covered["after"].any():
        was = "" if covered["before"] is None else f" ({int(covered['before'].sum())} before)"
        notes.append(f"{int(covered['after'].sum())} point(s) of the chosen posture at poses the calibration does "
                     f"not cover{was}: their margins are extrapolations of the robot model, not trusted")
    notes.append("margins: depth_limit / planned depth by the check (ZOA) with the robot model per point")
    return PostureResult(toolpath=out, rotation_deg=rotation, flange_angle_deg=theta, branch=int(branch), margin_before=mb,
                         margin_after=np.where(bad, np.nan, ma), min_margin_before=low(mb),
                         min_margin_after=low(np.where(bad, np.nan, ma)),
                         unreachable=tuple(int(i) for i in np.flatnonzero(bad)), station_index=st,
                         rotations_deg=grid, station_margin=m, evaluations=counts, notes=tuple(notes))
