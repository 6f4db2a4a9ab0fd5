"""Pose-by-pose kernel (numba) of the quantities :func:`planner.robot.dynamics.robot_modes` needs:
the joint-space mass matrix (composite rigid bodies) and the tool tip's translational Jacobian.

The same mathematics as :func:`planner.robot.dynamics.mass_matrix` and
:func:`planner.robot.kinematics.tip_jacobian` (which stay the vectorised NumPy reference, and the
tests check this kernel against them); written as scalar loops so that 100 000 poses take a
fraction of a second instead of seconds of small-matrix NumPy calls.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def mass_and_tip_jacobian(q, rots, offs, ps, mass, com, inertia, tip, m_out, jv_out):
    """For each pose ``q[n]`` (6,): ``m_out[n]`` (6, 6) and ``jv_out[n]`` (3, 6).

    ``rots, offs`` (6, 3, 3), (6, 3): canonical joint origins (each joint about its frame's z);
    ``ps`` (6, 3, 3): canonical to body frame rotations; ``mass, com, inertia``: bodies in their
    own frames (tool lumped into body 6); ``tip`` (3,): tool tip in body 6's frame.
    """
    n = q.shape[0]
    r = np.empty((3, 3))
    rb = np.empty((6, 3, 3))
    pos = np.empty((6, 3))
    z = np.empty((6, 3))
    tmp = np.empty((3, 3))
    c_b = np.empty(3)
    i_b = np.empty((3, 3))
    c_c = np.empty(3)
    i_c = np.empty((3, 3))
    force = np.empty(3)
    moment = np.empty(3)
    for k in range(n):
        # ---- frames
        for a in range(3):
            for b in range(3):
                r[a, b] = 1.0 if a == b else 0.0
        p0 = 0.0
        p1 = 0.0
        p2 = 0.0
        for i in range(6):
            o = offs[i]
            p0 += r[0, 0] * o[0] + r[0, 1] * o[1] + r[0, 2] * o[2]
            p1 += r[1, 0] * o[0] + r[1, 1] * o[1] + r[1, 2] * o[2]
            p2 += r[2, 0] * o[0] + r[2, 1] * o[1] + r[2, 2] * o[2]
            for a in range(3):
                for b in range(3):
                    tmp[a, b] = r[a, 0] * rots[i, 0, b] + r[a, 1] * rots[i, 1, b] + r[a, 2] * rots[i, 2, b]
            c = math.cos(q[k, i])
            s = math.sin(q[k, i])
            for a in range(3):
                x = tmp[a, 0]
                y = tmp[a, 1]
                r[a, 0] = c * x + s * y
                r[a, 1] = c * y - s * x
                r[a, 2] = tmp[a, 2]
            # joint axis in the world = canonical z
            z[i, 0] = r[0, 2]
            z[i, 1] = r[1, 2]
            z[i, 2] = r[2, 2]
            for a in range(3):
                for b in range(3):
                    rb[i, a, b] = r[a, 0] * ps[i, b, 0] + r[a, 1] * ps[i, b, 1] + r[a, 2] * ps[i, b, 2]
            pos[i, 0] = p0
            pos[i, 1] = p1
            pos[i, 2] = p2
        # ---- tool tip and its Jacobian
        t0 = pos[5, 0] + rb[5, 0, 0] * tip[0] + rb[5, 0, 1] * tip[1] + rb[5, 0, 2] * tip[2]
        t1 = pos[5, 1] + rb[5, 1, 0] * tip[0] + rb[5, 1, 1] * tip[1] + rb[5, 1, 2] * tip[2]
        t2 = pos[5, 2] + rb[5, 2, 0] * tip[0] + rb[5, 2, 1] * tip[1] + rb[5, 2, 2] * tip[2]
        for i in range(6):
            d0 = t0 - pos[i, 0]
            d1 = t1 - pos[i, 1]
            d2 = t2 - pos[i, 2]
            jv_out[k, 0, i] = z[i, 1] * d2 - z[i, 2] * d1
            jv_out[k, 1, i] = z[i, 2] * d0 - z[i, 0] * d2
            jv_out[k, 2, i] = z[i, 0] * d1 - z[i, 1] * d0
        # ---- composite rigid bodies, from the last body back
        m_c = 0.0
        for a in range(3):
            c_c[a] = 0.0
            for b in range(3):
                i_c[a, b] = 0.0
        for j in range(5, -1, -1):
            for a in range(3):
                c_b[a] = pos[j, a] + rb[j, a, 0] * com[j, 0] + rb[j, a, 1] * com[j, 1] + rb[j, a, 2] * com[j, 2]
            for a in range(3):
                for b in range(3):
                    tmp[a, b] = rb[j, a, 0] * inertia[j, 0, b] + rb[j, a, 1] * inertia[j, 1, b] + rb[j, a, 2] * inertia[j, 2, b]
            for a in range(3):
                for b in range(3):
                    i_b[a, b] = tmp[a, 0] * rb[j, b, 0] + tmp[a, 1] * rb[j, b, 1] + tmp[a, 2] * rb[j, b, 2]
            m_new = m_c + mass[j]
            cn0 = (m_c * c_c[0] + mass[j] * c_b[0]) / m_new if m_new > 0 else c_b[0]
            cn1 = (m_c * c_c[1] + mass[j] * c_b[1]) / m_new if m_new > 0 else c_b[1]
            cn2 = (m_c * c_c[2] + mass[j] * c_b[2]) / m_new if m_new > 0 else c_b[2]
            # parallel-axis shifts of the old composite and the new body to the new centre
            e0 = c_c[0] - cn0
            e1 = c_c[1] - cn1
            e2 = c_c[2] - cn2
            f0 = c_b[0] - cn0
            f1 = c_b[1] - cn1
            f2 = c_b[2] - cn2
            ee = e0 * e0 + e1 * e1 + e2 * e2
            ff = f0 * f0 + f1 * f1 + f2 * f2
            ev = (e0, e1, e2)
            fv = (f0, f1, f2)
            for a in range(3):
                for b in range(3):
                    delta = 1.0 if a == b else 0.0
                    i_c[a, b] = (i_c[a, b] + i_b[a, b] + m_c * (ee * delta - ev[a] * ev[b])
                                 + mass[j] * (ff * delta - fv[a] * fv[b]))
            m_c = m_new
            c_c[0] = cn0
            c_c[1] = cn1
            c_c[2] = cn2
            d0 = c_c[0] - pos[j, 0]
            d1 = c_c[1] - pos[j, 1]
            d2 = c_c[2] - pos[j, 2]
            force[0] = m_c * (z[j, 1] * d2 - z[j, 2] * d1)
            force[1] = m_c * (z[j, 2] * d0 - z[j, 0] * d2)
            force[2] = m_c * (z[j, 0] * d1 - z[j, 1] * d0)
            for a in range(3):
                moment[a] = i_c[a, 0] * z[j, 0] + i_c[a, 1] * z[j, 1] + i_c[a, 2] * z[j, 2]
            for i in range(j + 1):
                g0 = c_c[0] - pos[i, 0]
                g1 = c_c[1] - pos[i, 1]
                g2 = c_c[2] - pos[i, 2]
                w0 = moment[0] + g1 * force[2] - g2 * force[1]
                w1 = moment[1] + g2 * force[0] - g0 * force[2]
                w2 = moment[2] + g0 * force[1] - g1 * force[0]
                tau = z[i, 0] * w0 + z[i, 1] * w1 + z[i, 2] * w2
                m_out[k, i, j] = tau
                m_out[k, j, i] = tau
