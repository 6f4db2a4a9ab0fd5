"""The surface location error on the whole finished wall, and where on the wall it is largest.

formats.md bounds ``|SLE|`` on the finished wall, not at the tool tip alone. With a helix, the
slice at height ``z`` above the tip reaches the finishing angle ``kappa z / Omega`` after the tip
(``kappa``: :func:`stability.oriented.helix_lag_per_m`), so the wall at ``z`` is the steady
displacement along the wall's normal at that later instant: harmonic ``h`` of the tooth-passing
frequency turns by ``exp(i h N kappa z)`` (the profile of :func:`stability.forced.forced_response`,
``surface_location_error_profile`` of :func:`stability.lobes.predict_point`, which samples it at
21 heights). Every command reduces its model to the same trigonometric polynomial in the height,

    ``SLE(z) = s + 2 Re sum_{h=1..H} a_h exp(i h theta_1 z)``,  ``theta_1 = N kappa``,

and one search finds its largest magnitude over ``0 <= z <= depth`` (:func:`wall_maxima`,
vectorised over many walls): a grid of ``_WALL_POINTS_PER_TURN`` heights per turn of the highest
harmonic over the depth (the tip and the top included; :func:`wall_points`), then a safeguarded
Newton iteration on ``d|SLE|/dz = 0`` from every sampled local maximum that may sit next to the
largest peak, kept between its grid neighbours (a Newton step where it stays inside and heads for
a maximum, else bisection of the bracket by the sign of the slope). A peak's nearest grid height
is at most ``max|SLE''| (dz / 2)^2 / 2`` below it (:func:`_sampling_gap`), so every sampled local
maximum within that of the best peak found is refined (in batches, largest first): the grid
maximum next to the largest peak is among them, however many peaks of nearly one height the wall
has (a search from a fixed two or three missed it, by up to 2 %: tests/test_predict_wall.py).
Newton then converges to rounding. The answer is never below the largest sampled value, nor the tip's.

* :func:`wall_maxima`: the search (``plan`` through :meth:`planner.cut_model.CutModel.wall_max`,
  ``check`` through :func:`planner.check_forces.surface_errors`, ``predict`` and the planner's
  re-check through :func:`wall_extremum`);
* :func:`wall_extremum`, :func:`wall_error`: of a predicted cut (its forced response's
  displacement harmonics), signed and as a magnitude;
* :func:`local_maxima`, :func:`wall_points`: the grid, shared with the planner's start heights
  (:mod:`planner.optimize`).
"""

from __future__ import annotations

import numpy as np

from stability.lobes import OperatingPoint
from stability.oriented import helix_lag_per_m

__all__ = ["wall_maxima", "wall_extremum", "wall_error", "local_maxima", "wall_points"]

TWO_PI = 2.0 * np.pi

#: Grid heights per turn of the highest harmonic over the depth: a sampled maximum within
#: ``(pi / 8)^2 / 2`` of that harmonic's amplitude, close enough for the iteration to converge.
_WALL_POINTS_PER_TURN = 8
#: Fewest and most grid heights per wall (the most bounds memory and time at very many turns).
_WALL_MIN_POINTS, _WALL_MAX_POINTS = 17, 8193
#: Sampled local maxima refined at once per wall (in batches, largest first, while one is within
#: the sampling's bound of the best peak found: :func:`_largest_peaks`), and the most iterations
#: from each (Newton converges in 3-4 from the grid; bisection alone gains 2^-8 of the bracket).
_WALL_CANDIDATES = 4
_WALL_ITERATIONS = 8
#: The iteration stops once no height moves by more than this fraction of the depth (the value is
#: then within ~(1e-12)^2 of the peak's, relative).
_WALL_Z_RTOL = 1e-12
#: Complex values per block of the grid evaluation (walls x heights): 4 MB.
_WALL_BLOCK = 2**18
#: A helix lag below this over the depth (rad) is a straight flute: every height is finished at
#: the tip's instant (as ``stability.oriented._STRAIGHT_LAG_RAD``).
_STRAIGHT_LAG_RAD = 1e-9


def local_maxima(v) -> np.ndarray:
    """Indices of the local maxima of ``v`` (the ends included), largest first."""
    pad = np.concatenate([[-np.inf], v, [-np.inf]])
    peaks = np.flatnonzero((pad[1:-1] >= pad[:-2]) & (pad[1:-1] >= pad[2:]))
    return peaks[np.argsort(v[peaks])[::-1]]


def wall_points(n_harm: int, theta_1: float, ap: float) -> int:
    """Grid heights of the search on a wall of height ``ap`` (m), harmonic 1 turning by
    ``theta_1`` rad/m along it (``N kappa``) and ``n_harm`` harmonics summed:
    ``_WALL_POINTS_PER_TURN`` per turn of the highest harmonic over the depth, 17 to 8193."""
    turns = n_harm * abs(theta_1) * ap / TWO_PI
    return int(np.clip(np.ceil(_WALL_POINTS_PER_TURN * turns) + 1, _WALL_MIN_POINTS, _WALL_MAX_POINTS))


def _harmonic_sums(a, p, orders=(0,)) -> list[np.ndarray]:
    """``sum_h h^k a_h p^h`` (h = 1..H) for each ``k`` in ``orders``: a (G, H), p (G, K) complex;
    each (G, K). On a grid (many heights, k = 0) by Horner's rule; at a few heights, the powers by a
    running product over ``h`` (vectorised over ``h``, in blocks of ``_WALL_BLOCK`` values)."""
    n_h = a.shape[1]
    if tuple(orders) == (0,) and p.shape[1] > _WALL_CANDIDATES:  # a grid: Horner's rule, in place
        total = np.zeros(p.shape, dtype=complex)
        for h in range(n_h, 0, -1):
            total += a[:, h - 1, None]
            total *= p
        return [total]
    out = [np.empty(p.shape, dtype=complex) for _ in orders]
    h = np.arange(1, n_h + 1, dtype=float)
    weights = [a * h**k for k in orders]  # (G, H) each
    cols = max(1, _WALL_BLOCK // max(1, n_h))
    rows = max(1, _WALL_BLOCK // max(1, min(cols, p.shape[1]) * n_h))
    for g0 in range(0, p.shape[0], rows):
        g = slice(g0, g0 + rows)
        for k0 in range(0, p.shape[1], cols):
            k = slice(k0, k0 + cols)
            pw = np.cumprod(np.broadcast_to(p[g, k, None], p[g, k].shape + (n_h,)), axis=-1)  # (G, K, H)
            for o, w in zip(out, weights):
                o[g, k] = np.einsum("gkh,gh->gk", pw, w[g])
    return out


def _sle(a, static, theta_1: float, z, orders=(0,)) -> list[np.ndarray]:
    """``SLE(z)`` and its derivatives of the ``orders`` in ``z`` (0, 1, 2), each z's shape (G, K)."""
    sums = _harmonic_sums(a, np.exp(1j * theta_1 * z), orders)
    return [static[:, None] + 2.0 * s.real if k == 0 else 2.0 * ((1j * theta_1) ** k * s).real
            for k, s in zip(orders, sums)]


def _refine(a, static, theta_1: float, zc, lo, hi, tol_m: float):
    """Safeguarded Newton on ``d|SLE|/dz = 0`` from ``zc`` within ``[lo, hi]`` (each (G, K)), m;
    stops early once no height moves by more than ``tol_m``."""
    for _ in range(_WALL_ITERATIONS):
        f, d1, d2 = _sle(a, static, theta_1, zc, (0, 1, 2))
        sign = np.where(f < 0.0, -1.0, 1.0)
        slope, curve = sign * d1, sign * d2  # of |SLE|
        # the peak lies uphill: shrink the bracket to that side of zc (at a zero slope, onto zc)
        lo, hi = np.where(slope >= 0.0, zc, lo), np.where(slope <= 0.0, zc, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = zc - slope / curve
        newton = (curve < 0.0) & (step >= lo) & (step <= hi)  # converged: the step stays on zc
        new = np.where(newton, step, 0.5 * (lo + hi))
        done = bool(np.all(np.abs(new - zc) <= tol_m))
        zc = new
        if done:
            break
    return zc


def _sampling_gap(a, theta_1: float, spacing_m) -> np.ndarray:
    """How far below a peak of ``|SLE|`` its nearest grid height can lie, m, per wall: ``|f''|
    (spacing / 2)^2 / 2`` (``f' = 0`` at an inner peak), with ``|f''| <= 2 theta_1^2 sum h^2 |a_h|``."""
    h = np.arange(1, a.shape[1] + 1)
    return theta_1**2 * (np.abs(a) @ (h * h)) * (np.asarray(spacing_m) / 2.0) ** 2


def wall_maxima(amplitudes, static, theta_1: float, depth_m, n_harm=None) -> tuple[np.ndarray, np.ndarray]:
    """The largest ``|SLE|`` on each of many walls, signed, and its height above the tip.

    ``SLE(z) = static + 2 Re sum_{h=1..H} a_h exp(i h theta_1 z)`` over ``0 <= z <= depth``
    (module docstring: the grid, then a safeguarded Newton iteration from its best local maxima).

    Parameters
    ----------
    amplitudes : array_like, shape (n_walls, H), complex
        ``a_h`` for h = 1..H, m (zero above a wall's own harmonic count).
    static : array_like, shape (n_walls,)
        The part that does not turn with the height, m.
    theta_1 : float
        Turn of harmonic 1 per unit height, ``N kappa``, rad/m (0: straight flutes).
    depth_m : array_like, shape (n_walls,)
        Height of each wall (the axial depth), m.
    n_harm : array_like of int, shape (n_walls,), optional
        Harmonics summed on each wall (the grid's density); default H.

    Returns
    -------
    value : ndarray, shape (n_walls,)
        ``SLE`` where ``|SLE|`` is largest, m (signed: positive, material left on the wall).
    height : ndarray, shape (n_walls,)
        Where that is, m above the tip (0 for a straight flute, whose wall is the tip's value).
    """
    a = np.atleast_2d(np.asarray(amplitudes, dtype=complex))
    static = np.atleast_1d(np.asarray(static, dtype=float))
    depth = np.atleast_1d(np.asarray(depth_m, dtype=float))
    harm = np.full(a.shape[0], a.shape[1]) if n_harm is None else np.atleast_1d(np.asarray(n_harm))
    value, height = static + 2.0 * a.sum(axis=1).real, np.zeros(a.shape[0])  # at the tip
    helix = np.flatnonzero((np.abs(theta_1 * depth) >= _STRAIGHT_LAG_RAD) & (harm > 0))
    if helix.size == 0 or a.shape[1] == 0:
        return value, height
    n = wall_points(1, theta_1, float(np.max(harm[helix] * depth[helix])))
    frac = np.linspace(0.0, 1.0, n)
    rows_per_block = max(1, _WALL_BLOCK // n)
    for j0 in range(0, helix.size, rows_per_block):
        sel = helix[j0:j0 + rows_per_block]
        aa, st, d = a[sel], static[sel], depth[sel]
        z = d[:, None] * frac[None, :]  # (G, n): the tip and the top included
        fc, zc = _largest_peaks(aa, st, theta_1, z, _sle(aa, st, theta_1, z)[0])
        tip = np.abs(fc) <= np.abs(value[sel])  # the tip by the direct sum: never below it by rounding
        value[sel], height[sel] = np.where(tip, value[sel], fc), np.where(tip, 0.0, zc)
    return value, height


def _largest_peaks(a, static, theta_1: float, z, f) -> tuple[np.ndarray, np.ndarray]:
    """The largest ``|SLE|`` of each wall from its grid ``z``, ``f = SLE(z)`` (G, n): the sampled
    local maxima refined in batches of ``_WALL_CANDIDATES``, largest first, while one lies within
    the sampling gap (:func:`_sampling_gap`) of the best peak found. Returns (value, height), (G,)."""
    n = z.shape[1]
    v = np.abs(f)
    pad = np.pad(v, ((0, 0), (1, 1)), constant_values=-np.inf)
    local = np.where((v >= pad[:, :-2]) & (v >= pad[:, 2:]), v, -np.inf)
    order = np.argsort(-local, axis=1, kind="stable")  # local maxima first, largest first
    gap = _sampling_gap(a, theta_1, z[:, -1] / (n - 1))
    rows = np.arange(z.shape[0])
    best = np.argmax(v, axis=1)
    best_f, best_z = f[rows, best], z[rows, best]
    tol_m = _WALL_Z_RTOL * float(z[:, -1].max())
    for start in range(0, n, _WALL_CANDIDATES):
        cand = order[:, start:start + _WALL_CANDIDATES]  # (G, K)
        # a peak lies within gap of its nearest grid height's |SLE|: below that, none can beat the best
        open_ = local[rows[:, None], cand] >= np.abs(best_f)[:, None] - gap[:, None]
        live = np.flatnonzero(open_.any(axis=1))
        if live.size == 0:
            break
        cand = np.where(open_[live], cand[live], cand[live, :1])  # (the first of a batch is open)
        r = live[:, None]
        zs, fs = z[r, cand], f[r, cand]
        lo, hi = z[r, np.maximum(cand - 1, 0)], z[r, np.minimum(cand + 1, n - 1)]
        zr = _refine(a[live], static[live], theta_1, zs, lo, hi, tol_m)
        fr = _sle(a[live], static[live], theta_1, zr)[0]
        better = np.abs(fr) > np.abs(fs)  # never below the sampled maximum
        fr, zr = np.where(better, fr, fs), np.where(better, zr, zs)
        k = np.argmax(np.abs(fr), axis=1)
        fr, zr = fr[np.arange(live.size), k], zr[np.arange(live.size), k]
        up = np.abs(fr) > np.abs(best_f[live])
        best_f[live], best_z[live] = np.where(up, fr, best_f[live]), np.where(up, zr, best_z[live])
    return best_f, best_z


def wall_extremum(point: OperatingPoint, tool, cut) -> tuple[float, float]:
    """The surface location error where ``|SLE|`` on the finished wall of a predicted cut is
    largest, m (signed: positive, material left on the wall), and its height above the tip, m.

    From the displacement harmonics ``X_h`` of :func:`stability.lobes.predict_point`'s forced
    response: ``SLE(z) = sign n . (X_0 + 2 Re sum_h X_h exp(i h 2 pi f_T (t_fin + kappa z /
    Omega)))`` (the function ``surface_location_error_profile`` samples), so ``a_h = sign n . X_h
    exp(i h 2 pi f_T t_fin)`` and ``theta_1 = N kappa`` (:func:`wall_maxima`). ``cut`` gives the
    milling direction and the wall's normal (its feed is the point's already). ``point`` may also
    be a :class:`stability.forced.ForcedResponse`.
    """
    fr = point.forced if isinstance(point, OperatingPoint) else point
    sign = 1.0 if cut.milling == "down" else -1.0
    along = sign * (np.asarray(cut.normal_direction, dtype=float) @ fr.displacement_harmonics_m)  # (H + 1,)
    h = np.arange(1, fr.harmonics + 1)
    amp = along[1:] * np.exp(1j * TWO_PI * fr.tooth_frequency_hz * fr.finishing_time_s * h)
    value, height = wall_maxima(amp[None, :], [along[0].real], tool.teeth * helix_lag_per_m(tool),
                                [fr.axial_depth_m])
    if abs(value[0]) <= abs(fr.surface_location_error_m):  # at the tip: its value as reported, not a rounding below
        return fr.surface_location_error_m, 0.0
    return float(value[0]), float(height[0])


def wall_error(point: OperatingPoint, tool, cut) -> tuple[float, float]:
    """Largest ``|SLE|`` on the finished wall of a predicted cut, m, and its height above the
    tip, m (:func:`wall_extremum`; the planner's re-check and its report)."""
    value, height = wall_extremum(point, tool, cut)
    return abs(value), height
