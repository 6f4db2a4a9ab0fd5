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

Onsets. A lobe starts where its branch's ``Re lambda`` crosses 0 (depth -> infinity, ``eps`` -> 0
or 2 pi): the grid interval holding that crossing has one finite and one infinite end, and on a
coarse grid a lightly damped mode's whole lobe flank lies in it, down to a few times the lobe's
minimum (0.5 % damping, 10 000 lines: 14.9 mm at 21 990 rpm, where the next lobe up gave 0.119 m).
Such an interval is a candidate too, from the exact onset (:class:`_Onsets`) to its finite end; the
default grid adds lines around a mode too lightly damped for it (:func:`_mode_lines`), and a
second pass solves every candidate the interpolation may have wrongly left out
(:func:`_lowest_lobe`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oma.cutting import CuttingCoefficients, Cut, Tool

from .oriented import _readonly as _ro, average_directional_matrix

__all__ = [
    "ZOACurves",
    "ZOAEnvelope",
    "limit_curves",
    "default_chatter_frequencies",
    "envelope",
    "lobe_segments",
]

TWO_PI = 2.0 * np.pi

#: Chatter-frequency lines per ``zeta fn`` at a mode's peak added by
#: :func:`default_chatter_frequencies` where the log grid is coarser (as ``planner.atlas._kernel``:
#: with 4 the interpolated depth that preselects the lobes is within a few per cent at the peak).
MODE_STEPS = 4.0
#: At most this many added lines on each side of a mode (a damping ratio of 1e-5 needs 25 at
#: 10 000 log lines, 1e-7 needs 43).
MODE_LINES = 48


def _mode_lines(natural_frequency_hz, damping_ratio, stiffness_N_m, f_lo: float, f_hi: float,
               n_log: int) -> np.ndarray:
    """Lines added around each mode to a log grid of ``n_log`` lines over ``f_lo .. f_hi``, Hz.

    A mode turns the eigenvalues over a band ``~2 zeta fn`` wide; a lobe starts (``Re lambda``
    crosses 0) within it and reaches its lowest depth ``zeta fn`` further on. Where the log grid's
    relative step is coarser than ``zeta / MODE_STEPS``, the lines ``fn (1 + zeta sinh(j /
    MODE_STEPS))`` are added for ``|j| <= MODE_LINES`` while their local spacing ``zeta cosh(u) /
    MODE_STEPS`` is finer than the log grid's (the same rule as the atlas kernel,
    ``planner.atlas._kernel._a_grid``, and :func:`stability.zoa_batch._k_grid`). Modes with an
    infinite stiffness add nothing. Returns the lines inside ``(f_lo, f_hi)``, unsorted.
    """
    fn = np.atleast_1d(np.asarray(natural_frequency_hz, dtype=float))
    zeta = np.atleast_1d(np.asarray(damping_ratio, dtype=float))
    stiff = np.atleast_1d(np.asarray(stiffness_N_m, dtype=float))
    step = (np.log(f_hi) - np.log(f_lo)) / (int(n_log) - 1)
    h = 1.0 / MODE_STEPS
    out = []
    for r in range(fn.size):
        ratio = step / (zeta[r] * h) if zeta[r] > 0 else np.inf
        if not stiff[r] < np.inf or ratio <= 1.0:
            continue
        m = MODE_LINES if not np.isfinite(ratio) else min(MODE_LINES, int(np.arccosh(ratio) / h))
        f = fn[r] * (1.0 + zeta[r] * np.sinh(np.arange(-m, m + 1) * h))
        out.append(f[(f > f_lo) & (f < f_hi)])
    return np.concatenate(out) if out else np.zeros(0)


def _merge_lines(log_grid: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """``log_grid`` and ``extra`` lines sorted, a line within 1e-12 (relative) of the line before
    it dropped."""
    if extra.size == 0:
        return log_grid
    f = np.sort(np.concatenate([log_grid, extra]))
    keep = np.ones(f.size, dtype=bool)
    keep[1:] = f[1:] > f[:-1] * (1.0 + 1e-12)
    return f[keep]


def default_chatter_frequencies(structure, *, n_freq: int = 10_000) -> np.ndarray:
    """Chatter-frequency grid, Hz: the table's own frequencies for a measured FRF, otherwise
    ``n_freq`` log-spaced points from a third of the lowest to three times the highest natural
    frequency (constant relative resolution, so a 10 Hz robot mode and a 1.4 kHz spindle mode are
    resolved alike) plus, around a mode too lightly damped for that resolution, the lines of
    :func:`_mode_lines` (none at 10 000 lines unless ``zeta < 2.6e-3``; at 2 000, ``zeta < 1.3e-2``)."""
    if hasattr(structure, "natural_frequency_hz"):
        fn = np.asarray(structure.natural_frequency_hz, dtype=float)
        f_lo, f_hi = fn.min() / 3.0, fn.max() * 3.0
        extra = _mode_lines(fn, structure.damping_ratio, structure.stiffness_N_m, f_lo, f_hi, int(n_freq))
        return _merge_lines(np.geomspace(f_lo, f_hi, int(n_freq)), extra)
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
        self._frame = np.asarray(cut.frame)  # built once: the solvers ask for a few lines at a time
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
        # oriented_receptance (stability.oriented.cut_receptance's rows f, n) with the frame kept
        g = np.asarray(self.structure.receptance(np.atleast_1d(np.asarray(freq_hz, dtype=float))))
        g = np.einsum("ip,pqk,jq->ijk", self._frame, g, self._frame)[:2]  # (2, 3, n)
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

    def branch_eigenvalue(self, c, freq_hz) -> np.ndarray:
        """Eigenvalue of continued branch ``c`` (array, one per frequency) at ``freq_hz`` (call
        :meth:`follow` first)."""
        f = np.asarray(freq_hz, dtype=float)
        lam = self.eigenvalues(f)
        gap = self._grid_gap
        ref = np.interp(f, self._grid_f, gap.real) + 1j * np.interp(f, self._grid_f, gap.imag)
        sorted_first = (np.conj(ref) * (lam[0] - lam[1])).real >= 0  # row 0 continues branch 0
        return np.where(sorted_first == (np.asarray(c) == 0), lam[0], lam[1])

    def branch(self, c, freq_hz):
        """Depth and phase of continued branch ``c`` (array, one per frequency) at ``freq_hz``
        (call :meth:`follow` first)."""
        return self.depth_phase(self.branch_eigenvalue(c, freq_hz))


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


def _lobe_range(curves: ZOACurves, rpm_lo: float, rpm_hi: float,
                onsets: _Onsets | None = None) -> tuple[int, int]:
    """Lobes ``k_lo .. k_hi`` that can reach a speed in ``[rpm_lo, rpm_hi]`` (from the finite grid
    points and, when given, the lobes' onsets)."""
    ok = np.isfinite(curves.depth_m)
    f, p = curves.freq_hz[None, :], curves.phase_rad / TWO_PI
    f, p = np.broadcast_to(f, ok.shape)[ok], p[ok]
    if onsets is not None:
        f, p = np.concatenate([f, onsets.f_on]), np.concatenate([p, onsets.p_on])
    if f.size == 0:
        return 0, -1
    # lobe k reaches speed n at chatter frequency f iff k = 60 f / (N n) - eps / 2 pi
    x = 60.0 * f / curves.teeth
    return max(0, int(np.floor(np.min(x / rpm_hi - p)))), int(np.floor(np.max(x / rpm_lo - p)))


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
    onsets = _Onsets(prob, curves)
    k_lo, k_hi = _lobe_range(curves, rpm[0], rpm[-1], onsets)
    d, fr, k, b, iv = _lowest_lobe(prob, curves, rpm, k_lo, k_hi, onsets)
    # working set: grid points (kind 0), cusps (1), helper points that split intervals (2)
    pts = [rpm, d, fr, k, b, _lobe_piece(curves, b, k, iv, onsets), np.zeros(rpm.size, dtype=int)]
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
        ed, ef, ek, eb, ei = _lowest_lobe(prob, curves, uniq, k_lo, k_hi, onsets)
        at = np.searchsorted(uniq, rx)
        cusp = ed[at] >= dx * (1 - _CUSP_RTOL)
        new_kind = np.where(cusp, 1, 2)
        add = (rx, np.where(cusp, dx, ed[at]), ef[at], ek[at], eb[at], _lobe_piece(curves, eb, ek, ei, onsets)[at],
               new_kind)
        pts = [np.concatenate([p_, a_]) for p_, a_ in zip((r, d, fr, k, b, piece, kind), add)]
    order = np.argsort(pts[0], kind="stable")
    r, d, fr, k, kind = (pts[i][order] for i in (0, 1, 2, 3, 6))
    out = kind != 2
    return ZOAEnvelope(
        rpm=_ro(r[out]), depth_limit_m=_ro(d[out]), chatter_frequency_hz=_ro(fr[out]),
        lobe=_ro(k[out].astype(int)), is_intersection=_ro(kind[out] == 1),
    )
