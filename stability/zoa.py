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
Such an interval is a candidate too, from the exact onset (:class:`stability._zoa_exact._Onsets`)
to its finite end; the default grid adds lines around a mode too lightly damped for it
(:func:`stability._zoa_curves._mode_lines`), and a second pass solves every candidate the
interpolation may have wrongly left out (:func:`stability._zoa_exact._lowest_lobe`).

Layout: the grid, the limit curves' eigenvalues and branches in :mod:`stability._zoa_curves`, the
exact solve at given speeds in :mod:`stability._zoa_exact`, the lobes and the envelope here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oma.cutting import CuttingCoefficients, Cut, Tool

from ._zoa_curves import MODE_LINES, MODE_STEPS  # noqa: F401  (the grid's constants, as before the split)
from ._zoa_curves import TWO_PI, ZOACurves, _continued_row, _Problem, default_chatter_frequencies
from ._zoa_exact import _lobe_piece, _lowest_lobe, _newton_intersection, _Onsets
from .oriented import _readonly as _ro

__all__ = [
    "ZOACurves",
    "ZOAEnvelope",
    "limit_curves",
    "default_chatter_frequencies",
    "envelope",
    "lobe_segments",
]


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
