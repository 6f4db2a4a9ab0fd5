"""Zero-order approximation (ZOA) of the stability lobes (Altintas & Budak, CIRP Annals 44(1), 1995).

The time-varying directional matrix is replaced by its mean ``B0`` (:mod:`stability.oriented`),
which makes the regenerative loop time-invariant. A chatter frequency ``w`` is critical at depth
``a`` when ``det(I - a (1 - exp(-i w T)) G(w) B0) = 0`` with ``G`` the oriented receptance (rows
``f, n``, columns ``f, n, a``). With ``lambda`` an eigenvalue of ``G(w) B0`` (2 x 2) this gives, in
closed form (derivation in :func:`limit_curves`)::

    a = 1 / (2 Re(lambda))                 (only where Re(lambda) > 0)
    w T = eps + 2 pi k,  eps = pi + 2 atan2(Im(lambda), Re(lambda))  in (0, 2 pi),  k = 0, 1, ...
    spindle speed n = 60 / (N T)  rpm

which is Altintas's ``a_lim = -2 pi Lambda_R (1 + kappa^2) / (N Kt)`` written with ``lambda``
instead of ``Lambda = -1/lambda`` (N Kt/4 pi absorbed in ``B0``). Everything is vectorised over the
chatter frequencies; the envelope is evaluated on an rpm grid by solving, for every lobe that
reaches a grid speed, for the chatter frequency at that exact speed (not by interpolating sampled
lobes), and the points where the minimising lobe changes (the cusps between lobes) are found by a
Newton solve for the intersection of the two lobe curves and added to the envelope.

Branches. At each frequency the two eigenvalues are reported sorted (branch 0 has the larger real
part, so ``depth_m[0]`` is the smaller critical depth there). A lobe, however, is the curve traced by
*one* eigenvalue as the frequency changes, and where the real parts of the two cross the sorted
order swaps: the sorted branch's depth has a kink and its phase jumps, while each eigenvalue goes on
smoothly. The lobes are therefore traced on the *continued* branches (:meth:`ZOACurves.continued`):
the two roots ``lambda = tr/2 +- sqrt(tr^2/4 - det)`` are told apart by the direction of
``lambda_0 - lambda_1 = +-2 sqrt(...)``, which is kept continuous along the frequency grid (the
sign that turns it by less than 90 degrees between neighbouring frequencies) and, between grid
frequencies, interpolated linearly to pick the root at any frequency the solvers ask for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oma.cutting import CuttingCoefficients, Cut, Tool

from .oriented import _readonly as _ro, average_directional_matrix, oriented_receptance

__all__ = [
    "ZOACurves",
    "ZOAEnvelope",
    "limit_curves",
    "default_chatter_frequencies",
    "envelope",
    "lobe_segments",
]

TWO_PI = 2.0 * np.pi



def default_chatter_frequencies(structure, *, n_freq: int = 10_000) -> np.ndarray:
    """Chatter-frequency grid, Hz: the table's own frequencies for a measured FRF, otherwise
    ``n_freq`` log-spaced points from a third of the lowest to three times the highest natural
    frequency (constant relative resolution, so a 10 Hz robot mode and a 1.4 kHz spindle mode are
    resolved alike)."""
    if hasattr(structure, "natural_frequency_hz"):
        fn = np.asarray(structure.natural_frequency_hz, dtype=float)
        return np.geomspace(fn.min() / 3.0, fn.max() * 3.0, int(n_freq))
    if hasattr(structure, "freq_hz"):
        f = np.asarray(structure.freq_hz, dtype=float)
        return f[f > 0]
    raise TypeError("structure must be a ModalModel or an FRFTable (with .receptance(freq_hz))")


@dataclass(frozen=True)
class ZOACurves:
    """The ZOA critical depth and phase per chatter frequency, two eigenvalue branches.

    Attributes
    ----------
    freq_hz : ndarray, shape (n_freq,)
        Chatter frequencies, Hz.
    depth_m : ndarray, shape (2, n_freq)
        Critical axial depth ``1 / (2 Re lambda)``, m; ``inf`` where ``Re lambda <= 0``.
    phase_rad : ndarray, shape (2, n_freq)
        ``eps`` in (0, 2 pi): the phase between inner and outer modulation is ``eps + 2 pi k``.
    teeth : int
    eigenvalue : ndarray of complex, shape (2, n_freq)
        The eigenvalues ``lambda`` of ``G(w) B0``, 1/m, in the order of ``depth_m``.
    continued_row : ndarray of int, shape (n_freq,)
        Row of ``depth_m``/``phase_rad``/``eigenvalue`` that holds, at each frequency, the
        eigenvalue continued smoothly in frequency from branch 0 at the lowest frequency (the other
        row continues branch 1); see :meth:`continued`.

    Notes
    -----
    Rows 0 and 1 are sorted at every frequency (row 0 has the larger ``Re lambda``, so the smaller
    critical depth): ``depth_m.min(axis=0) == depth_m[0]``. A lobe follows one eigenvalue, which
    moves from one sorted row to the other wherever the two real parts cross; the lobes are the
    curves of :meth:`continued` (the frequency grid is taken in increasing order).
    """

    freq_hz: np.ndarray
    depth_m: np.ndarray
    phase_rad: np.ndarray
    teeth: int
    eigenvalue: np.ndarray
    continued_row: np.ndarray

    def rpm(self, k: int) -> np.ndarray:
        """Spindle speed of lobe ``k`` at every chatter frequency, shape (2, n_freq), rpm (rows as
        ``phase_rad``: sorted, not continued)."""
        return 60.0 * self.freq_hz / (self.teeth * (self.phase_rad / TWO_PI + k))

    def continued(self) -> tuple[np.ndarray, np.ndarray]:
        """Depth, m, and phase, rad, of the two continued branches, each shape (2, n_freq).

        Branch ``c`` is one eigenvalue followed continuously in frequency, so its depth and phase
        are continuous wherever its real part stays positive; lobe ``k`` of branch ``c`` is the
        curve ``(60 f / (N (phase[c] / 2 pi + k)), depth[c])``.
        """
        rows = np.stack([self.continued_row, 1 - self.continued_row]).astype(np.intp)
        return (np.take_along_axis(np.asarray(self.depth_m), rows, axis=0),
                np.take_along_axis(np.asarray(self.phase_rad), rows, axis=0))


def _continued_row(freq_hz: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Row of ``lam`` (shape (2, n), sorted per frequency) holding the continuation of branch 0.

    ``lambda_0 - lambda_1`` is ``+-2 sqrt(tr^2/4 - det)``, analytic in frequency away from a double
    eigenvalue; its sign is chosen so that it turns by less than 90 degrees between neighbouring
    (increasing) frequencies, which is continuity as long as the grid resolves the eigenvalues.
    """
    order = np.argsort(freq_hz, kind="stable")
    gap = lam[0, order] - lam[1, order]
    flip = (np.conj(gap[:-1]) * gap[1:]).real < 0
    row = np.empty(freq_hz.size, dtype=np.int8)
    row[order] = np.concatenate([[0], np.cumsum(flip) % 2])
    return row


class _Problem:
    """Evaluates the two eigenvalue branches at any chatter frequency (the receptance is re-evaluated,
    so refinement is exact for a modal model and follows the table's interpolation for an FRF)."""

    def __init__(self, structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients):
        self.structure, self.cut = structure, cut
        self.teeth = int(tool.teeth)
        self.b0 = average_directional_matrix(tool, cut, coefficients)
        self._grid_f = self._grid_gap = None

    def follow(self, curves: "ZOACurves") -> None:
        """Take the continued branches of ``curves``: at any frequency, branch ``c`` is then the
        root whose ``lambda_0 - lambda_1`` points along the gap interpolated from the grid."""
        order = np.argsort(curves.freq_hz, kind="stable")
        lam = np.asarray(curves.eigenvalue)[:, order]
        sign = 1 - 2 * np.asarray(curves.continued_row, dtype=float)[order]
        self._grid_f = np.asarray(curves.freq_hz, dtype=float)[order]
        self._grid_gap = (lam[0] - lam[1]) * sign

    def eigenvalues(self, freq_hz) -> np.ndarray:
        """Eigenvalues of ``G(w) B0``, shape (2, n), branch 0 with the larger real part."""
        g = oriented_receptance(self.structure, self.cut, freq_hz)  # (2, 3, n)
        m = np.einsum("ijk,jl->kil", g, self.b0)  # (n, 2, 2)
        tr = m[:, 0, 0] + m[:, 1, 1]
        det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
        half = tr / 2.0
        disc = np.sqrt(half * half - det)
        # take the root without cancellation first, the other from the product (det = l1 l2)
        disc = np.where((np.conj(half) * disc).real < 0, -disc, disc)
        l1 = half + disc
        with np.errstate(invalid="ignore", divide="ignore"):
            l2 = np.where(l1 != 0, det / l1, half - disc)
        swap = l2.real > l1.real
        return np.stack([np.where(swap, l2, l1), np.where(swap, l1, l2)])

    @staticmethod
    def depth_phase(lam):
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(lam.real > 0, 0.5 / lam.real, np.inf)
        phase = np.pi + 2.0 * np.arctan2(lam.imag, lam.real)
        return depth, phase

    def branch(self, c, freq_hz):
        """Depth and phase of continued branch ``c`` (array, one per frequency) at ``freq_hz``
        (call :meth:`follow` first)."""
        f = np.asarray(freq_hz, dtype=float)
        lam = self.eigenvalues(f)
        gap = self._grid_gap
        ref = np.interp(f, self._grid_f, gap.real) + 1j * np.interp(f, self._grid_f, gap.imag)
        sorted_first = (np.conj(ref) * (lam[0] - lam[1])).real >= 0  # row 0 continues branch 0
        lam = np.where(sorted_first == (np.asarray(c) == 0), lam[0], lam[1])
        return self.depth_phase(lam)


def limit_curves(structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients,
                 freq_hz) -> ZOACurves:
    """ZOA critical depth and phase at each chatter frequency (both eigenvalue branches).

    Derivation: the condition ``1 = a (1 - e^{-i eps}) lambda`` with ``1 - e^{-i eps} =
    2 i sin(eps/2) e^{-i eps/2}`` and ``lambda = |lambda| e^{i theta}`` is real and positive iff
    ``eps = pi + 2 theta (mod 2 pi)``, and then ``a = 1 / (2 |lambda| cos theta) = 1 / (2 Re lambda)``.

    Parameters
    ----------
    structure : ModalModel or FRFTable
        Machine-frame receptance ``receptance(freq_hz) -> (3, 3, n)``, m/N.
    tool, cut, coefficients
        The cut (engagement, teeth, frame) and the force model (``Ktc``, ``Krc``, ``Kac``).
    freq_hz : array_like, shape (n_freq,)
        Chatter frequencies, Hz, fine enough to resolve the eigenvalues (the branches are
        continued from one frequency to the next in increasing order).

    Returns
    -------
    ZOACurves
    """
    f = np.asarray(freq_hz, dtype=float).ravel()
    prob = _Problem(structure, tool, cut, coefficients)
    lam = prob.eigenvalues(f)
    depth, phase = prob.depth_phase(lam)
    return ZOACurves(_ro(f), _ro(depth), _ro(phase), prob.teeth, _ro(lam), _ro(_continued_row(f, lam)))


@dataclass(frozen=True)
class ZOAEnvelope:
    """Lower envelope of all ZOA lobes on an rpm grid, the lobes' intersections included.

    Attributes
    ----------
    rpm : ndarray, shape (n,)
        The requested grid speeds and the cusp speeds between them, increasing, rpm.
    depth_limit_m : ndarray, shape (n,)
        Critical depth, m (``inf`` where no lobe reaches the speed).
    chatter_frequency_hz : ndarray, shape (n,)
        Chatter frequency of the minimising lobe, Hz (NaN where none).
    lobe : ndarray of int, shape (n,)
        Lobe number ``k`` of the minimising lobe (-1 where none).
    is_intersection : ndarray of bool, shape (n,)
        True at the cusps added between grid points.
    """

    rpm: np.ndarray
    depth_limit_m: np.ndarray
    chatter_frequency_hz: np.ndarray
    lobe: np.ndarray
    is_intersection: np.ndarray


def _lobe_range(curves: ZOACurves, rpm_lo: float, rpm_hi: float) -> tuple[int, int]:
    ok = np.isfinite(curves.depth_m)
    if not ok.any():
        return 0, -1
    # lobe k reaches speed n at chatter frequency f iff k = 60 f / (N n) - eps / 2 pi
    x = 60.0 * curves.freq_hz / curves.teeth
    kk_hi = x / rpm_lo - curves.phase_rad / TWO_PI
    kk_lo = x / rpm_hi - curves.phase_rad / TWO_PI
    return max(0, int(np.floor(np.min(kk_lo[ok])))), int(np.floor(np.max(kk_hi[ok])))


def lobe_segments(curves: ZOACurves, rpm_lo: float, rpm_hi: float, *, max_depth_m: float = np.inf):
    """Every lobe inside a speed window, as sampled on the chatter-frequency grid, for plotting.

    The lobes are those of the continued branches (:meth:`ZOACurves.continued`), so a lobe runs on
    through a frequency where the two eigenvalues' real parts cross.

    Returns
    -------
    rpm, depth_m : ndarray, shape (n_pts,)
        The lobes one after another, separated by NaN; points deeper than ``max_depth_m`` or
        outside ``[rpm_lo, rpm_hi]`` are left out (the curve is split there).
    """
    k_lo, k_hi = _lobe_range(curves, rpm_lo, rpm_hi)
    order = np.argsort(curves.freq_hz, kind="stable")
    f = np.asarray(curves.freq_hz)[order]
    depth, phase = (a[:, order] for a in curves.continued())
    seg_r, seg_d = [], []
    for c in range(2):
        d = depth[c]
        # a phase step this large between grid frequencies is not resolved: do not draw across it
        jump = np.abs(np.diff(phase[c])) >= np.pi / 2
        for k in range(k_lo, k_hi + 1):
            r = 60.0 * f / (curves.teeth * (phase[c] / TWO_PI + k))
            keep = np.isfinite(d) & (d <= max_depth_m) & (r >= rpm_lo) & (r <= rpm_hi)
            idx = np.flatnonzero(keep)
            if idx.size < 2:
                continue
            breaks = np.flatnonzero((np.diff(idx) > 1) | jump[idx[:-1]]) + 1
            for part in np.split(idx, breaks):
                if part.size > 1:
                    seg_r += [r[part], [np.nan]]
                    seg_d += [d[part], [np.nan]]
    if not seg_r:
        return _ro(np.zeros(0)), _ro(np.zeros(0))
    return _ro(np.concatenate(seg_r)), _ro(np.concatenate(seg_d))


# The linear interpolation between chatter-frequency samples only preselects which lobes may be
# the lowest at a grid speed; every candidate within this factor of the sampled minimum is then
# solved exactly. 1.25 is far wider than the interpolation error of any usable frequency grid.
_PRESELECT_FACTOR = 1.25


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
    return 60.0 * freq_hz / (teeth * (phase_rad / TWO_PI + k))


def _lowest_lobe(prob: _Problem, curves: ZOACurves, rpm: np.ndarray, k_lo: int, k_hi: int):
    """Exact lowest lobe at each speed of ``rpm`` (sorted).

    Every (continued branch, lobe, frequency interval) whose speed range covers a target speed is a
    candidate; the linear interpolation preselects those within ``_PRESELECT_FACTOR`` of the
    sampled minimum, and each is solved for the exact chatter frequency at the exact speed.

    Returns depth, chatter frequency, lobe ``k``, branch and grid interval (index into
    ``curves.freq_hz``) of the minimising lobe at each speed (inf, NaN, -1, -1, -1 where none).
    """
    f = curves.freq_hz
    depth_c, phase_c = curves.continued()
    cand = {"b": [], "k": [], "i": [], "j": [], "d": []}
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
            x0, x1 = x[iv], x[iv + 1]
            j0 = np.searchsorted(rpm, np.minimum(x0, x1), side="left")
            cnt = np.searchsorted(rpm, np.maximum(x0, x1), side="right") - j0
            if not cnt.any():
                continue
            ii = np.repeat(iv, cnt)
            jj = np.repeat(j0, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (rpm[jj] - x[ii]) / (x[ii + 1] - x[ii])
            t = np.where(np.isfinite(t), np.clip(t, 0, 1), 0.5)
            cand["b"].append(np.full(ii.size, b))
            cand["k"].append(np.full(ii.size, k))
            cand["i"].append(ii)
            cand["j"].append(jj)
            cand["d"].append(d[ii] + t * (d[ii + 1] - d[ii]))
    n = rpm.size
    out_d, out_f = np.full(n, np.inf), np.full(n, np.nan)
    out_k, out_b, out_i = np.full(n, -1), np.full(n, -1), np.full(n, -1)
    if not cand["b"]:
        return out_d, out_f, out_k, out_b, out_i
    cb, ck, ci, cj, cd = (np.concatenate(cand[key]) for key in ("b", "k", "i", "j", "d"))
    best = np.full(n, np.inf)
    np.minimum.at(best, cj, cd)
    keep = cd <= _PRESELECT_FACTOR * best[cj]
    cb, ck, ci, cj = cb[keep], ck[keep], ci[keep], cj[keep]
    fr, depth, res = _solve_freq(prob, cb, ck, rpm[cj], f[ci], f[ci + 1])
    good = np.isfinite(depth) & (np.abs(res) < 1e-8)
    cb, ck, ci, cj, fr, depth = cb[good], ck[good], ci[good], cj[good], fr[good], depth[good]
    order = np.lexsort((depth, cj))
    first = np.ones(order.size, dtype=bool)
    first[1:] = cj[order][1:] != cj[order][:-1]
    sel = order[first]
    j = cj[sel]
    out_d[j], out_f[j], out_k[j], out_b[j], out_i[j] = depth[sel], fr[sel], ck[sel], cb[sel], ci[sel]
    return out_d, out_f, out_k, out_b, out_i


def _lobe_piece(curves: ZOACurves, b: np.ndarray, k: np.ndarray, i: np.ndarray) -> np.ndarray:
    """Which monotone piece of its lobe each point (branch ``b``, lobe ``k``, grid interval ``i``) is on.

    A piece is a run of grid intervals with finite depth at both ends over which the lobe's speed
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
        finite = np.isfinite(depth_c[bb])
        valid = finite[:-1] & finite[1:]
        with np.errstate(invalid="ignore"):
            up = np.diff(x) > 0
        starts = ~valid
        starts[1:] |= ~valid[:-1] | (up[1:] != up[:-1])
        run = np.cumsum(starts)
        sel = ok & (b == bb) & (k == kk)
        out[sel] = run[i[sel]]
    return out


# A cusp is accepted when no other lobe is lower there than the two that cross, to this tolerance.
_CUSP_RTOL = 1e-9
# Refinement levels of the cusp search: an interval whose minimising lobes cross somewhere above
# the envelope (a third lobe lower in between) is split there and searched again.
_CUSP_LEVELS = 4
# Two pieces of one lobe intersect at two distinct chatter frequencies; a Newton solution closer
# than this (relative) is the trivial one (both at the same point of the curve), not a crossing.
_SAME_POINT_RTOL = 1e-6


def envelope(structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients, rpm,
             *, curves: ZOACurves | None = None, freq_hz=None, n_freq: int = 10_000) -> ZOAEnvelope:
    """The ZOA stability limit at each grid speed, exact, plus the cusps between lobes.

    Parameters
    ----------
    structure, tool, cut, coefficients
        As in :func:`limit_curves`.
    rpm : array_like, shape (n_rpm,)
        Increasing spindle speeds, rpm.
    curves : ZOACurves, optional
        Precomputed :func:`limit_curves` (else computed on ``freq_hz``).
    freq_hz : array_like, optional
        Chatter-frequency grid; default :func:`default_chatter_frequencies`.
    n_freq : int
        Size of the default grid.

    Returns
    -------
    ZOAEnvelope

    Notes
    -----
    The lobes are those of the continued eigenvalue branches (:meth:`ZOACurves.continued`). Between
    two grid speeds whose lowest lobes differ (another branch, another ``k``, or another monotone
    piece of the same lobe, such as a robot mode's lobe 0 and a tool mode's lobe 0), the two lobe
    curves are intersected (Newton on ``rpm_1(f_1) = rpm_2(f_2)``, ``depth_1(f_1) = depth_2(f_2)``);
    the point is a cusp of the envelope when no third lobe is lower there. Otherwise the interval
    is split at that speed and searched again (up to 4 levels): where lobes are much narrower than
    the grid spacing some cusps are left out, but every returned value is exact.
    """
    rpm = np.asarray(rpm, dtype=float).ravel()
    if rpm.size == 0 or np.any(rpm <= 0) or np.any(np.diff(rpm) <= 0):
        raise ValueError("rpm must be positive and strictly increasing")
    prob = _Problem(structure, tool, cut, coefficients)
    if curves is None:
        f = default_chatter_frequencies(structure, n_freq=n_freq) if freq_hz is None else freq_hz
        curves = limit_curves(structure, tool, cut, coefficients, f)
    prob.follow(curves)
    k_lo, k_hi = _lobe_range(curves, rpm[0], rpm[-1])
    d, fr, k, b, iv = _lowest_lobe(prob, curves, rpm, k_lo, k_hi)
    # working set: grid points (kind 0), cusps (1), helper points that split intervals (2)
    pts = [rpm, d, fr, k, b, _lobe_piece(curves, b, k, iv), np.zeros(rpm.size, dtype=int)]
    for _ in range(_CUSP_LEVELS):
        order = np.argsort(pts[0], kind="stable")
        r, d, fr, k, b, piece, kind = (a[order] for a in pts)
        change = (k[:-1] != k[1:]) | (b[:-1] != b[1:]) | (piece[:-1] != piece[1:])
        sw = np.flatnonzero(np.isfinite(d[:-1]) & np.isfinite(d[1:]) & change
                            & (kind[:-1] != 1) & (kind[1:] != 1))
        if sw.size == 0:
            break
        rx, dx, f1, f2, ok = _newton_intersection(prob, b[sw], k[sw], fr[sw].copy(), b[sw + 1], k[sw + 1],
                                                  fr[sw + 1].copy())
        ok &= (rx > r[sw]) & (rx < r[sw + 1])
        same_lobe = (b[sw] == b[sw + 1]) & (k[sw] == k[sw + 1])
        ok &= ~same_lobe | (np.abs(f1 - f2) > _SAME_POINT_RTOL * f1)
        if not ok.any():
            break
        rx, dx = rx[ok], dx[ok]
        uniq = np.unique(rx)
        ed, ef, ek, eb, ei = _lowest_lobe(prob, curves, uniq, k_lo, k_hi)
        at = np.searchsorted(uniq, rx)
        cusp = ed[at] >= dx * (1 - _CUSP_RTOL)
        new_kind = np.where(cusp, 1, 2)
        add = (rx, np.where(cusp, dx, ed[at]), ef[at], ek[at], eb[at], _lobe_piece(curves, eb, ek, ei)[at],
               new_kind)
        pts = [np.concatenate([p_, a_]) for p_, a_ in zip((r, d, fr, k, b, piece, kind), add)]
    order = np.argsort(pts[0], kind="stable")
    r, d, fr, k, kind = (pts[i][order] for i in (0, 1, 2, 3, 6))
    out = kind != 2
    return ZOAEnvelope(
        rpm=_ro(r[out]), depth_limit_m=_ro(d[out]), chatter_frequency_hz=_ro(fr[out]),
        lobe=_ro(k[out].astype(int)), is_intersection=_ro(kind[out] == 1),
    )
