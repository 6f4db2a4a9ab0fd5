"""Compiled per-structure work of the atlas: the ZOA lobe envelope over a speed grid, the best
stable operating point on it, and the exact ZOA limit there.

For one structure (a pose's tool-tip modes seen in the cut frame) the two eigenvalue branches of
``G_or(f) B0`` (zero-order approximation, Altintas & Budak, CIRP Annals 44(1), 1995, as
:mod:`stability.zoa`) are sampled on a chatter-frequency grid and continued in frequency by
:mod:`stability.zoa`'s rule; the compiled helpers of :mod:`stability.zoa_batch` evaluate the
eigenvalues and solve the phase condition.

**The grid** is the log grid of :func:`stability.zoa.default_chatter_frequencies` (``n_freq`` lines
from a third of the lowest to three times the highest mode) plus, around every mode, lines at
``fn (1 + zeta sinh(u))``, ``u`` in steps of ``1 / MODE_STEPS``: ``MODE_STEPS`` lines per ``zeta
fn`` at the peak, wider apart away from it, as far as the log grid is coarser. A mode turns the
eigenvalue over a band ``~2 zeta fn`` wide, which the log grid alone does not resolve for a lightly
damped one (500 lines over 2-2200 Hz are 1.3 % apart: three lines across a 720 Hz tool mode with
2 % damping).

**Lobe segments.** Lobe ``k`` of continued branch ``b`` maps a grid interval ``[f_i, f_i+1]`` to the
speeds ``n_k(f) = 60 f / (N (eps(f) / 2 pi + k))``; along it the inverse critical depth ``q = 2 Re
lambda`` is interpolated in the tooth period ``1 / n``, linearly plus a curvature term from the
neighbouring lines (:func:`_a_segments`). An interval in which the branch's real part changes sign
(the lobe's onset, critical depth -> infinity) is a segment from the onset (``Re lambda``
interpolated linearly; ``eps`` is 0 or 2 pi there, ``q`` 0) to the finite end. ``stability.zoa``
and ``zoa_batch`` skip such intervals (their candidates have a finite depth at both ends): on a
coarse grid a whole lobe flank lies in one, down to depths near the lobe's minimum, and the atlas
gave its speeds to the next lobe up (0.23 m at 24 000 rpm where the 720 Hz lobe gives 12.9 mm).

**Envelope and best cut.** Every grid speed in a segment's image gets the interpolated depth; the
envelope is the smallest over all segments and lobes (``O(n_lines x lobes + n_rpm)`` per structure;
``min_depth_limit_m`` is its smallest value, or an exact limit below it). The best cut is chosen on
it (see :func:`planner.atlas.evaluate`); the limit at its speed, and at up to ``RANK_MORE`` other
speeds whose rate is within ``RANK_TOL`` of it, is solved exactly, as :func:`_a_limit` does:
every segment whose image holds the speed and whose interpolated depth is within ``_PRESELECT`` of
the smallest is solved for the chatter frequency (``zoa_batch._k_solve``, Illinois on the phase
condition; an onset segment bracketed from the exact onset, ``zoa_batch._k_onset``: Illinois on
``Re lambda`` to 1e-13, as :mod:`stability.zoa`), which is :func:`stability.lobes.predict_point`'s
limit, onsets included.
"""

from __future__ import annotations

import math

import numpy as np

from stability._zoa_curves import MODE_LINES, MODE_STEPS

__all__ = ["atlas_kernel", "MODE_STEPS", "MODE_LINES"]

# The lines around each mode are the library's (stability.zoa's grid, :mod:`stability._zoa_curves`):
# MODE_STEPS lines per ``zeta fn`` at a mode's peak (with the curvature term the envelope's smallest
# value is within 2e-3 of the exact one, measured; 6 would cost ~15 % more; docs/atlas.md), at most
# MODE_LINES on each side of a mode (a damping ratio of 1e-4 needs ~28 at 500 lines).
#: The best speed is chosen on the interpolated envelope, then solved exactly together with up to
#: ``RANK_MORE`` other speeds whose interpolated rate is within ``RANK_TOL`` of the best and where
#: stability may bind (the interpolation error of the envelope: measured up to 3.4 %, on a lobe's
#: steep flank next to its onset); the best of these by the exact limit wins.
RANK_TOL = 0.05
RANK_MORE = 3
#: Bound of the curvature term of a segment, relative to its larger end (see :func:`_a_segments`).
_CURVE_MAX = 0.1
#: As ``stability.zoa._PRESELECT_FACTOR``: candidates within this factor of the smallest
#: interpolated depth at a speed are solved exactly.
_PRESELECT = 1.25

#: The compiled helpers of :mod:`stability.zoa_batch`, bound by :func:`atlas_kernel` before compiling.
_k_lam = _k_depth_phase = _k_branch = _k_solve = _k_grid = _k_onset = _k_sample = None


def _a_segments(n, freq, lam, dep, pha, seg, has):
    """Per branch ``b`` and grid interval ``i``: the lobe segment ``seg[b, i] = (f0, p0, q0, f1, p1,
    q1, c)`` (frequency, phase in turns, inverse depth ``q = 2 Re lambda`` at both ends, and the
    curvature term ``c`` of ``q``) and whether there is one (``has``).

    Both ends finite: the grid lines, and ``q(t) = (1 - t) q0 + t q1 + c t (1 - t)`` along the
    segment with ``c = -q'' (f1 - f0)^2 / 2`` from the second divided differences of ``2 Re
    lambda`` at the two ends (linear interpolation alone is 1.6 % low at a mode's peak with
    ``MODE_STEPS = 4``; the term is bounded by ``_CURVE_MAX`` of the larger end, as a kink at a
    double eigenvalue is no parabola). One end finite: the other end is the onset ``Re lambda =
    0`` (linear in frequency between the lines), where the phase is 1 turn if ``Im lambda > 0``
    there, else 0; ``q = 0`` there and ``c = 0``."""
    for b in range(2):
        for i in range(n - 1):
            fin0, fin1 = dep[b, i] < np.inf, dep[b, i + 1] < np.inf
            has[b, i] = fin0 or fin1
            if not (fin0 or fin1):
                continue
            f0, f1 = freq[i], freq[i + 1]
            if fin0 and fin1:
                q0, q1 = 1.0 / dep[b, i], 1.0 / dep[b, i + 1]
                seg[b, i, 0], seg[b, i, 1], seg[b, i, 2] = f0, pha[b, i], q0
                seg[b, i, 3], seg[b, i, 4], seg[b, i, 5] = f1, pha[b, i + 1], q1
                slope = 2.0 * (lam[b, i + 1].real - lam[b, i].real) / (f1 - f0)
                d2, m = 0.0, 0
                if i > 0:
                    fm = freq[i - 1]
                    d2 += 2.0 * (slope - 2.0 * (lam[b, i].real - lam[b, i - 1].real) / (f0 - fm)) / (f1 - fm)
                    m += 1
                if i + 2 < n:
                    fp = freq[i + 2]
                    d2 += 2.0 * (2.0 * (lam[b, i + 2].real - lam[b, i + 1].real) / (fp - f1) - slope) / (fp - f0)
                    m += 1
                c = -0.5 * d2 / m * (f1 - f0) ** 2 if m > 0 else 0.0
                bound = _CURVE_MAX * max(q0, q1)
                seg[b, i, 6] = min(max(c, -bound), bound)
                continue
            la, lb = lam[b, i], lam[b, i + 1]
            t = la.real / (la.real - lb.real)
            fc = f0 + t * (f1 - f0)
            im = la.imag + t * (lb.imag - la.imag)
            seg[b, i, 6] = 0.0
            if fin1:
                pc = 1.0 if (im > 0.0 or (im == 0.0 and pha[b, i + 1] > 0.5)) else 0.0
                seg[b, i, 0], seg[b, i, 1], seg[b, i, 2] = fc, pc, 0.0
                seg[b, i, 3], seg[b, i, 4], seg[b, i, 5] = f1, pha[b, i + 1], 1.0 / dep[b, i + 1]
            else:
                pc = 1.0 if (im > 0.0 or (im == 0.0 and pha[b, i] > 0.5)) else 0.0
                seg[b, i, 0], seg[b, i, 1], seg[b, i, 2] = f0, pha[b, i], 1.0 / dep[b, i]
                seg[b, i, 3], seg[b, i, 4], seg[b, i, 5] = fc, pc, 0.0


def _a_depth(seg_bi, k, y, xs):
    """Interpolated depth of lobe ``k`` on segment ``seg_bi`` at tooth-period coordinate ``y = 1 /
    rpm``: ``2 Re lambda`` along the segment (:func:`_a_segments`) with ``t`` linear in ``y`` between
    the ends; ``inf`` where it is not positive."""
    y0 = (seg_bi[1] + k) / (xs * seg_bi[0])
    y1 = (seg_bi[4] + k) / (xs * seg_bi[3])
    t = (y - y0) / (y1 - y0) if y1 != y0 else 0.5
    t = min(max(t, 0.0), 1.0)
    q = seg_bi[2] + t * (seg_bi[5] - seg_bi[2]) + seg_bi[6] * t * (1.0 - t)
    return 1.0 / q if q > 0.0 else np.inf


def _a_limit(rpm, teeth, n_lines, freq, dep, pha, gap, seg, has, fn, zeta, stiff, w, wres):
    """Exact ZOA limit depth and chatter frequency at one speed (as ``stability.zoa._lowest_lobe``,
    onset segments included): the candidates are the lobe segments whose image holds the speed;
    those within ``_PRESELECT`` of the smallest interpolated depth are solved exactly, an onset
    segment's from the exact onset (``zoa_batch._k_onset``, as ``zoa_batch`` and ``stability.zoa``
    bracket it)."""
    xs = 60.0 / teeth
    y = 1.0 / rpm
    inv = xs / rpm
    cap = 256
    cand = np.empty((cap, 4))
    n_cand = 0
    best = np.inf
    for b in range(2):
        for i in range(n_lines - 1):
            if not has[b, i]:
                continue
            s = seg[b, i]
            # lobe k holds the speed iff k lies between h0 and h1 (1e-9: the test below decides)
            h0 = s[0] * inv - s[1]
            h1 = s[3] * inv - s[4]
            ka = max(0, int(math.ceil(min(h0, h1) - 1e-9)))
            kb = int(math.floor(max(h0, h1) + 1e-9))
            for k in range(ka, kb + 1):
                y0 = (s[1] + k) / (xs * s[0])
                y1 = (s[4] + k) / (xs * s[3])
                if not (min(y0, y1) <= y <= max(y0, y1)):
                    continue
                d = _a_depth(s, k, y, xs)
                if n_cand == cap:
                    more = np.empty((2 * cap, 4))
                    more[:cap] = cand
                    cand, cap = more, 2 * cap
                cand[n_cand, 0], cand[n_cand, 1], cand[n_cand, 2], cand[n_cand, 3] = b, k, i, d
                n_cand += 1
                best = min(best, d)
    out_d, out_f = np.inf, np.nan
    for j in range(n_cand):
        if not cand[j, 3] <= _PRESELECT * best:
            continue
        b, k, i = int(cand[j, 0]), int(cand[j, 1]), int(cand[j, 2])
        f_a, f_b, g_a, g_b = freq[i], freq[i + 1], gap[i], gap[i + 1]
        if not dep[b, i] < np.inf:  # onset on the left: bracket from it
            _, _, f_a, g_a = _k_onset(b, f_a, f_b, g_a, g_b, pha[b, i + 1], fn, zeta, stiff, w, wres)
        elif not dep[b, i + 1] < np.inf:  # onset on the right
            _, _, f_b, g_b = _k_onset(b, f_a, f_b, g_a, g_b, pha[b, i], fn, zeta, stiff, w, wres)
        d, f, res = _k_solve(b, k, rpm, teeth, f_a, f_b, g_a, g_b, fn, zeta, stiff, w, wres)
        if d < np.inf and abs(res) < 1e-8 and d < out_d:
            out_d, out_f = d, f
    return out_d, out_f


def _a_scan(fn, zeta, stiff, w, wres, f_lo, f_hi, teeth, n_freq, rpm, ap_lo, ap_hi, hi_code, c_pow, margin,
            out_env_min, out_rpm, out_ap, out_limit, out_freq, out_code, out_env):
    """Per structure group ``g``: envelope on ``rpm`` (geometric, ascending), the best cut, its
    exact limit, and the smallest limit over the speed grid.

    ``ap_hi`` is the depth bound that does not depend on speed (limits, force, torque; ``hi_code``
    names it), ``c_pow / rpm`` the power's depth bound (``inf``: none). The best speed maximises
    ``ap * rpm`` with ``ap = min(ap_hi, c_pow / rpm, margin * limit)``, ``ap >= ap_lo``; among
    equal rates (to 1e-12) the one with the largest stability reserve ``margin * limit / ap``,
    then the lowest speed: ranked on the interpolated envelope, then decided on the exact limits of
    the best and of up to ``RANK_MORE`` speeds within ``RANK_TOL`` of its rate where stability may
    bind. Codes: 0 stability, ``hi_code``, 4 power, -1 no feasible speed. ``out_env_min`` receives
    the envelope's smallest value, or the smallest exact limit solved if that is below it (so never
    more than ``out_limit``); ``out_env`` (``(G, n_rpm)``, or ``(0, 0)`` to skip) the interpolated
    envelopes.
    """
    n_rpm = rpm.shape[0]
    lo_rpm, hi_rpm = rpm[0], rpm[n_rpm - 1]
    n_max = n_freq + fn.shape[1] * (2 * MODE_LINES + 1)
    freq = np.empty(n_max)
    lam = np.empty((2, n_max), dtype=np.complex128)
    dep = np.empty((2, n_max))
    pha = np.empty((2, n_max))
    gap = np.empty(n_max, dtype=np.complex128)
    seg = np.empty((2, n_max - 1, 7))
    has = np.empty((2, n_max - 1), dtype=np.bool_)
    env = np.empty(n_rpm)
    qenv = np.empty(n_rpm)
    tried_j = np.empty(RANK_MORE + 1, dtype=np.int64)
    tried_d = np.empty(RANK_MORE + 1)
    tried_f = np.empty(RANK_MORE + 1)
    inv_rpm = 1.0 / rpm
    inv_lo, inv_hi = 1.0 / lo_rpm, 1.0 / hi_rpm
    last = np.full(64, -1, dtype=np.int64)  # per lobe k: the grid index its last segment started at
    xs = 60.0 / teeth
    inv_lstep = (n_rpm - 1) / math.log(hi_rpm / lo_rpm)
    keep_env = out_env.shape[0] > 0
    for g in range(fn.shape[0]):
        fn_g, zeta_g, stiff_g, w_g, wres_g = fn[g], zeta[g], stiff[g], w[g], wres[g]
        n = _k_grid(f_lo[g], f_hi[g], n_freq, fn_g, zeta_g, stiff_g, freq)
        _k_sample(n, freq, fn_g, zeta_g, stiff_g, w_g, wres_g, lam, dep, pha, gap)
        _a_segments(n, freq, lam, dep, pha, seg, has)
        # ---- the envelope on the speed grid, as the inverse depth (the largest 2 Re lambda)
        for j in range(n_rpm):
            qenv[j] = 0.0
        for b in range(2):
            last[:] = -1
            for i in range(n - 1):
                if not has[b, i]:
                    continue
                f0, p0, q0, f1, p1 = seg[b, i, 0], seg[b, i, 1], seg[b, i, 2], seg[b, i, 3], seg[b, i, 4]
                q1, curve = seg[b, i, 5], seg[b, i, 6]
                kmin = min(xs * f0 / hi_rpm - p0, xs * f1 / hi_rpm - p1)
                kmax = max(xs * f0 / lo_rpm - p0, xs * f1 / lo_rpm - p1)
                for k in range(max(0, int(math.ceil(kmin - 1e-9))), int(math.floor(kmax + 1e-9)) + 1):
                    y0 = (p0 + k) / (xs * f0)
                    y1 = (p1 + k) / (xs * f1)
                    y_lo, y_hi = min(y0, y1), max(y0, y1)
                    if not (y_hi >= inv_hi and y_lo <= inv_lo and y_hi > 0.0):
                        continue
                    # first grid speed >= 1 / y_hi: walked from where this lobe's previous interval
                    # started (its segments are adjacent), found from the geometric grid at first
                    if k >= last.shape[0]:
                        more = np.full(2 * k + 2, -1, dtype=np.int64)
                        more[:last.shape[0]] = last
                        last = more
                    j0 = last[k]
                    if j0 < 0:
                        j0 = min(n_rpm - 1, max(0, int(-math.log(max(y_hi * lo_rpm, 1e-300)) * inv_lstep)))
                    while j0 > 0 and inv_rpm[j0 - 1] <= y_hi:
                        j0 -= 1
                    while j0 < n_rpm and inv_rpm[j0] > y_hi:
                        j0 += 1
                    last[k] = j0
                    inv_dy = 1.0 / (y1 - y0) if y1 != y0 else 0.0
                    j = j0
                    while j < n_rpm and inv_rpm[j] >= y_lo:
                        t = (inv_rpm[j] - y0) * inv_dy if y1 != y0 else 0.5
                        q = q0 + t * (q1 - q0) + curve * t * (1.0 - t)
                        if q > qenv[j]:
                            qenv[j] = q
                        j += 1
        j_min = 0
        for j in range(n_rpm):
            env[j] = 1.0 / qenv[j] if qenv[j] > 0.0 else np.inf
            if qenv[j] > qenv[j_min]:
                j_min = j
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
        # ---- exact limits: at the best speed and at the speeds that could beat it once solved
        # (interpolated rate within RANK_TOL of the best, where stability may bind), best first
        for m in range(RANK_MORE + 1):
            tried_j[m] = -1
        n_tried = 0
        sel = -1
        sel_rate, sel_res = -1.0, -1.0
        next_j = best_j
        while next_j >= 0:
            jn = next_j
            d, fc = _a_limit(rpm[jn], teeth, n, freq, dep, pha, gap, seg, has, fn_g, zeta_g, stiff_g, w_g, wres_g)
            tried_j[n_tried], tried_d[n_tried], tried_f[n_tried] = jn, d, fc
            cap = min(ap_hi, c_pow / rpm[jn])
            ap = min(cap, margin * d)
            if ap >= ap_lo:
                rate = ap * rpm[jn]
                res = margin * d / ap
                better = rate > sel_rate * (1.0 + 1e-12)
                tie = (not better) and rate >= sel_rate * (1.0 - 1e-12)
                if better or (tie and (res > sel_res * (1.0 + 1e-12)
                                       or (res >= sel_res * (1.0 - 1e-12) and jn < tried_j[sel]))):
                    sel, sel_rate, sel_res = n_tried, rate, res
            n_tried += 1
            next_j = -1
            if n_tried <= RANK_MORE:
                top = -1.0
                for j in range(n_rpm):
                    cap = min(ap_hi, c_pow / rpm[j])
                    stab = margin * env[j]
                    ap = min(cap, stab)
                    if not (ap >= ap_lo and stab < cap * (1.0 + RANK_TOL)):
                        continue  # infeasible, or the cap binds whatever the exact limit
                    rate = ap * rpm[j]
                    if rate < best_rate * (1.0 - RANK_TOL) or rate <= top:
                        continue
                    done = False
                    for m in range(n_tried):
                        done = done or tried_j[m] == j
                    if not done:
                        next_j, top = j, rate
        d_min = env[j_min]
        for m in range(n_tried):
            d_min = min(d_min, tried_d[m])
        out_env_min[g] = d_min
        if best_j < 0:
            out_rpm[g], out_ap[g], out_limit[g], out_freq[g], out_code[g] = np.nan, np.nan, np.nan, np.nan, -1
            continue
        m = sel if sel >= 0 else 0  # none feasible once solved: the interpolated best, code -1
        n_best, d, fc = rpm[tried_j[m]], tried_d[m], tried_f[m]
        cap = min(ap_hi, c_pow / n_best)
        ap = min(cap, margin * d)
        code = 0
        if ap == cap:
            code = hi_code if ap_hi <= c_pow / n_best else 4
        if not ap >= ap_lo:
            code = -1
        out_rpm[g], out_ap[g], out_limit[g], out_freq[g], out_code[g] = n_best, ap, d, fc, code


_COMPILED: list = []
_NAMES = ("_a_segments", "_a_depth", "_a_limit", "_a_scan")
_PY = {name: globals()[name] for name in _NAMES}


def atlas_kernel():
    """:func:`_a_scan` compiled by numba on first use (cached on disk), calling the compiled
    helpers of :mod:`stability.zoa_batch`."""
    if not _COMPILED:
        import numba

        from stability import zoa_batch

        zoa_batch.scan_kernel()  # binds the compiled helpers in zoa_batch's namespace
        g = globals()
        for name in ("_k_lam", "_k_depth_phase", "_k_branch", "_k_solve", "_k_grid", "_k_onset", "_k_sample"):
            g[name] = getattr(zoa_batch, name)
        for name in _NAMES:
            g[name] = numba.njit(cache=True)(_PY[name])
        _COMPILED.append(g["_a_scan"])
    return _COMPILED[0]
