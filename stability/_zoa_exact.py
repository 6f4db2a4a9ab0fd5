"""The exact ZOA limit at given speeds: every lobe that may be the lowest there solved for its
chatter frequency, lobe onsets included (:mod:`stability.zoa` holds the method's notes, the
"Onsets" paragraph in particular; split off by size)."""

from __future__ import annotations

import numpy as np

from ._zoa_curves import TWO_PI, ZOACurves, _Problem

# The linear interpolation between chatter-frequency samples only preselects which lobes may be
# the lowest at a grid speed; every candidate within this factor of the sampled minimum is then
# solved exactly. 1.25 is wider than the interpolation error of a grid that resolves the lobes, but
# not next to a lobe's onset, where the depth falls from infinity to near the lobe's minimum
# within a few lines (measured: 4.1 mm interpolated, 1.47 mm exact, at 0.1 % damping); hence the
# second pass of :func:`_lowest_lobe`.
_PRESELECT_FACTOR = 1.25
# Second pass: a candidate not preselected is solved when its segment's smaller end depth over
# this factor is below the lowest exact depth found at its speed. Along a segment the depth is at
# least that unless 2 Re lambda peaks between the two lines by more than 10 % (at a mode's peak,
# MODE_STEPS = 4 lines per zeta fn leave 1.6 %, docs/atlas.md).
_BOUND_FACTOR = 1.1


def _solve_freq(prob: _Problem, branch, k, rpm, f_lo, f_hi, *, iters=80):
    """Solve ``eps(f)/2pi + k - 60 f/(N n) = 0`` for ``f`` in brackets, vectorised (Illinois)."""
    n_t = prob.teeth

    def resid(f):
        depth, phase = prob.branch(branch, f)
        return phase / TWO_PI + k - 60.0 * f / (n_t * rpm), depth

    a, b = f_lo.astype(float), f_hi.astype(float)
    fa, _ = resid(a)
    fb, _ = resid(b)
    side = np.zeros(a.shape, dtype=int)
    for _ in range(iters):
        denom = fb - fa
        with np.errstate(divide="ignore", invalid="ignore"):
            c = np.where(denom != 0, (a * fb - b * fa) / denom, 0.5 * (a + b))
        c = np.where((c >= np.minimum(a, b)) & (c <= np.maximum(a, b)), c, 0.5 * (a + b))
        fc, _ = resid(c)
        right = fc * fb > 0  # c replaces b
        left = ~right & (fc * fa > 0)  # c replaces a
        done = ~right & ~left  # fc == 0 (or NaN)
        fa = np.where(right & (side == -1), fa / 2, fa)
        fb = np.where(left & (side == 1), fb / 2, fb)
        b, fb = np.where(right | done, c, b), np.where(right | done, fc, fb)
        a, fa = np.where(left | done, c, a), np.where(left | done, fc, fa)
        side = np.where(right, -1, np.where(left, 1, side))
        if np.all(np.abs(b - a) <= 4e-15 * np.abs(b)):
            break
    f = np.where(np.abs(fa) < np.abs(fb), a, b)
    res, depth = resid(f)
    return f, depth, res


def _newton_intersection(prob, b1, k1, f1, b2, k2, f2, *, iters=30):
    """Solve ``rpm_1(f1) = rpm_2(f2)`` and ``depth_1(f1) = depth_2(f2)`` by Newton (vectorised).

    Returns the speed, depth and both chatter frequencies at the intersection, and whether it
    converged.
    """
    n_t = prob.teeth

    def curve(b, k, f):
        depth, phase = prob.branch(b, f)
        return 60.0 * f / (n_t * (phase / TWO_PI + k)), depth

    ok = np.ones(f1.shape, dtype=bool)
    for _ in range(iters):
        r1, d1 = curve(b1, k1, f1)
        r2, d2 = curve(b2, k2, f2)
        h1, h2 = 1e-7 * f1, 1e-7 * f2
        r1p, d1p = curve(b1, k1, f1 + h1)
        r2p, d2p = curve(b2, k2, f2 + h2)
        with np.errstate(divide="ignore", invalid="ignore"):
            j11, j21 = (r1p - r1) / h1, (d1p - d1) / h1
            j12, j22 = -(r2p - r2) / h2, -(d2p - d2) / h2
            e1, e2 = r1 - r2, d1 - d2
            det = j11 * j22 - j12 * j21
            s1 = (j22 * e1 - j12 * e2) / det
            s2 = (-j21 * e1 + j11 * e2) / det
        ok &= np.isfinite(s1) & np.isfinite(s2)
        s1 = np.where(ok, s1, 0.0)
        s2 = np.where(ok, s2, 0.0)
        # limit a step to 1 % of the frequency: the start is already close
        scale = np.maximum(1.0, np.maximum(np.abs(s1) / (0.01 * f1), np.abs(s2) / (0.01 * f2)))
        f1, f2 = f1 - s1 / scale, f2 - s2 / scale
        if np.all((np.abs(s1) <= 1e-13 * f1) & (np.abs(s2) <= 1e-13 * f2)):
            break
    r1, d1 = curve(b1, k1, f1)
    r2, d2 = curve(b2, k2, f2)
    with np.errstate(invalid="ignore"):  # a branch may leave its finite range (inf - inf): not ok
        ok &= (np.abs(r1 - r2) <= 1e-9 * r1) & (np.abs(d1 - d2) <= 1e-9 * np.abs(d1))
    return r1, d1, f1, f2, ok


def _lobe_speed(freq_hz, phase_rad, teeth, k):
    """Spindle speed (rpm) at which lobe ``k`` of a branch has this chatter frequency and phase;
    ``inf`` where the lobe's number of waves per tooth period is zero (lobe 0 at zero phase: no
    finite speed, and no lobe there), without NumPy's divide warning (which ``robomill``'s CLI
    would print to the user)."""
    with np.errstate(divide="ignore"):
        return 60.0 * freq_hz / (teeth * (phase_rad / TWO_PI + k))


# Illinois steps (at most) for a lobe's onset ``Re lambda = 0`` inside a grid interval.
_ONSET_ITERS = 60


class _Onsets:
    """Where a continued branch's real part changes sign inside a grid interval: a lobe starts
    (or ends) there, its critical depth going to infinity. One entry per such (branch, interval).

    ``b``, ``i``: branch and grid interval ``[f_i, f_i+1]``; ``left``: the onset is on the left
    (the finite end is ``i + 1``); ``f_on``: the onset with ``Re lambda`` interpolated linearly
    between the lines (for the lobe's speeds and the interpolated depth); ``p_on``: the phase ``eps
    / 2 pi`` there, 1 if ``Im lambda`` (interpolated) is positive (``eps -> 2 pi``), else 0;
    ``f_fin``, ``p_fin``, ``q_fin``: frequency, phase in turns and inverse depth ``2 Re lambda`` at
    the finite end. The onset interval's lobe segment runs from ``(f_on, p_on, q = 0)`` to the
    finite end. :meth:`exact` gives the onset that brackets the phase solve.
    """

    def __init__(self, prob: _Problem, curves: ZOACurves):
        f = np.asarray(curves.freq_hz)
        depth_c, phase_c = curves.continued()
        rows = np.stack([curves.continued_row, 1 - curves.continued_row]).astype(np.intp)
        lam_c = np.take_along_axis(np.asarray(curves.eigenvalue), rows, axis=0)
        fin = np.isfinite(depth_c)
        self.b, self.i = np.nonzero(fin[:, :-1] != fin[:, 1:])
        b, i = self.b, self.i
        self.left = fin[b, i + 1]
        j_fin = np.where(self.left, i + 1, i)
        l0, l1 = lam_c[b, i], lam_c[b, i + 1]
        t = l0.real / (l0.real - l1.real)  # in [0, 1]: Re lambda changes sign between the lines
        self.f_on = f[i] + t * (f[i + 1] - f[i])
        im = l0.imag + t * (l1.imag - l0.imag)
        self.f_fin, self.p_fin, self.q_fin = f[j_fin], phase_c[b, j_fin] / TWO_PI, 1.0 / depth_c[b, j_fin]
        self.p_on = np.where((im > 0) | ((im == 0) & (self.p_fin > 0.5)), 1.0, 0.0)
        self._prob, self._f0, self._f1, self._re0, self._re1 = prob, f[i], f[i + 1], l0.real, l1.real
        self._exact = np.full(b.size, np.nan)

    def exact(self, idx: np.ndarray) -> np.ndarray:
        """The onsets ``idx`` to 1e-13: the end with ``Re lambda <= 0`` of an Illinois bracket (the
        end of the phase solve's bracket, which then holds no point where the lobe is not
        defined); solved once, when a candidate on the segment is first solved."""
        need = np.unique(idx[np.isnan(self._exact[idx])])
        if need.size:
            self._exact[need] = self._illinois(need)
        return self._exact[idx]

    def _illinois(self, sel):
        b = self.b[sel]
        a, ga, c, gc = self._f0[sel], self._re0[sel], self._f1[sel], self._re1[sel]
        side = np.zeros(sel.size, dtype=int)
        for _ in range(_ONSET_ITERS):
            with np.errstate(divide="ignore", invalid="ignore"):
                m = (a * gc - c * ga) / (gc - ga)
            m = np.where((m > np.minimum(a, c)) & (m < np.maximum(a, c)), m, 0.5 * (a + c))
            gm = self._prob.branch_eigenvalue(b, m).real
            to_c = (gm > 0) == (gc > 0)  # m replaces c
            ga = np.where(to_c & (side == -1), ga / 2, ga)
            gc = np.where(~to_c & (side == 1), gc / 2, gc)
            c, gc = np.where(to_c, m, c), np.where(to_c, gm, gc)
            a, ga = np.where(to_c, a, m), np.where(to_c, ga, gm)
            side = np.where(to_c, -1, 1)
            if np.all(np.abs(c - a) <= 1e-13 * np.abs(c)):
                break
        return np.where(ga > 0, c, a)  # the halving keeps the signs


def _lowest_lobe(prob: _Problem, curves: ZOACurves, rpm: np.ndarray, k_lo: int, k_hi: int, onsets: _Onsets):
    """Exact lowest lobe at each speed of ``rpm`` (sorted).

    Every (continued branch, lobe, frequency interval) whose speed range covers a target speed is a
    candidate: the intervals with a finite depth at both ends, and those where a lobe starts
    (``onsets``: from the onset to the finite end; on a coarse grid a lightly damped mode's whole
    lobe flank, down to a few times the lobe's minimum, can lie in one). An interpolated depth
    (linear in speed; for an onset, ``2 Re lambda`` linear in the tooth period from 0 at the
    onset) preselects those within ``_PRESELECT_FACTOR`` of the smallest, and each is solved for
    the exact chatter frequency at the exact speed (an onset's bracketed from the onset). Next to
    an onset the interpolation can be off by a factor of 3 (the depth falls from infinity within a
    line or two), so a second pass solves every other candidate whose segment's smaller end depth,
    over ``_BOUND_FACTOR``, is below the smallest exact depth at its speed.

    Returns depth, chatter frequency, lobe ``k``, branch and grid interval (index into
    ``curves.freq_hz``) of the minimising lobe at each speed (inf, NaN, -1, -1, -1 where none).
    """
    f = curves.freq_hz
    depth_c, phase_c = curves.continued()
    cand = {"b": [], "k": [], "i": [], "j": [], "d": [], "bound": [], "on": []}

    def add(b, k, ii, jj, d, bound, on):
        for key, v in zip(cand, (np.broadcast_to(b, ii.shape), np.full(ii.size, k), ii, jj, d, bound,
                                 np.broadcast_to(on, ii.shape))):
            cand[key].append(v)

    def covered(x0, x1):
        """Grid speeds between ``x0`` and ``x1`` per segment: (segment, speed index) pairs."""
        with np.errstate(invalid="ignore"):
            j0 = np.searchsorted(rpm, np.minimum(x0, x1), side="left")
            cnt = np.searchsorted(rpm, np.maximum(x0, x1), side="right") - j0
        seg = np.repeat(np.arange(x0.size), cnt)
        jj = np.repeat(j0, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        return seg, jj

    for b in range(2):
        d = depth_c[b]
        valid = np.isfinite(d)
        # continued branches have a continuous phase, so every interval with finite ends is a
        # candidate (a phase step the grid does not resolve fails the residual test of the solve)
        iv = np.flatnonzero(valid[:-1] & valid[1:])
        if iv.size == 0:
            continue
        for k in range(k_lo, k_hi + 1):
            x = _lobe_speed(f, phase_c[b], prob.teeth, k)
            s, jj = covered(x[iv], x[iv + 1])
            if s.size == 0:
                continue
            ii = iv[s]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (rpm[jj] - x[ii]) / (x[ii + 1] - x[ii])
            t = np.where(np.isfinite(t), np.clip(t, 0, 1), 0.5)
            add(b, k, ii, jj, d[ii] + t * (d[ii + 1] - d[ii]), np.minimum(d[ii], d[ii + 1]), -1)
    if onsets.b.size:
        xs = 60.0 / prob.teeth
        for k in range(k_lo, k_hi + 1):
            # in the tooth period y = 1 / rpm the segment runs from y_on (q = 0) to y_fin (q_fin)
            y_on = (onsets.p_on + k) / (xs * onsets.f_on)
            y_fin = (onsets.p_fin + k) / (xs * onsets.f_fin)
            with np.errstate(divide="ignore"):
                s, jj = covered(1.0 / y_on, 1.0 / y_fin)
            if s.size == 0:
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (1.0 / rpm[jj] - y_on[s]) / (y_fin[s] - y_on[s])
                q = np.clip(np.where(np.isfinite(t), t, 0.5), 0, 1) * onsets.q_fin[s]
                dq = np.where(q > 0, 1.0 / q, np.inf)
            add(onsets.b[s], k, onsets.i[s], jj, dq, 1.0 / onsets.q_fin[s], s)
    n = rpm.size
    out_d, out_f = np.full(n, np.inf), np.full(n, np.nan)
    out_k, out_b, out_i = np.full(n, -1), np.full(n, -1), np.full(n, -1)
    if not cand["b"]:
        return out_d, out_f, out_k, out_b, out_i
    cb, ck, ci, cj, cd, cl, con = (np.concatenate(cand[key]) for key in cand)

    def solve(sel):
        """Solve candidates ``sel`` in their grid interval, an onset's from the exact onset."""
        lo, hi = f[ci[sel]], f[ci[sel] + 1]
        o = con[sel]
        at = np.flatnonzero(o >= 0)
        if at.size:
            f_on, left = onsets.exact(o[at]), onsets.left[o[at]]
            lo[at], hi[at] = np.where(left, f_on, lo[at]), np.where(left, hi[at], f_on)
        return (sel,) + _solve_freq(prob, cb[sel], ck[sel], rpm[cj[sel]], lo, hi)

    best = np.full(n, np.inf)
    np.minimum.at(best, cj, cd)
    first_pass = cd <= _PRESELECT_FACTOR * best[cj]
    solved = [solve(np.flatnonzero(first_pass))]
    # second pass: the interpolation can be far off next to a lobe's onset; solve every other
    # candidate whose segment may still hold a depth below the lowest exact one at its speed
    c0, _, depth0, res0 = solved[0]
    good0 = np.isfinite(depth0) & (np.abs(res0) < 1e-8)
    exact = np.full(n, np.inf)
    np.minimum.at(exact, cj[c0[good0]], depth0[good0])
    second = np.flatnonzero(~first_pass & (cl < _BOUND_FACTOR * exact[cj]))
    if second.size:
        solved.append(solve(second))
    idx, fr, depth, res = (np.concatenate(a) for a in zip(*solved))
    good = np.isfinite(depth) & (np.abs(res) < 1e-8)
    idx, fr, depth = idx[good], fr[good], depth[good]
    cb, ck, ci, cj = cb[idx], ck[idx], ci[idx], cj[idx]
    order = np.lexsort((depth, cj))
    first = np.ones(order.size, dtype=bool)
    first[1:] = cj[order][1:] != cj[order][:-1]
    sel = order[first]
    j = cj[sel]
    out_d[j], out_f[j], out_k[j], out_b[j], out_i[j] = depth[sel], fr[sel], ck[sel], cb[sel], ci[sel]
    return out_d, out_f, out_k, out_b, out_i


def _lobe_piece(curves: ZOACurves, b: np.ndarray, k: np.ndarray, i: np.ndarray, onsets: _Onsets) -> np.ndarray:
    """Which monotone piece of its lobe each point (branch ``b``, lobe ``k``, grid interval ``i``) is on.

    A piece is a run of lobe segments (grid intervals with a finite depth at both ends, and an
    onset interval from its onset) joined at finite grid points, over which the lobe's speed
    ``60 f / (N (eps / 2 pi + k))`` keeps increasing (or decreasing) with frequency: over its speed
    range the piece is one smooth curve ``depth(rpm)``. Two speeds whose lowest lobe is on different
    pieces of the same lobe (two modes' lobes with the same ``k`` on one branch, or the two sides of
    a fold) have an intersection of the two pieces between them. Returns an id, comparable only
    between points with the same ``b`` and ``k`` (-1 where ``i < 0``).
    """
    out = np.full(i.shape, -1)
    ok = i >= 0
    if not ok.any():
        return out
    depth_c, phase_c = curves.continued()
    for bb, kk in np.unique(np.stack([b[ok], k[ok]], axis=1), axis=0):
        x = _lobe_speed(curves.freq_hz, phase_c[bb], curves.teeth, kk)
        x0, x1 = x[:-1].copy(), x[1:].copy()
        on = onsets.b == bb
        with np.errstate(divide="ignore"):
            x_on = _lobe_speed(onsets.f_on[on], TWO_PI * onsets.p_on[on], curves.teeth, kk)
        left, io = onsets.left[on], onsets.i[on]
        x0[io[left]], x1[io[~left]] = x_on[left], x_on[~left]
        finite = np.isfinite(depth_c[bb])
        has = finite[:-1] | finite[1:]
        with np.errstate(invalid="ignore"):
            up = x1 > x0
        starts = ~has
        starts[1:] |= ~finite[1:-1] | (up[1:] != up[:-1])
        run = np.cumsum(starts)
        sel = ok & (b == bb) & (k == kk)
        out[sel] = run[i[sel]]
    return out
