"""The closed-form inverse-kinematics kernel (numba): one target at a time, all eight branches.

See :mod:`planner.robot.ik` for the method (Paden-Kahan subproblems on the product of
exponentials); this module holds only the scalar loop so that numba compiles it to tight code
(100 000 targets x 8 branches in a fraction of a second).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _rot(w, c, s, v, out):
    """out = Rot(w, angle) v with c = cos(angle), s = sin(angle) (Rodrigues)."""
    k = (v[0] * w[0] + v[1] * w[1] + v[2] * w[2]) * (1.0 - c)
    o0 = v[0] * c + (w[1] * v[2] - w[2] * v[1]) * s + w[0] * k
    o1 = v[1] * c + (w[2] * v[0] - w[0] * v[2]) * s + w[1] * k
    o2 = v[2] * c + (w[0] * v[1] - w[1] * v[0]) * s + w[2] * k
    out[0], out[1], out[2] = o0, o1, o2


@numba.njit(cache=True, inline="always")
def _angle(w, a, b):
    """Signed angle about w from a to b (their parts normal to w)."""
    sin = w[0] * (a[1] * b[2] - a[2] * b[1]) + w[1] * (a[2] * b[0] - a[0] * b[2]) + w[2] * (a[0] * b[1] - a[1] * b[0])
    aw = a[0] * w[0] + a[1] * w[1] + a[2] * w[2]
    bw = b[0] * w[0] + b[1] * w[1] + b[2] * w[2]
    cos = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] - aw * bw
    return math.atan2(sin, cos)


@numba.njit(cache=True, inline="always")
def _wrap(x):
    return (x + math.pi) % (2.0 * math.pi) - math.pi


@numba.njit(cache=True)
def solve_all(wc, t6, v6t, w, p, wc0, v6, lower, upper, q, reachable, within):
    """All branches for targets ``i``.

    Parameters
    ----------
    wc : (n, 3) wrist centres; t6, v6t : (n, 3) the target flange orientation applied to joint
    6's zero-pose axis and to a vector ``v6`` normal to it (``R_t R_F0^T w6``, ``R_t R_F0^T v6``);
    w, p : (6, 3) zero-pose joint axes and points; wc0 : (3,) zero-pose wrist centre.
    lower, upper : (6,) joint limits, rad.
    q : (n, 8, 6) out (NaN where unreachable); reachable, within : (n, 8) out (``within``: every
    joint inside its limits, after a 2 pi shift where one brings it inside).
    """
    n = wc.shape[0]
    w1, w2, w3, w4, w5, w6 = w[0], w[1], w[2], w[3], w[4], w[5]
    d12 = w2[0] * w1[0] + w2[1] * w1[1] + w2[2] * w1[2]
    w2p = w2 - d12 * w1
    cr12 = np.cross(w1, w2p)
    lat = w2[0] * (wc0[0] - p[0, 0]) + w2[1] * (wc0[1] - p[0, 1]) + w2[2] * (wc0[2] - p[0, 2])
    x = wc0 - p[2]
    x_p = x - (x[0] * w3[0] + x[1] * w3[1] + x[2] * w3[2]) * w3
    y = p[1] - p[2]
    y_p = y - (y[0] * w3[0] + y[1] * w3[1] + y[2] * w3[2]) * w3
    rx = math.sqrt(x_p[0] ** 2 + x_p[1] ** 2 + x_p[2] ** 2)
    ry = math.sqrt(y_p[0] ** 2 + y_p[1] ** 2 + y_p[2] ** 2)
    theta0 = _angle(w3, x_p, y_p)
    c45 = w4[0] * w5[0] + w4[1] * w5[1] + w4[2] * w5[2]
    c56 = w5[0] * w6[0] + w5[1] * w6[1] + w5[2] * w6[2]
    cr45 = np.cross(w4, w5)
    n45 = cr45[0] ** 2 + cr45[1] ** 2 + cr45[2] ** 2
    den = c45 * c45 - 1.0
    v = np.empty(3)
    u = np.empty(3)
    du = np.empty(3)
    x2 = np.empty(3)
    ta = np.empty(3)

    va = np.empty(3)
    vb = np.empty(3)
    z = np.empty(3)
    e1 = np.empty(3)
    e2 = np.empty(3)
    for i in range(n):
        for k in range(3):
            v[k] = wc[i, k] - p[0, k]
        a_c = v[0] * w2p[0] + v[1] * w2p[1] + v[2] * w2p[2]
        b_c = v[0] * cr12[0] + v[1] * cr12[1] + v[2] * cr12[2]
        c_c = lat - d12 * (v[0] * w1[0] + v[1] * w1[1] + v[2] * w1[2])
        r = math.hypot(a_c, b_c)
        ratio = c_c / r if r > 0 else 0.0
        ok1 = abs(ratio) <= 1.0 + 1e-12
        base = math.atan2(b_c, a_c)
        delta = math.acos(min(1.0, max(-1.0, ratio)))
        for i1 in range(2):
            q1 = base - delta if i1 == 0 else base + delta
            c1, s1 = math.cos(q1), math.sin(q1)
            _rot(w1, c1, -s1, v, u)
            for k in range(3):
                u[k] += p[0, k]
                du[k] = u[k] - p[1, k]
            dw = du[0] * w2[0] + du[1] * w2[1] + du[2] * w2[2]
            delta2 = du[0] ** 2 + du[1] ** 2 + du[2] ** 2 - dw * dw
            cos3 = (rx * rx + ry * ry - delta2) / (2.0 * rx * ry)
            ok3 = abs(cos3) <= 1.0 + 1e-12
            acos3 = math.acos(min(1.0, max(-1.0, cos3)))
            for i3 in range(2):
                q3 = theta0 + acos3 if i3 == 0 else theta0 - acos3
                c3, s3 = math.cos(q3), math.sin(q3)
                _rot(w3, c3, s3, x, x2)
                for k in range(3):
                    x2[k] += p[2, k] - p[1, k]
                q2 = _angle(w2, x2, du)
                c2, s2 = math.cos(q2), math.sin(q2)
                # pull the target's joint-6 axis and reference vector back through joints 1-3
                _rot(w1, c1, -s1, t6[i], e1)
                _rot(w2, c2, -s2, e1, e2)
                _rot(w3, c3, -s3, e2, ta)
                _rot(w1, c1, -s1, v6t[i], e1)
                _rot(w2, c2, -s2, e1, e2)
                _rot(w3, c3, -s3, e2, va)
                t4 = ta[0] * w4[0] + ta[1] * w4[1] + ta[2] * w4[2]
                alpha = (c45 * c56 - t4) / den
                beta = (c45 * t4 - c56) / den
                g2 = (1.0 - alpha * alpha - beta * beta - 2.0 * alpha * beta * c45) / n45
                okw = g2 >= -1e-9
                g = math.sqrt(max(g2, 0.0))
                for iw in range(2):
                    gam = g if iw == 0 else -g
                    for k in range(3):
                        z[k] = alpha * w4[k] + beta * w5[k] + gam * cr45[k]
                    q5 = _angle(w5, w6, z)
                    q4 = _angle(w4, z, ta)
                    _rot(w4, math.cos(q4), -math.sin(q4), va, e1)
                    _rot(w5, math.cos(q5), -math.sin(q5), e1, vb)
                    q6 = _angle(w6, v6, vb)
                    b = 4 * i1 + 2 * i3 + iw
                    q[i, b, 0] = _wrap(q1)
                    q[i, b, 1] = q2
                    q[i, b, 2] = _wrap(q3)
                    q[i, b, 3] = q4
                    q[i, b, 4] = q5
                    q[i, b, 5] = q6
                    ok = ok1 and ok3 and okw
                    reachable[i, b] = ok
                    inside = ok
                    for j in range(6):
                        qj = q[i, b, j]
                        if qj < lower[j] - 1e-12 or qj > upper[j] + 1e-12:
                            if lower[j] - 1e-12 <= qj + 2.0 * math.pi <= upper[j] + 1e-12:
                                q[i, b, j] = qj + 2.0 * math.pi
                            elif lower[j] - 1e-12 <= qj - 2.0 * math.pi <= upper[j] + 1e-12:
                                q[i, b, j] = qj - 2.0 * math.pi
                            else:
                                inside = False
                        if not ok:
                            q[i, b, j] = math.nan
                    within[i, b] = inside

