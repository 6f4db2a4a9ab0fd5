"""The residual correction of the rigid-link model: joint stiffness that softens with reach.

Rigid-link, compliant-joint models come out too stiff in stretched poses (Nguyen, Cvitanic &
Melkote 2020): the links bend and the main bearings tilt, and both add compliance that grows with
the lever arm from the shoulder to the tool tip. The correction keeps the physics model and makes
the stiffness of the shoulder and elbow joints (2 and 3) a function of that lever arm,

    k_j(q) = k_j exp(-gamma (r(q) - r_ref) / r_ref),   j in joints,

with ``r(q)`` the distance from joint 2's axis point to the tool tip (m) and ``r_ref`` the mean
over the calibration poses. ``gamma`` is fitted with the joint stiffnesses by ``robot calibrate``
(one extra parameter; ``gamma = 0`` is the plain physics model). Stored in the robot file under
``x_correction``: ``{kind: reach, gamma: ..., reference_reach_m: ..., joints: [2, 3]}``.
"""

from __future__ import annotations

import numpy as np

from .description import Robot
from .kinematics import as_poses, forward_kinematics, link_frames

__all__ = ["reach_m", "corrected_stiffness", "correction_factor", "CORRECTION_JOINTS"]

#: Joints (1-based) whose stiffness the correction scales: the shoulder and the elbow.
CORRECTION_JOINTS = (2, 3)


def reach_m(robot: Robot, q) -> np.ndarray:
    """Distance from joint 2's axis point to the tool tip, shape (n,), m."""
    q = as_poses(q)
    _, pos = link_frames(robot, q)
    tip = forward_kinematics(robot, q)[:, :3, 3]
    return np.linalg.norm(tip - pos[:, 1], axis=-1)


def correction_factor(reach, gamma: float, reference_reach_m: float, joints=CORRECTION_JOINTS) -> np.ndarray:
    """Stiffness factors, shape (n, 6), for reaches (n,) m."""
    factor = np.ones((np.size(reach), 6))
    scale = np.exp(-gamma * (np.asarray(reach, float) - reference_reach_m) / reference_reach_m)
    for j in joints:
        factor[:, j - 1] = scale
    return factor


def corrected_stiffness(robot: Robot, q) -> np.ndarray:
    """The robot's joint stiffness at each pose, shape (n, 6), N m/rad, its correction applied."""
    q = as_poses(q)
    k = np.broadcast_to(robot.joint_stiffness_N_m_rad, (q.shape[0], 6))
    c = robot.correction
    if not c or float(c.get("gamma", 0.0)) == 0.0:
        return np.array(k)
    return k * correction_factor(reach_m(robot, q), float(c["gamma"]), float(c["reference_reach_m"]),
                                 tuple(c.get("joints", CORRECTION_JOINTS)))
