"""Compiled per-structure work of the atlas: the ZOA lobe envelope over a speed grid, the best
stable operating point on it, and the exact ZOA limit there.

For one structure (a pose's tool-tip modes seen in the cut frame) the two eigenvalue branches of
``G_or(f) B0`` are sampled on the log chatter-frequency grid of
:func:`stability.zoa.default_chatter_frequencies` and continued in frequency exactly as
:mod:`stability.zoa_batch` does (its compiled ``_k_branches``, ``_k_limit`` are reused). The lobe
``k`` of branch ``b`` maps a grid interval ``[f_i, f_i+1]`` to the speeds
``n_k(f) = 60 f / (N (eps(f) / 2 pi + k))``; every speed of the grid that falls in that image gets
the depth interpolated linearly in speed (the candidate depth of ``zoa_batch._k_limit``), and the
envelope is the smallest over all lobes and intervals. This costs ``O(n_freq x lobes + n_rpm)``
per structure instead of ``O(n_freq)`` per speed.

On the envelope the best stable cut is chosen (see :func:`planner.atlas.evaluate`), and the
limit at its speed is solved exactly (``zoa_batch._k_limit``: the bracketed Illinois solve of the
phase condition), so that the reported limit and depth are those of
:func:`stability.lobes.predict_point` at the chosen speed.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["atlas_kernel"]

#: The compiled helpers of :mod:`stability.zoa_batch`, bound by :func:`atlas_kernel` before compiling.
_k_branches = _k_limit = None


def _a_scan(fn, zeta, stiff, w, wres, f_lo, f_hi, teeth, n_freq, rpm, ap_lo, ap_hi, hi_code, c_pow, margin,
            out_env_min, out_rpm, out_ap, out_limit, out_freq, out_code, out_env):
    """Per structure group ``g``: envelope on ``rpm`` (geometric, ascending), the best cut, its
    exact limit.

    ``ap_hi`` is the depth bound that does not depend on speed (limits, force, torque; ``hi_code``
    names it), ``c_pow / rpm`` the power's depth bound (``inf``: none). The best speed maximises
    ``ap * rpm`` with ``ap = min(ap_hi, c_pow / rpm, margin * envelope)``, ``ap >= ap_lo``; among
    equal rates (to 1e-12) the one with the largest stability reserve ``margin * envelope / ap``,
    then the lowest speed. Codes: 0 stability, ``hi_code``, 4 power, -1 no feasible speed.
    ``out_env`` (``(G, n_rpm)``, or ``(0, 0)`` to skip) receives the envelopes.
    """
    n_rpm = rpm.shape[0]
    lo_rpm, hi_rpm = rpm[0], rpm[n_rpm - 1]
    freq = np.empty(n_freq)
    dep = np.empty((2, n_freq))
    pha = np.empty((2, n_freq))
    gap = np.empty(n_freq, dtype=np.complex128)
    valid = np.empty((2, n_freq - 1), dtype=np.bool_)
    env = np.empty(n_rpm)
    last = np.full(64, -1, dtype=np.int64)  # per lobe k: the grid index its last segment started at
    xs = 60.0 / teeth
    inv_lstep = (n_rpm - 1) / math.log(hi_rpm / lo_rpm)
    keep_env = out_env.shape[0] > 0
    for g in range(fn.shape[0]):
        fn_g, zeta_g, stiff_g, w_g, wres_g = fn[g], zeta[g], stiff[g], w[g], wres[g]
        _k_branches(f_lo[g], f_hi[g], fn_g, zeta_g, stiff_g, w_g, wres_g, freq, dep, pha, gap, valid)
        # ---- the envelope on the speed grid
        for j in range(n_rpm):
            env[j] = np.inf
        for b in range(2):
            last[:] = -1
            for i in range(n_freq - 1):
                if not valid[b, i]:
                    continue
                f0, f1, p0, p1 = freq[i], freq[i + 1], pha[b, i], pha[b, i + 1]
                kmin = min(xs * f0 / hi_rpm - p0, xs * f1 / hi_rpm - p1)
                kmax = max(xs * f0 / lo_rpm - p0, xs * f1 / lo_rpm - p1)
                for k in range(max(0, int(math.ceil(kmin - 1e-9))), int(math.floor(kmax + 1e-9)) + 1):
                    x0 = xs * f0 / (p0 + k)
                    x1 = xs * f1 / (p1 + k)
                    s_lo, s_hi = min(x0, x1), max(x0, x1)
                    if s_hi < lo_rpm or s_lo > hi_rpm:
                        continue
                    # first grid speed >= s_lo: walked from where this lobe's previous interval
                    # started (its segments are adjacent), found from the geometric grid at first
                    if k >= last.shape[0]:
                        more = np.full(2 * k + 2, -1, dtype=np.int64)
                        more[:last.shape[0]] = last
                        last = more
                    j0 = last[k]
                    if j0 < 0:
                        j0 = min(n_rpm - 1, max(0, int(math.log(s_lo / lo_rpm) * inv_lstep)))
                    while j0 > 0 and rpm[j0 - 1] >= s_lo:
                        j0 -= 1
                    while j0 < n_rpm and rpm[j0] < s_lo:
                        j0 += 1
                    last[k] = j0
                    j1 = j0
                    while j1 < n_rpm and rpm[j1] <= s_hi:
                        j1 += 1
                    for j in range(j0, j1):
                        t = (rpm[j] - x0) / (x1 - x0) if x1 != x0 else 0.5
                        t = min(max(t, 0.0), 1.0)
                        d = dep[b, i] + t * (dep[b, i + 1] - dep[b, i])
                        if d < env[j]:
                            env[j] = d
        emin = np.inf
        for j in range(n_rpm):
            emin = min(emin, env[j])
        out_env_min[g] = emin
        if keep_env:
            for j in range(n_rpm):
                out_env[g, j] = env[j]
        # ---- the best cut on the grid
        best_j, best_rate, best_res = -1, -1.0, -1.0
        for j in range(n_rpm):
            cap = min(ap_hi, c_pow / rpm[j])
            stab = margin * env[j]
            ap = min(cap, stab)
            if not ap >= ap_lo:
                continue
            rate = ap * rpm[j]
            res = stab / ap
            if rate > best_rate * (1.0 + 1e-12) or (rate >= best_rate * (1.0 - 1e-12) and res > best_res):
                best_j, best_rate, best_res = j, rate, res
        if best_j < 0:
            out_rpm[g], out_ap[g], out_limit[g], out_freq[g], out_code[g] = np.nan, np.nan, np.nan, np.nan, -1
            continue
        n_best = rpm[best_j]
        d, fc = _k_limit(n_best, teeth, freq, dep, pha, gap, valid, fn_g, zeta_g, stiff_g, w_g, wres_g)
        cap = min(ap_hi, c_pow / n_best)
        ap = min(cap, margin * d)
        code = 0
        if ap == cap:
            code = hi_code if ap_hi <= c_pow / n_best else 4
        if not ap >= ap_lo:
            code = -1
        out_rpm[g], out_ap[g], out_limit[g], out_freq[g], out_code[g] = n_best, ap, d, fc, code


_COMPILED: list = []


def atlas_kernel():
    """:func:`_a_scan` compiled by numba on first use (cached on disk), calling the compiled
    helpers of :mod:`stability.zoa_batch`."""
    if not _COMPILED:
        import numba

        from stability import zoa_batch

        zoa_batch.scan_kernel()  # binds the compiled helpers in zoa_batch's namespace
        g = globals()
        g["_k_branches"], g["_k_limit"] = zoa_batch._k_branches, zoa_batch._k_limit
        _COMPILED.append(numba.njit(cache=True)(_a_scan))
    return _COMPILED[0]
