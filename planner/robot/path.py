"""A Cartesian toolpath on the robot: joints per point and the robot's modal model per point.

``robomill check --robot`` (cli.md) on a toolpath in the part frame (formats.md "Toolpath with a
robot"): every point's tool-tip position and tool axis, with the rotation about the tool axis
(``tool_rotation_deg``, 0 = the flange x axis as close as possible to the feed direction), fix the
flange frame; inverse kinematics (:func:`planner.robot.ik.inverse_kinematics`, every branch of the
6R arm with a spherical wrist) gives the joints. (The branch is followed here by a vectorised
unwrap of the wrist joints instead of :func:`planner.robot.ik.continuous_branch`, a per-point loop
too slow for 10^5 points.) One configuration (branch) is kept along the whole
path (a configuration flip is a stop of the robot: not something a check may invent), the branch
with the most points reachable within the joint limits; joint angles given in the toolpath win.

Per point the outcome is one of

* ``unreachable``: no branch reaches the target (the point is outside the workspace, or only
  other configurations than the path's reach it); no pose, so no robot model: the stability and
  surface error there are NaN;
* ``joint_limit``: the path's branch reaches it only outside a joint's range (or the given joints
  are outside it); the model is still evaluated at that pose;
* ``singularity``: the pose is too close to a singularity for its Jacobian to be trusted, decided
  by the inverse condition number of the scaled tool-tip Jacobian (:func:`singularity_measure`)
  below :data:`SINGULARITY_THRESHOLD`.

The robot model per point is vectorised: joints rounded to :data:`POSE_RESOLUTION_DEG`, the
distinct poses solved at once (:func:`planner.robot.dynamics.robot_modes`: one batched ``eigh``),
every pose keeping its six joint-space modes (a mode that hardly moves the tip gets a negligible
compliance) plus the pose-independent tool modes in series.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from oma._arrays import readonly as _ro
from oma.modal import ModalModel

from .description import Robot, RobotError
from .ik import SINGULARITY_THRESHOLD

__all__ = ["PathJoints", "solve_path", "singularity_measure", "lowest_mode_map", "read_cell", "robot_point_models",
           "POSE_RESOLUTION_DEG", "SINGULARITY_THRESHOLD", "CHARACTERISTIC_LENGTH_M"]

#: Joint angles are rounded to this before the robot model is evaluated, deg. The lowest tool-tip
#: mode moves by about +-50 % over the workspace (DOMAIN.md), i.e. well under 1 % per degree of
#: any joint: 0.05 deg (0.025 deg at most off) changes the limit depth by < 1e-7 and the surface
#: location error by < 3e-4 of itself on the example (``benchmarks/bench_check.py``, robot case),
#: and cuts the distinct models of a dense path ~5x against 0.01 deg.
POSE_RESOLUTION_DEG = 0.05
#: Length scaling the Jacobian's translational rows, m (the order of the arm's links).
CHARACTERISTIC_LENGTH_M = 1.0
#: Modes whose tool-tip compliance is below this fraction of the largest at the pose are stiffened
#: to that fraction (their effect on the tip is negligible; it keeps every pose at six modes).
_MIN_TIP_FRACTION = 1e-9


@dataclass(frozen=True)
class PathJoints:
    """The joints of every point of a path.

    Attributes
    ----------
    joints_rad : ndarray, shape (n, 6)
        NaN rows where unreachable.
    reachable : ndarray of bool, shape (n,)
    within_limits : ndarray of bool, shape (n,)
    limit_excess_deg : ndarray, shape (n,)
        How far the worst joint is outside its range, deg (0 inside).
    limit_distance_deg : ndarray, shape (n,)
        Smallest distance of a joint to its limit, deg (negative outside).
    singularity : ndarray, shape (n,)
        :func:`singularity_measure` (NaN where unreachable).
    given : ndarray of bool, shape (n,)
        The joints came from the toolpath.
    branch : int
        The IK branch kept along the path (-1: none needed).
    """

    joints_rad: np.ndarray
    reachable: np.ndarray
    within_limits: np.ndarray
    limit_excess_deg: np.ndarray
    limit_distance_deg: np.ndarray
    singularity: np.ndarray
    given: np.ndarray
    branch: int

    def __post_init__(self):
        for name in ("joints_rad", "limit_excess_deg", "limit_distance_deg", "singularity"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        for name in ("reachable", "within_limits", "given"):
            object.__setattr__(self, name, _ro(getattr(self, name), bool))

    @property
    def joints_deg(self) -> np.ndarray:
        return np.degrees(self.joints_rad)

    def to_dict(self) -> dict:
        return {"branch": self.branch, "unreachable": np.flatnonzero(~self.reachable).tolist(),
                "outside_limits": np.flatnonzero(self.reachable & ~self.within_limits).tolist()}


def singularity_measure(robot: Robot, q) -> np.ndarray:
    """Inverse condition number ``sigma_min / sigma_max`` of the tool-tip Jacobian with its
    rotational rows times :data:`CHARACTERISTIC_LENGTH_M` (dimensionless, 0 at a singularity):
    :func:`planner.robot.ik.singularity_measure`."""
    from .ik import singularity_measure as measure

    return measure(robot, q, length_m=CHARACTERISTIC_LENGTH_M)


def _limits(robot: Robot, q):
    lo, hi = np.degrees(robot.lower_rad), np.degrees(robot.upper_rad)
    d = np.degrees(q)
    distance = np.min(np.minimum(d - lo, hi - d), axis=-1)
    excess = np.max(np.maximum(np.maximum(lo - d, d - hi), 0.0), axis=-1)
    return distance, excess


def solve_path(robot: Robot, positions_m, tool_axis, feed, rotation_rad, *, joints_rad=None, branch=None,
               singularity: bool = True) -> PathJoints:
    """Joints of every point of a Cartesian path (one IK branch kept along it).

    Parameters
    ----------
    robot : Robot
    positions_m, tool_axis, feed : array_like, shape (n, 3)
        Tool tip, tool axis (unit) and feed direction, machine frame.
    rotation_rad : array_like, shape (n,)
        Rotation about the tool axis (0: the flange reference axis towards the feed).
    joints_rad : array_like, shape (n, 6), optional
        Given joints (NaN rows: not given); they win.
    branch : int, optional
        The IK branch to keep (default: the one valid at most points).
    singularity : bool
        Compute :func:`singularity_measure` at every reached point (else NaN: the caller computes
        it, e.g. at the distinct rounded poses).

    Returns
    -------
    PathJoints
    """
    positions_m = np.asarray(positions_m, float)
    n = positions_m.shape[0]
    rotation_rad = np.broadcast_to(np.asarray(rotation_rad, float), (n,))
    given = np.zeros(n, dtype=bool)
    q = np.full((n, 6), np.nan)
    if joints_rad is not None:
        joints_rad = np.asarray(joints_rad, float)
        given = np.all(np.isfinite(joints_rad), axis=1)
        q[given] = joints_rad[given]
    todo = np.flatnonzero(~given)
    chosen = -1
    if todo.size:
        from .ik import inverse_kinematics

        ik = inverse_kinematics(robot, positions_m[todo], np.asarray(tool_axis, float)[todo],
                                rotation_rad[todo], np.asarray(feed, float)[todo])
        sols, ok, inside = np.asarray(ik.q), np.asarray(ik.reachable), np.asarray(ik.valid)
        if branch is None:
            # most points within the limits, then most reached, then the farthest from the limits
            dist, _ = _limits(robot, np.where(ok[..., None], sols, 0.0))
            count = np.maximum(inside.sum(axis=0), 1)
            margin = np.sum(np.where(inside, dist, 0.0), axis=0) / count
            score = inside.sum(axis=0) + 1e-3 * ok.sum(axis=0) + 1e-9 * np.nan_to_num(margin)
            chosen = int(np.argmax(score))
        else:
            chosen = int(branch)
        pick = sols[:, chosen]
        pick = _continuous(robot, pick, ok[:, chosen])
        q[todo] = np.where(ok[:, chosen, None], pick, np.nan)
    reachable = np.all(np.isfinite(q), axis=1)
    distance, excess = _limits(robot, np.where(reachable[:, None], q, 0.5 * (robot.lower_rad + robot.upper_rad)))
    sing = np.full(n, np.nan)
    if singularity and reachable.any():
        sing[reachable] = singularity_measure(robot, q[reachable])
    distance = np.where(reachable, distance, np.nan)
    return PathJoints(q, reachable, reachable & (excess <= 1e-9), np.where(reachable, excess, np.nan), distance,
                      sing, given, chosen)


def _continuous(robot: Robot, q, ok):
    """Joints of the wrist (range > 2 pi) kept continuous along the path: each point's
    representative (mod 2 pi) nearest the previous reached point's, within the limits if possible."""
    q = np.array(q, float)
    wide = np.flatnonzero(robot.upper_rad - robot.lower_rad > 2 * math.pi)
    idx = np.flatnonzero(ok)
    if idx.size < 2 or wide.size == 0:
        return q
    sub = q[idx][:, wide]
    # unwrap along the path, then shift the whole run by the multiple of 2 pi that fits the range best
    un = np.unwrap(sub, axis=0)
    lo, hi = robot.lower_rad[wide], robot.upper_rad[wide]
    for k, j in enumerate(wide):
        shifts = 2 * math.pi * np.arange(-2, 3)
        # inside the range first, then nearest the middle of the range; a tie (a run at +-180 deg
        # around a middle of 0) goes to the larger turn, whatever the rounding noise of the mean
        mid = 0.5 * (lo[k] + hi[k])
        cost = [1e6 * np.sum(np.maximum(lo[k] - (un[:, k] + s), 0) + np.maximum(un[:, k] + s - hi[k], 0))
                + round(abs(np.mean(un[:, k]) + s - mid), 9) - 1e-10 * s for s in shifts]
        un[:, k] += shifts[int(np.argmin(cost))]
    sub[:] = un
    out = q.copy()
    out[np.ix_(idx, wide)] = sub
    return out


def _stacked_models(robot: Robot, q_unique, tool_model: ModalModel | None):
    """Modal parameters of the robot (plus tool) at the distinct poses, stacked (n, m)."""
    from .dynamics import robot_modes

    modes = robot_modes(robot, q_unique)
    comp = modes.compliance_m_N
    floor = _MIN_TIP_FRACTION * comp.max(axis=1, keepdims=True)
    stiff = 1.0 / np.maximum(comp, floor)
    fn, zeta, dirs = modes.frequency_hz, np.maximum(modes.damping_ratio, 1e-6), np.array(modes.directions)
    dirs[np.linalg.norm(dirs, axis=-1) == 0] = [1.0, 0.0, 0.0]
    res = np.zeros((fn.shape[0], 3, 3))
    if tool_model is not None:
        n = fn.shape[0]
        rep = lambda a: np.broadcast_to(a, (n,) + a.shape)  # noqa: E731
        fn = np.hstack([fn, rep(tool_model.natural_frequency_hz)])
        zeta = np.hstack([zeta, rep(tool_model.damping_ratio)])
        stiff = np.hstack([stiff, rep(tool_model.stiffness_N_m)])
        dirs = np.concatenate([dirs, rep(tool_model.directions)], axis=1)
        res = res + tool_model.residual_compliance_m_N
    return fn, zeta, stiff, dirs, res


def robot_point_models(robot: Robot, toolpath, *, tool_model=None, resolution_deg: float = POSE_RESOLUTION_DEG,
                       notes: list | None = None, singularity_threshold: float | None = None, counts=None):
    """The per-point models of :func:`planner.check.check_toolpath` with a robot.

    Returns
    -------
    models : planner.check._Models
    extra : dict
        ``{kind: (mask (n,), value (n,), limit)}`` for ``unreachable``, ``joint_limit``,
        ``singularity``.
    joints_deg : ndarray, shape (n, 6)
        NaN rows where unreachable.
    """
    from ..check import _Models, _groups, _quantise

    if robot.joint_stiffness_N_m_rad is None:
        raise RobotError(robot.file, "joints.stiffness_N_m_rad", "joint stiffness (a calibrated robot: robomill "
                         "robot calibrate)", "none")
    notes = [] if notes is None else notes
    threshold = SINGULARITY_THRESHOLD if singularity_threshold is None else float(singularity_threshold)
    n = toolpath.n_points
    axis = np.broadcast_to(np.asarray(toolpath.tool_axis, float), (n, 3))
    rotation = toolpath.tool_rotation_deg
    free = np.ones(n, dtype=bool) if rotation is None else ~np.isfinite(rotation)
    rot_rad = np.radians(np.where(free, 0.0, np.nan_to_num(rotation if rotation is not None else 0.0)))
    joints = None if toolpath.joints_deg is None else np.radians(toolpath.joints_deg)
    pj = solve_path(robot, toolpath.positions_m, axis, toolpath.feed_directions(), rot_rad, joints_rad=joints,
                    singularity=False)
    if (free & ~pj.given).any():
        notes.append(f"{int((free & ~pj.given).sum())} point(s) without joints or tool_rotation_deg: rotation 0 "
                     "about the tool axis (flange x towards the feed); robomill posture chooses a better one")
    if pj.branch >= 0:
        notes.append(f"inverse kinematics: branch {pj.branch} kept along the path")
    notes.append(f"singularity: inverse condition number of the tool-tip Jacobian (translation rows per "
                 f"{CHARACTERISTIC_LENGTH_M:g} m) below {threshold:g}")
    reach = pj.reachable
    q_eval = np.where(reach[:, None], pj.joints_rad, 0.5 * (robot.lower_rad + robot.upper_rad))
    q_deg = _quantise(np.degrees(q_eval), resolution_deg) if resolution_deg > 0 else np.degrees(q_eval)
    first, inverse = _groups(*q_deg.T)
    fn, zeta, stiff, dirs, res = _stacked_models(robot, np.radians(q_deg[first]), tool_model)
    # the singularity measure at the rounded poses (it changes by ~1e-4 per 0.05 deg)
    sing = np.where(reach, singularity_measure(robot, np.radians(q_deg[first]))[inverse], np.nan)
    if counts is not None:
        counts["robot_poses"] = int(first.size)
    ones = np.ones(n, dtype=bool)
    trusted = ones.copy()
    cal = robot.calibration or {}
    if "poses_deg" in cal and "covariance" in cal:  # the trust rule of robot calibrate, at the distinct poses
        from .calibrate import trust_poses

        trusted = trust_poses(robot, np.radians(q_deg[first]))[0][inverse] & reach
        if (~trusted & reach).any():
            notes.append(f"{int((~trusted & reach).sum())} point(s) at poses the calibration does not cover "
                         "(robot calibrate's trust rule): in_span false, their predictions are not trusted")
    else:
        notes.append("the robot has no calibration record: whether its poses are covered is not assessed")
    models = _Models(fn, zeta, stiff, dirs, res, inverse, trusted, ~ones, np.zeros(n), math.inf, math.inf)
    extra = {
        "unreachable": (~reach, np.ones(n), 0.0),
        "joint_limit": (reach & ~pj.within_limits, np.nan_to_num(pj.limit_excess_deg), 0.0),
        "singularity": (reach & (sing < threshold), sing, threshold),
    }
    return models, extra, np.where(reach[:, None], np.degrees(pj.joints_rad), np.nan)


def read_cell(toolpath, robot_path=None, tool_model_path=None, toolpath_file=None):
    """The robot (``robot_path``, else the toolpath's ``robot:``) and the optional tool model of a
    check or posture run; :class:`RobotError` for a robot without joint stiffness, an
    :class:`~oma.errors.InputError` when there is no robot at all."""
    from oma.errors import ToolpathError
    from oma.modal_io import read_modal_model

    from .description import read_robot

    path = robot_path if robot_path is not None else toolpath.robot_file
    if path is None:
        raise ToolpathError(toolpath_file, "robot", "a robot (the key robot, or --robot ROBOT) or --models",
                            "neither")
    robot = read_robot(path)
    if robot.joint_stiffness_N_m_rad is None:
        raise RobotError(path, "joints.stiffness_N_m_rad", "joint stiffness (a calibrated robot: robomill robot "
                         "calibrate)", "none")
    tool_model = None if tool_model_path is None else read_modal_model(tool_model_path)
    return robot, tool_model


def lowest_mode_map(robot: Robot, x_m, y_m, z_m: float, *, tool_axis=(0.0, 0.0, 1.0), feed=(0.0, 1.0, 0.0),
                    rotation_deg: float = 0.0, branch: int | None = None, min_tip_fraction: float = 0.01):
    """The lowest tool-tip mode over a horizontal grid of tool-tip positions (machine frame).

    Parameters
    ----------
    robot : Robot
        With joint stiffness.
    x_m, y_m : array_like, shape (nx,), (ny,)
        Grid, m; ``z_m`` its height, m.
    tool_axis, feed : array_like, shape (3,)
        Tool axis and feed direction (the reference of the rotation), machine frame.
    rotation_deg : float
        Rotation about the tool axis.
    branch : int, optional
        IK branch (default: the one valid at most grid points).
    min_tip_fraction : float
        A mode counts as a tool-tip mode when its tip compliance is at least this fraction of the
        pose's largest.

    Returns
    -------
    frequency_hz, stiffness_N_m : ndarray, shape (ny, nx)
        Of the lowest tool-tip mode (NaN where no valid pose).
    """
    from .dynamics import robot_modes
    from .ik import inverse_kinematics

    xx, yy = np.meshgrid(np.asarray(x_m, float), np.asarray(y_m, float))
    pts = np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, float(z_m))])
    sol = inverse_kinematics(robot, pts, np.asarray(tool_axis, float), math.radians(rotation_deg),
                             np.asarray(feed, float))
    valid = np.asarray(sol.valid)
    b = int(np.argmax(valid.sum(axis=0))) if branch is None else int(branch)
    ok = valid[:, b]
    freq = np.full(xx.size, np.nan)
    stiff = np.full(xx.size, np.nan)
    if ok.any():
        modes = robot_modes(robot, np.asarray(sol.q)[ok, b])
        comp = modes.compliance_m_N
        tip = comp >= min_tip_fraction * comp.max(axis=1, keepdims=True)
        f = np.where(tip, modes.frequency_hz, np.inf)
        r = np.argmin(f, axis=1)
        freq[ok] = f[np.arange(r.size), r]
        stiff[ok] = modes.stiffness_N_m[np.arange(r.size), r]
    return freq.reshape(xx.shape), stiff.reshape(xx.shape)
