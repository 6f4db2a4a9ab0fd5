"""Forward kinematics and the tool-tip Jacobian of a :class:`~planner.robot.description.Robot`,
vectorised over many poses.

Every function takes ``q`` in rad, shape ``(6,)`` or ``(n, 6)``, and returns arrays with a leading
``n`` axis (``n = 1`` for a single pose). Complex ``q`` is allowed (complex-step derivatives in
tests). Frames are 4x4 homogeneous transforms in the machine (``base_link``) frame.

The tool-tip frame of :func:`forward_kinematics` has the flange's axes as rotation columns and the
tool tip as origin; :func:`tool_axis` is the tool axis ``a`` (from the tip into the spindle) in the
machine frame. The Jacobian's rows are the tool tip's linear velocity then the angular velocity,
``J[:, :, i] = [z_i x (p_tip - o_i); z_i]`` for joint ``i`` with axis ``z_i`` through ``o_i``
(Siciliano et al., *Robotics: Modelling, Planning and Control*, Springer 2009, sec. 3.1).
"""

from __future__ import annotations

import numpy as np

from .description import Robot

__all__ = ["as_poses", "axis_rotation", "link_frames", "flange_frames", "forward_kinematics", "tool_axis",
           "tip_jacobian", "body_jacobians", "joint_axes_points"]


def as_poses(q) -> np.ndarray:
    """``q`` as an array of shape (n, 6) (float, or complex if complex)."""
    q = np.asarray(q)
    if not np.iscomplexobj(q):
        q = q.astype(float)
    if q.ndim == 1:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != 6:
        raise ValueError(f"joint angles must have shape (6,) or (n, 6); found {q.shape}")
    return q


def _cross(a, b):
    """Cross product of (..., 3) arrays (faster than np.cross on many short vectors)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def axis_rotation(axis, angle) -> np.ndarray:
    """Rotation matrices about the unit ``axis`` (3,) by ``angle`` (n,): shape (n, 3, 3) (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def _canonical(robot: Robot):
    """Joint origins re-expressed so that every joint turns about its frame's z axis:
    ``Rot(axis, q) = P Rz(q) P^T`` with ``P`` taking z to ``axis``; returns the new origins'
    rotations (6, 3, 3) and offsets (6, 3), and ``P`` (6, 3, 3) (body ``i`` frame = canonical
    frame ``i`` @ ``P_i^T``)."""
    ps = []
    for axis in robot.joint_axis:
        z = np.asarray(axis, float)
        helper = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
        x = helper - (helper @ z) * z
        x /= np.linalg.norm(x)
        ps.append(np.column_stack([x, np.cross(z, x), z]))
    ps = np.array(ps)
    rots, offs = [], []
    prev = np.eye(3)
    for i in range(6):
        a = robot.joint_origin[i]
        rots.append(prev.T @ a[:3, :3] @ ps[i])
        offs.append(prev.T @ a[:3, 3])
        prev = ps[i]
    return np.array(rots), np.array(offs), ps


def link_frames(robot: Robot, q) -> tuple[np.ndarray, np.ndarray]:
    """Frames of bodies 1..6 in the machine frame.

    Returns
    -------
    rotation : ndarray, shape (n, 6, 3, 3)
    origin : ndarray, shape (n, 6, 3)
        Body ``i``'s frame is joint ``i``'s frame: its origin lies on joint ``i``'s axis.
    """
    q = as_poses(q)
    n = q.shape[0]
    rots, offs, ps = _canonical(robot)
    rot = np.empty((n, 6, 3, 3), dtype=q.dtype)
    pos = np.empty((n, 6, 3), dtype=q.dtype)
    r = np.broadcast_to(np.eye(3), (n, 3, 3)).astype(q.dtype)
    p = np.zeros((n, 3), dtype=q.dtype)
    c, s = np.cos(q), np.sin(q)
    for i in range(6):
        p = p + r @ offs[i]
        r = r @ rots[i]
        x, y = r[:, :, 0], r[:, :, 1]
        ci, si = c[:, i, None], s[:, i, None]
        r = np.stack([ci * x + si * y, ci * y - si * x, r[:, :, 2]], axis=-1)  # r @ Rz(q_i)
        rot[:, i] = r @ ps[i].T
        pos[:, i] = p
    return rot, pos


def flange_frames(robot: Robot, q) -> np.ndarray:
    """Flange frames, shape (n, 4, 4)."""
    rot, pos = link_frames(robot, q)
    return _compose(rot[:, 5], pos[:, 5], robot.flange_origin)


def _compose(rot, pos, t) -> np.ndarray:
    n = rot.shape[0]
    out = np.zeros((n, 4, 4), dtype=rot.dtype)
    out[:, :3, :3] = rot @ t[:3, :3]
    out[:, :3, 3] = pos + rot @ t[:3, 3]
    out[:, 3, 3] = 1.0
    return out


def forward_kinematics(robot: Robot, q) -> np.ndarray:
    """Tool-tip frames: flange axes as rotation columns, the tool tip as origin.

    Parameters
    ----------
    robot : Robot
    q : array_like, shape (6,) or (n, 6)
        Joint angles (URDF values), rad.

    Returns
    -------
    ndarray, shape (n, 4, 4)
        ``T[:, :3, :3]`` the flange orientation, ``T[:, :3, 3]`` the tool tip, m, machine frame.
    """
    f = flange_frames(robot, q)
    f[:, :3, 3] = f[:, :3, 3] + f[:, :3, :3] @ robot.tool.tip_m
    return f


def tool_axis(robot: Robot, q) -> np.ndarray:
    """The tool axis ``a`` (tip into spindle) in the machine frame, shape (n, 3), unit."""
    f = flange_frames(robot, q)
    return f[:, :3, :3] @ robot.tool.axis


def joint_axes_points(robot: Robot, q) -> tuple[np.ndarray, np.ndarray]:
    """Joint axes ``z_i`` (n, 6, 3) and a point ``o_i`` on each (n, 6, 3), machine frame."""
    rot, pos = link_frames(robot, q)
    z = np.einsum("nijk,ik->nij", rot, robot.joint_axis)
    return z, pos


def body_jacobians(z, o, points, upto) -> np.ndarray:
    """Linear-velocity Jacobians of points moving with bodies.

    Parameters
    ----------
    z, o : ndarray, shape (n, 6, 3)
        Joint axes and points on them.
    points : ndarray, shape (n, m, 3)
        Points, machine frame.
    upto : sequence of int, length m
        Point ``j`` moves with body ``upto[j]`` (1..6): joints ``1..upto[j]`` move it.

    Returns
    -------
    ndarray, shape (n, m, 3, 6)
    """
    d = points[:, :, None, :] - o[:, None, :, :]  # (n, m, 6, 3)
    jv = _cross(np.broadcast_to(z[:, None], d.shape), d)  # (n, m, 6, 3)
    mask = np.arange(6)[None, :] < np.asarray(upto)[:, None]  # (m, 6)
    jv = jv * mask[None, :, :, None]
    return np.swapaxes(jv, -1, -2)


def tip_jacobian(robot: Robot, q) -> np.ndarray:
    """The tool tip's geometric Jacobian.

    Parameters
    ----------
    robot : Robot
    q : array_like, shape (6,) or (n, 6)
        rad.

    Returns
    -------
    ndarray, shape (n, 6, 6)
        Rows 0-2: tool-tip linear velocity (m/s per rad/s), machine frame; rows 3-5: angular
        velocity (rad/s per rad/s). Columns: joints 1..6.
    """
    return _tip_jacobian(robot, *link_frames(robot, q))


def _tip_jacobian(robot: Robot, rot, pos) -> np.ndarray:
    z = np.einsum("nijk,ik->nij", rot, robot.joint_axis)
    tip = _compose(rot[:, 5], pos[:, 5], robot.flange_origin)
    p = tip[:, :3, 3] + tip[:, :3, :3] @ robot.tool.tip_m
    jac = np.empty((z.shape[0], 6, 6), dtype=z.dtype)
    jac[:, :3, :] = np.swapaxes(_cross(z, p[:, None, :] - pos), 1, 2)
    jac[:, 3:, :] = np.swapaxes(z, 1, 2)
    return jac
