"""Compiled zero-order-approximation limits for many structures and spindle speeds at once.

The batch counterpart of :func:`stability.zoa.envelope`, used by ``robomill check`` where a toolpath
asks for the limit at thousands of (structure, speed) pairs: for each *structure group* (one
oriented 2 x 2 receptance, given by its modes' natural frequencies, damping ratios, stiffnesses and
orientation weights) the two eigenvalue branches of ``G_or(f) B0`` are sampled once on the
chatter-frequency grid of :func:`stability.zoa.default_chatter_frequencies` (log lines, plus lines
around a lightly damped mode: :func:`_k_grid`) and continued in frequency (each follows one
eigenvalue through the swaps of their order, as :meth:`stability.zoa.ZOACurves.continued`); every
speed of the group is then solved on that grid exactly as :func:`stability.zoa.envelope` solves one
speed (candidate lobe intervals, those where a lobe starts included from the onset, the same
preselection factor and second pass, a bracketed Illinois solve of the phase condition), so the
limits equal :func:`stability.lobes.predict_point`'s. Where a query asks for it and the speed is
unstable at the allowed depth, the nearest stable speed is found on the same grid (see
:func:`_k_nearest`).

The functions are plain Python compiled by numba on first use (:func:`scan_kernel`; cached on
disk), so that importing this module does not import numba.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from ._zoa_curves import MODE_LINES, MODE_STEPS
from ._zoa_exact import _BOUND_FACTOR as _BOUND, _ONSET_ITERS, _PRESELECT_FACTOR as _PRESELECT

__all__ = ["scan_kernel"]

_TWO_PI = 2.0 * math.pi


def _k_lam(f, fn, zeta, stiff, w, wres):
    """Eigenvalues of ``G_or(f) B0`` (2 x 2), the larger real part first.

    ``G_or B0 = sum_r W_r / (k_r (1 - rho^2 + 2 i zeta_r rho)) + W_res`` with ``W_r = v_r[:2] (B0^T
    v_r)^T`` (``v_r`` the mode direction in the cut frame), which is ``oriented_receptance @ B0``.
    """
    a00, a01, a10, a11 = wres[0, 0], wres[0, 1], wres[1, 0], wres[1, 1]
    b00 = b01 = b10 = b11 = 0.0
    for r in range(fn.shape[0]):
        rho = f / fn[r]
        re = 1.0 - rho * rho
        im = 2.0 * zeta[r] * rho
        den = 1.0 / (stiff[r] * (re * re + im * im))
        re, im = re * den, -im * den  # 1 / (k (1 - rho^2 + 2 i zeta rho))
        a00 += w[r, 0, 0] * re
        b00 += w[r, 0, 0] * im
        a01 += w[r, 0, 1] * re
        b01 += w[r, 0, 1] * im
        a10 += w[r, 1, 0] * re
        b10 += w[r, 1, 0] * im
        a11 += w[r, 1, 1] * re
        b11 += w[r, 1, 1] * im
    m00, m01, m10, m11 = complex(a00, b00), complex(a01, b01), complex(a10, b10), complex(a11, b11)
    half = (m00 + m11) / 2.0
    det = m00 * m11 - m01 * m10
    disc = cmath.sqrt(half * half - det)
    if (half.conjugate() * disc).real < 0.0:
        disc = -disc
    l1 = half + disc
    l2 = det / l1 if l1 != 0 else half - disc
    if l2.real > l1.real:
        return l2, l1
    return l1, l2


def _k_depth_phase(lam):
    depth = 0.5 / lam.real if lam.real > 0.0 else np.inf
    return depth, math.pi + 2.0 * math.atan2(lam.imag, lam.real)


def _k_branch(f, b, f0, f1, g0, g1, fn, zeta, stiff, w, wres):
    """Eigenvalue of continued branch ``b`` at ``f`` in the grid interval ``[f0, f1]`` (as
    ``stability.zoa._Problem.branch``): the root whose ``lambda_0 - lambda_1`` points along the
    gap interpolated between the interval's continued gaps ``g0``, ``g1``."""
    l1, l2 = _k_lam(f, fn, zeta, stiff, w, wres)
    t = (f - f0) / (f1 - f0) if f1 != f0 else 0.0
    ref = g0 + t * (g1 - g0)
    first = (ref.conjugate() * (l1 - l2)).real >= 0.0  # the sorted first root continues branch 0
    return l1 if first == (b == 0) else l2


def _k_solve(b, k, rpm, teeth, f_lo, f_hi, g_lo, g_hi, fn, zeta, stiff, w, wres):
    """Chatter frequency of lobe ``k`` of continued branch ``b`` at ``rpm`` in ``[f_lo, f_hi]``
    (Illinois, as ``stability.zoa._solve_freq``); returns (depth, frequency, residual)."""
    x = 60.0 / (teeth * rpm)
    d, p = _k_depth_phase(_k_branch(f_lo, b, f_lo, f_hi, g_lo, g_hi, fn, zeta, stiff, w, wres))
    a, fa = f_lo, p / _TWO_PI + k - x * f_lo
    d, p = _k_depth_phase(_k_branch(f_hi, b, f_lo, f_hi, g_lo, g_hi, fn, zeta, stiff, w, wres))
    c_hi, fb = f_hi, p / _TWO_PI + k - x * f_hi
    side = 0
    for _ in range(80):
        denom = fb - fa
        c = (a * fb - c_hi * fa) / denom if denom != 0.0 else 0.5 * (a + c_hi)
        if not (c >= min(a, c_hi) and c <= max(a, c_hi)):
            c = 0.5 * (a + c_hi)
        d, p = _k_depth_phase(_k_branch(c, b, f_lo, f_hi, g_lo, g_hi, fn, zeta, stiff, w, wres))
        fc = p / _TWO_PI + k - x * c
        right = fc * fb > 0.0
        left = (not right) and fc * fa > 0.0
        done = (not right) and (not left)
        if right and side == -1:
            fa = fa / 2.0
        if left and side == 1:
            fb = fb / 2.0
        if right or done:
            c_hi, fb = c, fc
        if left or done:
            a, fa = c, fc
        if right:
            side = -1
        elif left:
            side = 1
        if abs(c_hi - a) <= 4e-15 * abs(c_hi):
            break
    f = a if abs(fa) < abs(fb) else c_hi
    d, p = _k_depth_phase(_k_branch(f, b, f_lo, f_hi, g_lo, g_hi, fn, zeta, stiff, w, wres))
    return d, f, p / _TWO_PI + k - x * f


def _k_add(cand, cap, n_cand, b, k, i, d, bound):
    """Write candidate ``n_cand`` (branch, lobe, interval, interpolated depth, the segment's smaller
    end depth) into ``cand`` (grown when full); return it and its capacity."""
    if n_cand == cap:
        more = np.empty((2 * cap, 5))
        more[:cap] = cand
        cand, cap = more, 2 * cap
    cand[n_cand, 0], cand[n_cand, 1], cand[n_cand, 2], cand[n_cand, 3], cand[n_cand, 4] = b, k, i, d, bound
    return cand, cap


def _k_limit(rpm, teeth, freq, dep, pha, gap, valid, ons_at, ons_f, ons_p, ons_x, ons_g, fn, zeta, stiff, w, wres):
    """ZOA limit depth and chatter frequency at one speed from the sampled continued branches (as
    ``stability.zoa._lowest_lobe``). ``valid[b, i]``: interval ``i`` of branch ``b`` holds a lobe
    segment (1: finite depths at both ends; 2: at one end, and the segment starts at the onset
    ``ons_f[b, i]``, phase ``ons_p`` in turns, solved from the exact onset ``ons_x``, gap
    ``ons_g``, see :func:`_k_onset`; 0: none); ``ons_at`` lists the 2s as ``b (n - 1) + i``
    (then -1); ``pha`` is the phase over 2 pi; ``gap`` the continued ``lambda_0 - lambda_1`` at the
    grid frequencies."""
    nf = freq.shape[0]
    xs = 60.0 / teeth
    inv = xs / rpm
    # the candidates: lobe k crosses the speed inside interval i (zoa's test, in speed), with the
    # depth interpolated there; those within the preselection factor of the smallest are solved,
    # then those whose segment may still hold a depth below the smallest solved (zoa's two passes)
    cap = 256
    cand = np.empty((cap, 5))
    n_cand = 0
    best = np.inf
    for b in range(2):
        h1 = freq[0] * inv - pha[b, 0]
        for i in range(nf - 1):
            h0 = h1
            h1 = freq[i + 1] * inv - pha[b, i + 1]
            if valid[b, i] != 1:
                continue
            # lobe k can reach the speed in the interval only if k lies between h0 and h1 (the
            # 1e-9 lets the speed test below decide the cases rounding could tip)
            ka = max(0, int(math.ceil(min(h0, h1) - 1e-9)))
            kb = int(math.floor(max(h0, h1) + 1e-9))
            for k in range(ka, kb + 1):
                x0 = xs * freq[i] / (pha[b, i] + k)
                x1 = xs * freq[i + 1] / (pha[b, i + 1] + k)
                if not (min(x0, x1) <= rpm <= max(x0, x1)):
                    continue
                t = (rpm - x0) / (x1 - x0)
                if not np.isfinite(t):
                    t = 0.5
                t = min(max(t, 0.0), 1.0)
                d = dep[b, i] + t * (dep[b, i + 1] - dep[b, i])
                cand, cap = _k_add(cand, cap, n_cand, b, k, i, d, min(dep[b, i], dep[b, i + 1]))
                n_cand += 1
                best = min(best, d)
    # the onset intervals (a few): 2 Re lambda linear in the tooth period y from 0 at the onset
    y = 1.0 / rpm
    for m in range(ons_at.shape[0]):
        if ons_at[m] < 0:
            break
        b, i = ons_at[m] // (nf - 1), ons_at[m] % (nf - 1)
        left = not dep[b, i] < np.inf
        f_fin, p_fin, d_fin = (freq[i + 1], pha[b, i + 1], dep[b, i + 1]) if left else (freq[i], pha[b, i], dep[b, i])
        f_on, p_on = ons_f[b, i], ons_p[b, i]
        h_on, h_fin = f_on * inv - p_on, f_fin * inv - p_fin
        ka = max(0, int(math.ceil(min(h_on, h_fin) - 1e-9)))
        kb = int(math.floor(max(h_on, h_fin) + 1e-9))
        for k in range(ka, kb + 1):
            y_on = (p_on + k) / (xs * f_on)
            y_fin = (p_fin + k) / (xs * f_fin)
            if not (min(y_on, y_fin) <= y <= max(y_on, y_fin)):
                continue
            t = (y - y_on) / (y_fin - y_on) if y_fin != y_on else 0.5
            t = min(max(t, 0.0), 1.0)
            d = d_fin / t if t > 0.0 else np.inf
            cand, cap = _k_add(cand, cap, n_cand, b, k, i, d, d_fin)
            n_cand += 1
            best = min(best, d)
    out_d, out_f = np.inf, np.nan
    exact = np.inf  # the smallest depth of the first pass
    for second in range(2):
        if second == 1:
            exact = out_d
        for j in range(n_cand):
            first = cand[j, 3] <= _PRESELECT * best
            if second == 0:
                if not first:
                    continue
            elif first or not cand[j, 4] < _BOUND * exact:
                continue
            b, k, i = int(cand[j, 0]), int(cand[j, 1]), int(cand[j, 2])
            f0, f1, g0, g1 = freq[i], freq[i + 1], gap[i], gap[i + 1]
            if valid[b, i] == 2:  # from the exact onset
                if not dep[b, i] < np.inf:
                    f0, g0 = ons_x[b, i], ons_g[b, i]
                else:
                    f1, g1 = ons_x[b, i], ons_g[b, i]
            d, f, res = _k_solve(b, k, rpm, teeth, f0, f1, g0, g1, fn, zeta, stiff, w, wres)
            if d < np.inf and abs(res) < 1e-8 and d < out_d:
                out_d, out_f = d, f
    return out_d, out_f


def _k_crossing(b, target, f_a, f_b, g_a, g_b, fn, zeta, stiff, w, wres):
    """Frequency in the grid interval ``[f_a, f_b]`` (continued gaps ``g_a``, ``g_b``) where
    ``Re lambda_b = target`` (bisection; the real part of a continued branch is continuous)."""
    f0, f1 = f_a, f_b
    ga = _k_branch(f_a, b, f0, f1, g_a, g_b, fn, zeta, stiff, w, wres).real - target
    for _ in range(200):
        mid = 0.5 * (f_a + f_b)
        if mid <= f_a or mid >= f_b:
            break
        gm = _k_branch(mid, b, f0, f1, g_a, g_b, fn, zeta, stiff, w, wres).real - target
        if (gm > 0.0) == (ga > 0.0):
            f_a, ga = mid, gm
        else:
            f_b = mid
    return 0.5 * (f_a + f_b)


def _k_unstable_intervals(thr, lo, hi, teeth, freq, dep, pha, gap, valid, fn, zeta, stiff, w, wres):
    """Speed intervals in which some lobe lies below depth ``thr``: the images, under every lobe's
    speed map ``n_k(f) = 60 f / (N (eps(f) / 2 pi + k))``, of the frequency runs where a continued
    branch's critical depth is below ``thr`` (on the intervals the ZOA solve uses, ``valid``; in an
    onset interval the run starts or ends where ``2 Re lambda = 1 / thr``, as at any other crossing
    of ``thr``). Returns (starts, ends), arrays."""
    nf = freq.shape[0]
    xs = 60.0 / teeth
    starts = np.empty(256)
    ends = np.empty(256)
    n_int = 0
    run_f = np.empty(nf + 2)
    run_p = np.empty(nf + 2)
    target = 0.5 / thr
    for b in range(2):
        n_run = 0
        for i in range(nf):  # interval i = [freq[i], freq[i+1]]; i == nf - 1 flushes the last run
            piece = 0  # 0 none, 1 whole, 2 left part (below at i), 3 right part (below at i+1)
            if i < nf - 1:
                d0, d1 = dep[b, i], dep[b, i + 1]
                if valid[b, i]:
                    if d0 < thr and d1 < thr:
                        piece = 1
                    elif d0 < thr:
                        piece = 2
                    elif d1 < thr:
                        piece = 3
            if piece == 1 or piece == 2:
                if n_run == 0:
                    run_f[0], run_p[0] = freq[i], pha[b, i]
                    n_run = 1
            if piece == 1:
                run_f[n_run], run_p[n_run] = freq[i + 1], pha[b, i + 1]
                n_run += 1
                continue
            if piece == 2:
                fc = _k_crossing(b, target, freq[i], freq[i + 1], gap[i], gap[i + 1], fn, zeta, stiff, w, wres)
                run_f[n_run] = fc
                lam = _k_branch(fc, b, freq[i], freq[i + 1], gap[i], gap[i + 1], fn, zeta, stiff, w, wres)
                run_p[n_run] = _k_depth_phase(lam)[1] / _TWO_PI
                n_run += 1
            if n_run > 0:  # the run ends here: emit its image under every lobe
                kmin, kmax = np.inf, -np.inf
                for j in range(n_run):
                    kmin = min(kmin, xs * run_f[j] / hi - run_p[j])
                    kmax = max(kmax, xs * run_f[j] / lo - run_p[j])
                for k in range(max(0, int(math.floor(kmin))), int(math.floor(kmax)) + 1):
                    r_min, r_max = np.inf, -np.inf
                    for j in range(n_run):
                        r = xs * run_f[j] / (run_p[j] + k)
                        r_min = min(r_min, r)
                        r_max = max(r_max, r)
                    if r_max >= lo and r_min <= hi:
                        if n_int == starts.shape[0]:  # grow
                            more_s, more_e = np.empty(2 * n_int), np.empty(2 * n_int)
                            more_s[:n_int], more_e[:n_int] = starts, ends
                            starts, ends = more_s, more_e
                        starts[n_int], ends[n_int] = r_min, r_max
                        n_int += 1
                n_run = 0
            if piece == 3:
                fc = _k_crossing(b, target, freq[i], freq[i + 1], gap[i], gap[i + 1], fn, zeta, stiff, w, wres)
                run_f[0] = fc
                lam = _k_branch(fc, b, freq[i], freq[i + 1], gap[i], gap[i + 1], fn, zeta, stiff, w, wres)
                run_p[0] = _k_depth_phase(lam)[1] / _TWO_PI
                run_f[1], run_p[1] = freq[i + 1], pha[b, i + 1]
                n_run = 2
    return starts[:n_int], ends[:n_int]


def _k_nearest(rpm0, thr, lo, hi, teeth, freq, dep, pha, gap, valid, ons_at, ons_f, ons_p, ons_x, ons_g, fn, zeta,
               stiff, w, wres):
    """Speed nearest to ``rpm0`` in ``[lo, hi]`` whose ZOA limit is at least ``thr`` (NaN: none).

    The candidates are the ends of the connected unstable speed set around ``rpm0``; each is moved
    outwards by 1e-9 .. 1e-4 of itself until the exact limit there passes (the sampled images can
    miss a lobe's turning point between two grid frequencies by ~1e-7); a side that never passes is
    widened and searched again, and a verified side is returned only when the other side cannot be
    nearer.
    """
    p = min(max(rpm0, lo), hi)
    lim = (teeth, freq, dep, pha, gap, valid, ons_at, ons_f, ons_p, ons_x, ons_g, fn, zeta, stiff, w, wres)
    if p != rpm0 and _k_limit(p, *lim)[0] >= thr:
        return p
    starts, ends = _k_unstable_intervals(thr, lo, hi, teeth, freq, dep, pha, gap, valid, fn, zeta, stiff, w, wres)
    left, right = p, p
    for _ in range(200):
        changed = True
        while changed:
            changed = False
            for j in range(starts.shape[0]):
                if starts[j] <= right and ends[j] >= left:
                    if starts[j] < left:
                        left, changed = starts[j], True
                    if ends[j] > right:
                        right, changed = ends[j], True
        # verify each side; an unverified side is known to reach at least `reach`
        found_r, found_l = np.nan, np.nan
        reach_r, reach_l = right, left
        if right < hi:
            step = 1e-9
            while step <= 1.01e-4:
                c = min(right * (1.0 + step), hi)
                if _k_limit(c, *lim)[0] >= thr:
                    found_r = c
                    break
                reach_r = c
                step *= 10.0
        if left > lo:
            step = 1e-9
            while step <= 1.01e-4:
                c = max(left * (1.0 - step), lo)
                if _k_limit(c, *lim)[0] >= thr:
                    found_l = c
                    break
                reach_l = c
                step *= 10.0
        dist_r = found_r - rpm0 if found_r == found_r else (np.inf if right >= hi else reach_r - rpm0)
        dist_l = rpm0 - found_l if found_l == found_l else (np.inf if left <= lo else rpm0 - reach_l)
        if found_r == found_r and dist_r <= dist_l:
            return found_r
        if found_l == found_l and dist_l <= dist_r:
            return found_l
        if dist_r == np.inf and dist_l == np.inf:
            return np.nan
        # widen the unverified side(s) that could still be nearer, and search again
        if found_r != found_r and right < hi:
            right = reach_r
        if found_l != found_l and left > lo:
            left = reach_l
    return np.nan


def _k_grid(f_lo, f_hi, n_log, fn, zeta, stiff, freq):
    """Write the chatter-frequency grid of :func:`stability.zoa.default_chatter_frequencies` into
    ``freq`` (increasing, distinct) and return its length: ``n_log`` log-spaced lines ``f_lo ..
    f_hi`` and the lines around the lightly damped modes (``stability.zoa._mode_lines``, the same
    rule and order of operations)."""
    a = math.log(f_lo)
    step = (math.log(f_hi) - a) / (n_log - 1)
    for i in range(n_log):
        freq[i] = math.exp(i * step + a)
    freq[0], freq[n_log - 1] = f_lo, f_hi
    n = n_log
    h = 1.0 / MODE_STEPS
    for r in range(fn.shape[0]):
        ratio = step / (zeta[r] * h) if zeta[r] > 0.0 else np.inf
        if not stiff[r] < np.inf or ratio <= 1.0:
            continue
        m = MODE_LINES if not ratio < np.inf else min(MODE_LINES, int(math.acosh(ratio) / h))
        for j in range(-m, m + 1):
            f = fn[r] * (1.0 + zeta[r] * math.sinh(j * h))
            if f_lo < f < f_hi:
                freq[n] = f
                n += 1
    if n > n_log:
        freq[:n] = np.sort(freq[:n])
        m = 1
        prev = freq[0]
        for i in range(1, n):
            fi = freq[i]
            if fi > prev * (1.0 + 1e-12):  # as zoa._merge_lines: against the line before
                freq[m] = fi
                m += 1
            prev = fi
        n = m
    return n


def _k_onset(b, f0, f1, g0, g1, p_fin, fn, zeta, stiff, w, wres):
    """The onset ``Re lambda_b = 0`` in the grid interval ``[f0, f1]`` (continued gaps ``g0``,
    ``g1``; ``p_fin`` the phase in turns at its finite end) where the sign of ``Re lambda_b``
    changes, as ``stability.zoa._Onsets``: the onset with ``Re lambda`` interpolated linearly
    between the lines and the phase in turns there (1 if ``Im lambda``, interpolated, is positive,
    else 0), for the lobe's speeds and the interpolated depth; and the exact onset, the end with
    ``Re lambda_b <= 0`` of an Illinois bracket narrowed to 1e-13, with the gap interpolated there,
    for the phase solve's bracket (also the atlas's, planner.atlas._kernel, which uses the exact
    onset only)."""
    l0 = _k_branch(f0, b, f0, f1, g0, g1, fn, zeta, stiff, w, wres)
    l1 = _k_branch(f1, b, f0, f1, g0, g1, fn, zeta, stiff, w, wres)
    t = l0.real / (l0.real - l1.real)
    f_lin = f0 + t * (f1 - f0)
    im = l0.imag + t * (l1.imag - l0.imag)
    p_on = 1.0 if (im > 0.0 or (im == 0.0 and p_fin > 0.5)) else 0.0
    a, ga, c, gc = f0, l0.real, f1, l1.real
    side = 0
    for _ in range(_ONSET_ITERS):
        m = (a * gc - c * ga) / (gc - ga) if gc != ga else 0.5 * (a + c)
        if not (min(a, c) < m < max(a, c)):
            m = 0.5 * (a + c)
        gm = _k_branch(m, b, f0, f1, g0, g1, fn, zeta, stiff, w, wres).real
        if (gm > 0.0) == (gc > 0.0):
            if side == -1:
                ga = ga / 2.0
            c, gc, side = m, gm, -1
        else:
            if side == 1:
                gc = gc / 2.0
            a, ga, side = m, gm, 1
        if abs(c - a) <= 1e-13 * abs(c):
            break
    f_on = c if ga > 0.0 else a
    t = (f_on - f0) / (f1 - f0)
    return f_lin, p_on, f_on, g0 + t * (g1 - g0)


def _k_sample(n, freq, fn, zeta, stiff, w, wres, lam, dep, pha, gap):
    """The two continued eigenvalue branches at ``freq[:n]``: ``lam`` (2, n), limit depth ``dep``
    and phase ``pha`` (in turns) per branch (``inf``/NaN where the real part is not positive), and
    the continued gap ``gap`` = ``lambda_0 - lambda_1`` (also the atlas's, planner.atlas._kernel)."""
    swapped = False
    prev = 0j
    for i in range(n):
        l1, l2 = _k_lam(freq[i], fn, zeta, stiff, w, wres)
        # continue the branches: the sorted gap l1 - l2 turning by more than 90 degrees from
        # the previous frequency's means the sorted order has swapped (stability.zoa's rule)
        d12 = l1 - l2
        if i > 0 and (prev.conjugate() * d12).real < 0.0:
            swapped = not swapped
        prev = d12
        if swapped:
            l1, l2 = l2, l1
        gap[i] = l1 - l2
        lam[0, i], lam[1, i] = l1, l2
        # the phase is used only where the depth is finite (atan2 is a fifth of the cost)
        dep[0, i], pha[0, i] = np.inf, np.nan
        dep[1, i], pha[1, i] = np.inf, np.nan
        if l1.real > 0.0:
            d, p = _k_depth_phase(l1)
            dep[0, i], pha[0, i] = d, p / _TWO_PI
        if l2.real > 0.0:
            d, p = _k_depth_phase(l2)
            dep[1, i], pha[1, i] = d, p / _TWO_PI


def _k_branches(n, freq, fn, zeta, stiff, w, wres, lam, dep, pha, gap, valid, ons_at, ons_f, ons_p, ons_x, ons_g):
    """Sample the two eigenvalue branches of one structure group at ``freq[:n]`` (:func:`_k_grid`),
    continued in frequency (:func:`_k_sample`: ``lam``, ``dep``, ``pha``, ``gap``), and mark
    ``valid`` (int8: 1 the interval holds a lobe segment between finite depths, 2 one from the onset
    of a lobe inside it, one end's depth infinite, 0 none) and, for 2, the onset (:func:`_k_onset`):
    interpolated ``ons_f`` with its phase ``ons_p``, exact ``ons_x`` with the gap ``ons_g`` there;
    ``ons_at`` lists the onset intervals as ``b (n - 1) + i``, then -1."""
    _k_sample(n, freq, fn, zeta, stiff, w, wres, lam, dep, pha, gap)
    n_on = 0
    for b in range(2):
        for i in range(n - 1):
            fin0, fin1 = dep[b, i] < np.inf, dep[b, i + 1] < np.inf
            valid[b, i] = 1 if fin0 and fin1 else (2 if fin0 or fin1 else 0)
            if fin0 != fin1:
                p_fin = pha[b, i + 1] if fin1 else pha[b, i]
                ons_f[b, i], ons_p[b, i], ons_x[b, i], ons_g[b, i] = _k_onset(b, freq[i], freq[i + 1], gap[i],
                                                                             gap[i + 1], p_fin, fn, zeta, stiff, w,
                                                                             wres)
                ons_at[n_on] = b * (n - 1) + i
                n_on += 1
    ons_at[n_on:] = -1


def _k_scan(fn, zeta, stiff, w, wres, f_lo, f_hi, teeth, n_freq, q_ptr, q_rpm, q_thr, q_lo, q_hi, q_near,
            out_depth, out_freq, out_near):
    """For every structure group: sample both branches on the chatter-frequency grid of
    ``stability.zoa.default_chatter_frequencies`` (:func:`_k_grid`), continued in frequency as in
    ``stability.zoa.ZOACurves.continued``, then answer its queries (limit at a speed and, where
    flagged and unstable, the nearest stable speed)."""
    n_max = n_freq + fn.shape[1] * (2 * MODE_LINES + 1)
    grid = np.empty(n_max)
    for g in range(fn.shape[0]):
        fn_g, zeta_g, stiff_g, w_g, wres_g = fn[g], zeta[g], stiff[g], w[g], wres[g]
        n = _k_grid(f_lo[g], f_hi[g], n_freq, fn_g, zeta_g, stiff_g, grid)
        freq = grid[:n].copy()
        lam = np.empty((2, n), dtype=np.complex128)
        dep = np.empty((2, n))
        pha = np.empty((2, n))
        gap = np.empty(n, dtype=np.complex128)
        valid = np.empty((2, n - 1), dtype=np.int8)
        ons_at = np.empty(2 * (n - 1), dtype=np.int64)
        ons_f = np.empty((2, n - 1))
        ons_p = np.empty((2, n - 1))
        ons_x = np.empty((2, n - 1))
        ons_g = np.empty((2, n - 1), dtype=np.complex128)
        ons = (ons_at, ons_f, ons_p, ons_x, ons_g)
        _k_branches(n, freq, fn_g, zeta_g, stiff_g, w_g, wres_g, lam, dep, pha, gap, valid, *ons)
        for q in range(q_ptr[g], q_ptr[g + 1]):
            d, fc = _k_limit(q_rpm[q], teeth, freq, dep, pha, gap, valid, *ons, fn_g, zeta_g, stiff_g, w_g, wres_g)
            out_depth[q], out_freq[q] = d, fc
            out_near[q] = np.nan
            if q_near[q] and d < q_thr[q]:
                out_near[q] = _k_nearest(q_rpm[q], q_thr[q], q_lo[q], q_hi[q], teeth, freq, dep, pha, gap, valid,
                                         *ons, fn_g, zeta_g, stiff_g, w_g, wres_g)


_KERNEL_NAMES = ("_k_lam", "_k_depth_phase", "_k_branch", "_k_solve", "_k_grid", "_k_onset", "_k_sample",
                 "_k_branches", "_k_add", "_k_limit", "_k_crossing", "_k_unstable_intervals", "_k_nearest", "_k_scan")
_PY_KERNELS = {name: globals()[name] for name in _KERNEL_NAMES}
_COMPILED: list = []


def scan_kernel():
    """:func:`_k_scan` compiled by numba on first use (cached on disk), so that importing this
    module does not import numba. Each helper is compiled and bound to its module name, so that the
    compiled callers resolve the compiled helpers."""
    if not _COMPILED:
        import numba

        g = globals()
        for name in _KERNEL_NAMES:
            g[name] = numba.njit(cache=True)(_PY_KERNELS[name])
        _COMPILED.append(g["_k_scan"])
    return _COMPILED[0]
