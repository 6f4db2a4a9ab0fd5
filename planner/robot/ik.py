"""Inverse kinematics of the tool tip, every branch, in closed form, vectorised.

The arm must be of the ortho-parallel class with a spherical wrist (OPW: Brandstoetter, Angerer &
Hofbaur, ISR/Robotik 2014), as the KUKA KR 500 R2800-2 and KR 300 R2800-2 MT are: joint 2 not
parallel to joint 1, joints 2 and 3 parallel, joints 4, 5, 6 meeting in one point (the wrist
centre). :func:`check_opw` verifies it from the zero-pose geometry and :func:`opw_parameters`
reports the OPW lengths. The solution is written on the product of exponentials
``T(q) = exp(xi_1 q_1) ... exp(xi_6 q_6) T(0)`` (Murray, Li & Sastry, *A Mathematical Introduction
to Robotic Manipulation*, 1994, sec. 3.3, Paden-Kahan subproblems), so it needs no DH frames:

1. the flange orientation from the tool axis, the reference (e.g. feed) direction and the rotation
   about the tool axis; the wrist centre from the tool tip;
2. ``q1`` (2 branches: front/back): the wrist centre must lie in the plane joints 2 and 3 move it in;
3. ``q3`` (2: elbow up/down): subproblem 3, the wrist centre's distance from joint 2's axis;
   ``q2``: subproblem 1;
4. ``q4, q5`` (2: wrist flip): subproblem 2 on joint 6's axis; ``q6``: subproblem 1.

Rotation about the tool axis (formats.md): ``rotation_rad = 0`` puts the flange x axis
(:attr:`~planner.robot.description.ToolBody.reference_axis`) as close as possible to the reference
direction; positive turns it right-handed about the tool axis ``a``.

Joint values are returned in ``(-pi, pi]`` unless a ``2 pi`` shift is needed to bring them within
the limits (joints 1, 4, 6 of a KUKA have more than one turn of range; :func:`continuous_branch`
picks the turn nearest the previous point along a path).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oma._arrays import readonly as _ro

from .description import Robot, RobotError
from ._ik_kernel import solve_all
from .kinematics import _cross, as_poses, flange_frames, link_frames, tip_jacobian

#: A pose is "too close to a singularity" below this :func:`singularity_measure` (1 m length):
#: near the wrist singularity it is ~ sin(q5) x 0.3 for this arm class, so 0.01 is about
#: |q5| < 2 deg, where 1 mm of commanded tool motion asks for > 100 mrad of joint motion. The
#: toolpath check, the posture search and the atlas all use it.
SINGULARITY_THRESHOLD = 0.01

__all__ = ["IKSolutions", "SINGULARITY_THRESHOLD", "inverse_kinematics", "target_rotation", "check_opw", "opw_parameters",
           "continuous_branch", "PathIK", "singularity_measure", "joint_limit_distance", "tool_rotation",
           "N_BRANCHES"]

N_BRANCHES = 8
_TOL = 1e-9  # geometric tolerance of the OPW check, m and rad


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _zero_geometry(robot: Robot):
    rot, pos = link_frames(robot, np.zeros(6))
    w = np.einsum("ijk,ik->ij", rot[0], robot.joint_axis)
    p = pos[0]
    # wrist centre: least-squares point nearest the lines of joints 4, 5, 6
    a = np.zeros((3, 3))
    rhs = np.zeros(3)
    for i in (3, 4, 5):
        proj = np.eye(3) - np.outer(w[i], w[i])
        a += proj
        rhs += proj @ p[i]
    wc = np.linalg.solve(a, rhs)
    return w, p, wc, flange_frames(robot, np.zeros(6))[0]


def _line_distance(p, w, x):
    d = x - p
    return float(np.linalg.norm(d - (d @ w) * w))


def check_opw(robot: Robot) -> None:
    """Raise :class:`RobotError` unless the arm is ortho-parallel with a spherical wrist."""
    w, p, wc, _ = _zero_geometry(robot)
    where = f"chain {robot.base_link} -> {robot.flange_link}"
    file = robot.urdf

    def fail(expected, found):
        raise RobotError(file, where, f"{expected} (an ortho-parallel arm with a spherical wrist, for inverse "
                         "kinematics)", found)

    if np.linalg.norm(np.cross(w[0], w[1])) < 1e-6:
        fail("joint 2 not parallel to joint 1", "parallel axes")
    if np.linalg.norm(np.cross(w[1], w[2])) > _TOL:
        fail("joints 2 and 3 parallel", f"an angle of {np.degrees(np.arcsin(min(1, np.linalg.norm(np.cross(w[1], w[2]))))):.3g} deg")
    for i in (3, 4, 5):
        d = _line_distance(p[i], w[i], wc)
        if d > 1e-7:
            fail("joints 4, 5 and 6 meeting in one point", f"joint {i + 1} {d:.3g} m from the wrist centre")
    for i, j in ((3, 4), (4, 5)):
        if np.linalg.norm(np.cross(w[i], w[j])) < 1e-6:
            fail(f"joints {i + 1} and {j + 1} not parallel", "parallel axes")
    if _line_distance(p[2], w[2], wc) < 1e-6:
        fail("the wrist centre off joint 3's axis", "on it")


def opw_parameters(robot: Robot) -> dict:
    """The OPW lengths of the arm (m), from its zero-pose geometry: ``a1`` (joint 1 to joint 2
    axis), ``c1`` (height of joint 2 above the base along joint 1), ``c2`` (joint 2 to joint 3),
    ``b`` (lateral offset of the wrist centre from the arm's plane), ``c3`` (joint 3 to the wrist
    centre along joint 4), ``a2`` (the wrist centre's offset normal to it), ``c4`` (wrist centre to
    flange). Signs are those of the geometry, not of any controller convention."""
    check_opw(robot)
    w, p, wc, f0 = _zero_geometry(robot)
    n = np.cross(w[0], w[1])
    n /= np.linalg.norm(n)
    a1 = abs((p[1] - p[0]) @ n)
    # foot of the common normal on axis 2
    d = p[1] - p[0]
    m = np.array([[w[0] @ w[0], -(w[0] @ w[1])], [w[0] @ w[1], -(w[1] @ w[1])]])
    s, t = np.linalg.solve(m, [d @ w[0], d @ w[1]])
    foot2 = p[1] + t * w[1]
    c2 = _line_distance(p[1], w[1], p[2])
    v = wc - p[2]
    v = v - (v @ w[2]) * w[2]
    c3 = abs(v @ w[3])
    return {"a1": a1, "c1": float(w[0] @ foot2), "c2": c2, "b": float(w[1] @ (wc - p[0])),
            "c3": c3, "a2": float(np.sqrt(max(v @ v - c3**2, 0.0))), "c4": float(np.linalg.norm(f0[:3, 3] - wc))}


def target_rotation(robot: Robot, tool_axis, reference, rotation_rad) -> np.ndarray:
    """Flange orientations (n, 3, 3) that put the tool axis along ``tool_axis`` (n, 3) and the
    flange reference axis at ``rotation_rad`` (n,) about it from ``reference`` (n, 3)."""
    a = _unit(np.asarray(tool_axis, float).reshape(-1, 3))
    ref = np.asarray(reference, float).reshape(-1, 3)
    x = ref - _dot(ref, a)[:, None] * a
    norm = np.linalg.norm(x, axis=-1)
    if np.any(norm < 1e-9 * np.maximum(np.linalg.norm(ref, axis=-1), 1e-300)):
        i = int(np.argmax(norm < 1e-9 * np.maximum(np.linalg.norm(ref, axis=-1), 1e-300)))
        raise ValueError(f"point {i}: the reference direction is parallel to the tool axis")
    x = x / norm[:, None]
    rho = np.broadcast_to(np.asarray(rotation_rad, float), a.shape[:1])
    x = np.cos(rho)[:, None] * x + np.sin(rho)[:, None] * _cross(a, x)
    target = np.stack([x, _cross(a, x), a], axis=-1)
    af = robot.tool.axis
    xf = robot.tool.reference_axis
    flange = np.column_stack([xf, np.cross(af, xf), af])
    return target @ flange.T


def tool_rotation(robot: Robot, q, reference) -> np.ndarray:
    """The rotation about the tool axis (n,), rad, of poses ``q`` relative to ``reference`` (n, 3):
    the inverse of the ``rotation_rad`` of :func:`inverse_kinematics`."""
    f = flange_frames(robot, q)
    a = f[:, :3, :3] @ robot.tool.axis
    x = f[:, :3, :3] @ robot.tool.reference_axis
    ref = np.asarray(reference, float).reshape(-1, 3)
    ref = ref - _dot(ref, a)[:, None] * a
    return np.arctan2(_dot(_cross(ref, x), a), _dot(ref, x))


@dataclass(frozen=True, eq=False)
class IKSolutions:
    """All closed-form branches at ``n`` targets.

    Attributes
    ----------
    q : ndarray, shape (n, 8, 6)
        Joint angles, rad (NaN where unreachable). Branch ``4 i1 + 2 i3 + iw``: ``i1`` the
        shoulder (front/back), ``i3`` the elbow, ``iw`` the wrist flip.
    reachable : ndarray of bool, shape (n, 8)
        The branch exists (the target is within the arm's reach).
    within_limits : ndarray of bool, shape (n, 8)
        Every joint within its limits.
    valid : ndarray of bool, shape (n, 8)
        ``reachable & within_limits``.
    """

    q: np.ndarray
    reachable: np.ndarray
    within_limits: np.ndarray
    valid: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "q", _ro(self.q))
        for name in ("reachable", "within_limits", "valid"):
            object.__setattr__(self, name, _ro(getattr(self, name), dtype=bool))

    @property
    def any_valid(self) -> np.ndarray:
        """A valid branch exists, shape (n,)."""
        return self.valid.any(axis=1)

    def to_dict(self) -> dict:
        return {"q_rad": np.where(np.isnan(self.q), None, self.q).tolist(), "valid": self.valid.tolist(),
                "reachable": self.reachable.tolist(), "within_limits": self.within_limits.tolist()}


def inverse_kinematics(robot: Robot, position_m, tool_axis, rotation_rad, reference) -> IKSolutions:
    """Every joint solution placing the tool tip at ``position_m`` with the tool along
    ``tool_axis``, turned ``rotation_rad`` about it from ``reference``.

    Parameters
    ----------
    robot : Robot
        Ortho-parallel with a spherical wrist (else :class:`RobotError`).
    position_m : array_like, shape (n, 3) or (3,)
        Tool tip, machine frame, m.
    tool_axis : array_like, shape (n, 3) or (3,)
        Tool axis ``a`` (tip into spindle), machine frame.
    rotation_rad : array_like, shape (n,) or scalar
        Rotation about the tool axis (0: flange reference axis nearest ``reference``).
    reference : array_like, shape (n, 3) or (3,)
        The reference direction, e.g. the feed direction; not parallel to the tool axis.

    Returns
    -------
    IKSolutions
    """
    check_opw(robot)
    pos = np.atleast_2d(np.asarray(position_m, float))
    n = pos.shape[0]
    axis = np.broadcast_to(np.asarray(tool_axis, float), (n, 3))
    ref = np.broadcast_to(np.asarray(reference, float), (n, 3))
    rho = np.broadcast_to(np.asarray(rotation_rad, float), (n,))
    w, p, wc0, f0 = _zero_geometry(robot)
    rt = target_rotation(robot, axis, ref, rho)  # flange orientation (n, 3, 3)
    c_f = f0[:3, :3].T @ (wc0 - f0[:3, 3])  # wrist centre in the flange frame
    flange_origin = pos - rt @ robot.tool.tip_m
    wc = flange_origin + rt @ c_f
    e = np.eye(3)[int(np.argmin(np.abs(w[5])))]
    v6 = e - (e @ w[5]) * w[5]
    v6 /= np.linalg.norm(v6)
    r0t = f0[:3, :3].T
    t6 = rt @ (r0t @ w[5])
    v6t = rt @ (r0t @ v6)
    q = np.empty((n, N_BRANCHES, 6))
    reachable = np.empty((n, N_BRANCHES), dtype=bool)
    within = np.empty((n, N_BRANCHES), dtype=bool)
    solve_all(np.ascontiguousarray(wc), np.ascontiguousarray(t6), np.ascontiguousarray(v6t),
              np.ascontiguousarray(w), np.ascontiguousarray(p), wc0, v6, robot.lower_rad, robot.upper_rad,
              q, reachable, within)
    return IKSolutions(q=q, reachable=reachable, within_limits=within, valid=within)


# ----------------------------------------------------------------------------- measures
def singularity_measure(robot: Robot, q, *, length_m: float = 1.0) -> np.ndarray:
    """Inverse condition number of the tool-tip Jacobian, shape (n,), in [0, 1] (0: singular).

    The angular rows are scaled by ``length_m`` so that both halves have units of m per rad
    (the characteristic length of the arm; 1 m for a 500 kg-class robot)."""
    jac = tip_jacobian(robot, q).copy()
    jac[:, 3:, :] *= length_m
    s = np.linalg.svd(jac, compute_uv=False)
    return s[:, -1] / s[:, 0]


def joint_limit_distance(robot: Robot, q) -> np.ndarray:
    """Distance to the nearest joint limit per joint, shape (n, 6), rad (negative: outside)."""
    q = as_poses(q)
    return np.minimum(q - robot.lower_rad, robot.upper_rad - q)


@dataclass(frozen=True, eq=False)
class PathIK:
    """One branch followed along a path.

    Attributes
    ----------
    q : ndarray, shape (n, 6)
        rad; NaN where no valid branch exists.
    branch : ndarray of int, shape (n,)
        Branch index chosen at each point (-1: none valid).
    flips : ndarray of int
        Indices where the branch changes (a configuration flip).
    """

    q: np.ndarray
    branch: np.ndarray
    flips: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "q", _ro(self.q))
        for name in ("branch", "flips"):
            object.__setattr__(self, name, _ro(getattr(self, name), dtype=int))


def _nearest_turn(robot: Robot, q, previous):
    """``q`` (m, 6) shifted by multiples of 2 pi towards ``previous`` (6,) while within limits."""
    out = q.copy()
    for shift in (2 * np.pi, -2 * np.pi):
        alt = out + shift
        better = (np.abs(alt - previous) < np.abs(out - previous)) & (alt >= robot.lower_rad) & (alt <= robot.upper_rad)
        out = np.where(better, alt, out)
    return out


def continuous_branch(robot: Robot, solutions: IKSolutions, *, start=None) -> PathIK:
    """Follow the valid branch that moves the joints least from point to point.

    Parameters
    ----------
    robot : Robot
    solutions : IKSolutions
        Of consecutive path points.
    start : int or array_like (6,), optional
        Branch index to start in, or joint angles (rad) to start nearest to; default: the valid
        branch at the first point farthest from the joint limits.

    Returns
    -------
    PathIK
    """
    n = solutions.q.shape[0]
    q_out = np.full((n, 6), np.nan)
    branch = np.full(n, -1)
    previous = None
    prev_branch = None
    for i in range(n):
        valid = np.flatnonzero(solutions.valid[i])
        if valid.size == 0:
            continue
        cand = solutions.q[i, valid]
        if previous is None:
            if start is None:
                score = -joint_limit_distance(robot, cand).min(axis=1)
                k = int(np.argmin(score))
            elif np.ndim(start) == 0:
                k = int(np.argmax(valid == int(start))) if int(start) in valid else 0
            else:
                cand = _nearest_turn(robot, cand, np.asarray(start, float))
                k = int(np.argmin(np.abs(cand - np.asarray(start, float)).max(axis=1)))
        else:
            cand = _nearest_turn(robot, cand, previous)
            step = np.abs(cand - previous).max(axis=1)
            step = step + np.where(valid == prev_branch, 0.0, 1e-9)  # ties keep the branch
            k = int(np.argmin(step))
        q_out[i] = cand[k]
        branch[i] = valid[k]
        previous, prev_branch = q_out[i], valid[k]
    ok = branch >= 0
    idx = np.flatnonzero(ok)
    flips = idx[1:][branch[idx[1:]] != branch[idx[:-1]]]
    return PathIK(q=q_out, branch=branch, flips=flips)

