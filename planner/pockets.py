"""Speed pockets of the planner: the stability limit as smooth pieces between lobe crossings.

The lower envelope of the lobes is smooth between two adjacent lobe crossings (one lobe branch), so
:func:`plan <planner.optimize.plan>` cuts the speed range into *pockets* there and solves one NLP
per pocket. ZOA (:func:`zoa_pockets`): the exact cusps of :func:`stability.zoa.envelope`, plus
crossings it does not mark (two lobes with the same number from different modes: the chatter
frequency jumps; bisected); in each pocket the limit is a Chebyshev series through the exact
envelope at Chebyshev-Lobatto nodes, the degree doubled until converged. SDM
(:func:`sdm_pockets`): the local maxima of the sampled diagram refined by golden-section search and
a PCHIP through the samples. Pockets narrower than ``min_pocket_rel_width`` of their centre speed
are merged into the lower convex hull of their minima, one linear piece per NLP (conservative).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.interpolate import PchipInterpolator

from stability import zoa
from stability.lobes import LobeDiagram, lobe_diagram

if TYPE_CHECKING:
    from .plan_results import PlanSettings

__all__ = ["Pocket", "cheb_eval", "build_pockets", "zoa_pockets", "sdm_pockets"]

log = logging.getLogger(__name__)


def _lobatto(m: int) -> np.ndarray:
    """Chebyshev-Lobatto points ``cos(pi j / m)``, j = 0..m (from 1 down to -1)."""
    return np.cos(np.pi * np.arange(m + 1) / m)


def _cheb_coeffs(values) -> np.ndarray:
    """Coefficients of the degree-m interpolant through values at :func:`_lobatto` (m) points."""
    v = np.asarray(values, dtype=float)
    m = v.size - 1
    if m == 0:
        return v.copy()
    j = np.arange(m + 1)
    w = np.ones(m + 1)
    w[0] = w[-1] = 0.5
    c = (2.0 / m) * (np.cos(np.pi * np.outer(j, j) / m) @ (w * v))
    c[0] *= 0.5
    c[-1] *= 0.5
    return c


def cheb_eval(coeffs, x):
    """Clenshaw sum of a Chebyshev series at ``x`` in [-1, 1]; NumPy arrays or CasADi symbols."""
    b1, b2 = 0.0 * x, 0.0 * x
    for c in coeffs[:0:-1]:
        b1, b2 = 2.0 * x * b1 - b2 + c, b1
    return x * b1 - b2 + coeffs[0]


@dataclass(frozen=True)
class Pocket:
    """One speed interval with a smooth stability limit ``a_lim(n)`` (Chebyshev series)."""

    rpm_lo: float
    rpm_hi: float
    coeffs: np.ndarray
    kind: str  # 'lobe' (ZOA exact), 'sampled' (SDM samples), 'hull' (merged narrow pockets)

    def x(self, rpm):
        return (2.0 * rpm - (self.rpm_lo + self.rpm_hi)) / (self.rpm_hi - self.rpm_lo)

    def limit(self, rpm):
        """Limit depth, m, at speeds inside the pocket (NumPy or CasADi)."""
        return cheb_eval(self.coeffs, self.x(rpm))


# ------------------------------------------------------------------------------- stability model
def _pocket_breaks_zoa(diagram: LobeDiagram, lo: float, hi: float, chatter_at) -> np.ndarray:
    """Pocket ends: the diagram's cusps, plus cusps it does not mark.

    Two lobes with the same number ``k`` from different modes (a robot mode's lobe 0 and a tool
    mode's lobe 0) cross without an intersection point in :func:`stability.zoa.envelope`; there
    the chatter frequency jumps between neighbouring grid speeds. Each such jump is bisected on
    speed (``chatter_at(rpm) -> Hz``) to the crossing.
    """
    rpm = np.asarray(diagram.rpm)
    f = np.asarray(diagram.chatter_frequency_hz)
    inter = np.asarray(diagram.is_intersection)
    cusps = list(rpm[inter])
    i = np.flatnonzero(~inter[:-1] & ~inter[1:] & np.isfinite(f[:-1]) & np.isfinite(f[1:]))
    jump = i[np.abs(np.log(f[i + 1] / f[i])) > np.log(1.0 + _CHATTER_JUMP)]
    if jump.size:
        a, b = rpm[jump].copy(), rpm[jump + 1].copy()
        fa, fb = f[jump], f[jump + 1]
        for _ in range(60):
            mid = 0.5 * (a + b)
            fm = chatter_at(mid)
            left = np.abs(np.log(fm / fa)) < np.abs(np.log(fm / fb))
            a, b = np.where(left, mid, a), np.where(left, b, mid)
            if np.all(b - a <= 1e-10 * b):
                break
        cusps += list(0.5 * (a + b))
        log.info("%d lobe crossings not marked in the diagram, located by bisection", jump.size)
    cusps = np.asarray(cusps, dtype=float)
    return np.unique(np.concatenate([[lo], cusps[(cusps > lo) & (cusps < hi)], [hi]]))


# Relative jump of the chatter frequency between neighbouring speeds that marks a lobe change
# (along one lobe it changes by well under 1 % between grid speeds).
_CHATTER_JUMP = 0.05


def _sdm_samples(diagram: LobeDiagram, limit_at, lo: float, hi: float, iterations: int):
    """SDM samples with every cusp located by golden-section search, and the pocket ends.

    The cusps of a sampled diagram are its local maxima; between the neighbouring samples the
    envelope is unimodal (two lobe branches meeting), so each is refined by golden-section steps
    (``limit_at(rpm_array) -> depth_array``, all cusps at once). Returns the speeds and limits
    of all samples (sorted) and the breaks (range ends and refined cusps).
    """
    r = np.asarray(diagram.rpm, dtype=float)
    d = np.asarray(diagram.depth_limit_m, dtype=float)
    d = np.where(np.isfinite(d), d, 1.0)  # no limit found below the search depth
    peak = np.flatnonzero((d[1:-1] > d[:-2]) & (d[1:-1] >= d[2:])) + 1
    extra_r, extra_d = [], []
    best_r = r[peak].copy()
    if peak.size and iterations > 0:
        g = (np.sqrt(5.0) - 1.0) / 2.0
        a, b = r[peak - 1].copy(), r[peak + 1].copy()
        c, e = b - g * (b - a), a + g * (b - a)
        fc, fe = limit_at(c), limit_at(e)
        extra_r += [c, e]
        extra_d += [fc, fe]
        for _ in range(iterations - 1):
            left = fc >= fe  # the maximum is in [a, e]
            a, b = np.where(left, a, c), np.where(left, e, b)
            new = np.where(left, b - g * (b - a), a + g * (b - a))
            fn = limit_at(new)
            c, fc, e, fe = (np.where(left, new, e), np.where(left, fn, fe), np.where(left, c, new),
                            np.where(left, fc, fn))
            extra_r.append(new)
            extra_d.append(fn)
        allr = np.concatenate([r[peak][None]] + [x[None] for x in extra_r])
        alld = np.concatenate([d[peak][None]] + [x[None] for x in extra_d])
        i = np.argmax(alld, axis=0)
        best_r = allr[i, np.arange(peak.size)]
    rr = np.concatenate([r] + extra_r)
    dd = np.concatenate([d] + [np.where(np.isfinite(x), x, 1.0) for x in extra_d])
    rr, idx = np.unique(rr, return_index=True)
    breaks = np.unique(np.concatenate([[lo], best_r[(best_r > lo) & (best_r < hi)], [hi]]))
    return rr, dd[idx], breaks


def _lower_hull(x, y):
    """Vertices of the lower convex hull of points sorted by x (monotone chain)."""
    hull = []
    for p in zip(x, y):
        while len(hull) >= 2:
            (x1, y1), (x2, y2) = hull[-2], hull[-1]
            if (x2 - x1) * (p[1] - y1) - (y2 - y1) * (p[0] - x1) <= 0:
                hull.pop()
            else:
                break
        hull.append(p)
    return np.array(hull)


def _linear_pocket(x0, y0, x1, y1) -> Pocket:
    return Pocket(float(x0), float(x1), np.array([(y0 + y1) / 2.0, (y1 - y0) / 2.0]), "hull")


# A Chebyshev series of the SDM's PCHIP (only once differentiable at the samples) is accepted at
# this relative accuracy: well inside the SDM's own (PlanSettings.sdm_rtol = 1 %).
_SAMPLED_CHEB_RTOL = 1e-3


def build_pockets(breaks, value_fn, settings: PlanSettings, *, sampled: bool, merge: bool = True) -> list[Pocket]:
    """Pockets between consecutive breaks; narrow ones merged into lower-hull pieces (``merge``).

    ``value_fn(rpm_array) -> depth_array`` gives the limit (exact ZOA, or the SDM PCHIP).
    """
    lo, hi = breaks[:-1], breaks[1:]
    narrow = (hi - lo) / (0.5 * (hi + lo)) < settings.min_pocket_rel_width
    if not merge:
        narrow[:] = False
    pockets: list[Pocket] = []
    wide = np.flatnonzero(~narrow)
    # --- wide pockets: Chebyshev series, degree doubled until converged (ZOA) -------------------
    degree = {int(i): 16 for i in wide}
    coeffs: dict[int, np.ndarray] = {}
    pending = list(degree)
    while pending:
        nodes = {i: 0.5 * (lo[i] + hi[i]) + 0.5 * (hi[i] - lo[i]) * _lobatto(2 * degree[i]) for i in pending}
        allr = np.concatenate([nodes[i] for i in pending])
        vals = value_fn(allr)
        again, k = [], 0
        for i in pending:
            v = vals[k:k + nodes[i].size]
            k += nodes[i].size
            v = np.where(np.isfinite(v), v, 1.0)  # no limit found: any depth (bounded by ap_hi)
            c_half = _cheb_coeffs(v[::2])
            err = np.max(np.abs(cheb_eval(c_half, _lobatto(2 * degree[i])[1::2]) - v[1::2]))
            rtol = _SAMPLED_CHEB_RTOL if sampled else settings.cheb_rtol
            if err <= rtol * np.min(v) or degree[i] >= 64:
                if err > rtol * np.min(v):
                    log.info("pocket %.0f-%.0f rpm: Chebyshev series not converged (rel. error %.1e)",
                             lo[i], hi[i], err / np.min(v))
                coeffs[i] = _cheb_coeffs(v)
            else:
                degree[i] *= 2
                again.append(i)
        pending = again
    # --- runs of narrow pockets: lower convex hull of the pocket minima -------------------------
    runs, i = [], 0
    while i < narrow.size:
        if narrow[i]:
            j = i
            while j + 1 < narrow.size and narrow[j + 1]:
                j += 1
            runs.append((i, j))
            i = j + 1
        else:
            i += 1
    hull_pockets: dict[int, list[Pocket]] = {}
    for i, j in runs:
        r = np.concatenate([np.linspace(lo[p], hi[p], 9) for p in range(i, j + 1)])
        v = value_fn(r).reshape(j - i + 1, 9)
        v = np.where(np.isfinite(v), v, 1.0)
        rr = r.reshape(j - i + 1, 9)
        arg = np.argmin(v, axis=1)
        xm, ym = rr[np.arange(arg.size), arg], v[np.arange(arg.size), arg]
        # ends of the run: the envelope there, so the hull spans the whole run
        xs = np.concatenate([[lo[i]], xm, [hi[j]]])
        ys = np.concatenate([[min(v[0, 0], ym.min())], ym, [min(v[-1, -1], ym.min())]])
        order = np.argsort(xs, kind="stable")
        xs, ys = xs[order], ys[order]
        keep = np.concatenate([[True], np.diff(xs) > 0])
        h = _lower_hull(xs[keep], ys[keep])
        hull_pockets[i] = [_linear_pocket(*h[q], *h[q + 1]) for q in range(len(h) - 1)]
    for p in range(lo.size):
        if p in coeffs:
            pockets.append(Pocket(float(lo[p]), float(hi[p]), coeffs[p], "sampled" if sampled else "lobe"))
        elif p in hull_pockets:
            pockets.extend(hull_pockets[p])
    return pockets


def zoa_pockets(model, setup, rpm_range, settings: PlanSettings):
    """ZOA: the diagram and the pockets."""
    tool, cut, coef = setup.tool, setup.cut, setup.material.cutting_coefficients
    lo, hi = rpm_range
    curves = zoa.limit_curves(model, tool, cut, coef, zoa.default_chatter_frequencies(model, n_freq=settings.n_freq))
    diagram = lobe_diagram(model, tool, cut, coef, rpm_range=rpm_range, n_rpm=settings.n_rpm_zoa, n_freq=settings.n_freq)

    def envelope(r):
        """Depth limit and chatter frequency of the envelope at the speeds ``r`` (cusps excluded)."""
        u, inv = np.unique(np.asarray(r, dtype=float), return_inverse=True)
        env = zoa.envelope(model, tool, cut, coef, u, curves=curves)
        keep = ~np.asarray(env.is_intersection)
        return np.asarray(env.depth_limit_m)[keep][inv], np.asarray(env.chatter_frequency_hz)[keep][inv]

    breaks = _pocket_breaks_zoa(diagram, lo, hi, lambda r: envelope(r)[1])
    return diagram, build_pockets(breaks, lambda r: envelope(r)[0], settings, sampled=False)


def sdm_pockets(model, setup, rpm_range, settings: PlanSettings):
    """SDM: the diagram, the pockets, the samples (speeds, limits) and the limit function."""
    tool, cut, coef = setup.tool, setup.cut, setup.material.cutting_coefficients
    diagram = lobe_diagram(model, tool, cut, coef, rpm_range=rpm_range, n_rpm=settings.n_rpm_sdm, method="sdm",
                           rtol=settings.sdm_rtol)
    res = diagram.resolution

    def sdm_limit(r):
        """SDM limits at more speeds, at the diagram's resolution (no new convergence test)."""
        u, inv = np.unique(np.asarray(r, dtype=float), return_inverse=True)
        more = lobe_diagram(model, tool, cut, coef, rpm_range=(u[0], u[-1] + 1.0), rpm=u, method="sdm",
                            rtol=settings.sdm_rtol, steps_per_mode_period=res.steps_per_mode_period,
                            min_steps=res.min_steps)
        return np.asarray(more.depth_limit_m)[inv]

    rr, dd, breaks = _sdm_samples(diagram, sdm_limit, *rpm_range, settings.sdm_cusp_iterations)
    pockets = build_pockets(breaks, PchipInterpolator(rr, dd), settings, sampled=True)
    return diagram, pockets, [rr, dd], sdm_limit


def sampled_pockets(limit_fn, method: str, rpm_range, settings: PlanSettings):
    """Pockets of any limit function sampled like the SDM's (``limit_fn(rpm_array) -> depth_array``),
    e.g. the chance-constrained depth of a learned posterior (:class:`planner.learn.predictive.
    ChanceLimit`): the diagram, the pockets, the samples and the function, as :func:`sdm_pockets`."""
    lo, hi = rpm_range
    rpm = np.linspace(lo, hi, settings.n_rpm_sdm)
    depth = np.asarray(limit_fn(rpm), dtype=float)
    n = rpm.size
    diagram = LobeDiagram(method=method, rpm=rpm, depth_limit_m=depth, chatter_frequency_hz=np.full(n, np.nan),
                          kind=np.full(n, "none"), is_intersection=np.zeros(n, bool), steps=np.zeros(n, int))
    rr, dd, breaks = _sdm_samples(diagram, limit_fn, lo, hi, settings.sdm_cusp_iterations)
    pockets = build_pockets(breaks, PchipInterpolator(rr, dd), settings, sampled=True)
    return diagram, pockets, [rr, dd], limit_fn
