"""The rigid-tool forces and the forced tool-tip response along a checked toolpath
(:func:`planner.check.check_toolpath`, items 4: surface location error, peak force, mean torque).

* Force harmonics: the rigid-tool force per unit depth is integrated in closed form over the
  engagement window (``(N / 2 pi) int b(psi) exp(-i h N psi) dpsi`` with trigonometric ``b``), and the
  helix is the exact axial filter ``int_0^a exp(-i h N kappa z) dz``; so the harmonics are exact for
  every depth (:func:`stability.forced.forced_response` takes them from 1024+ cell means with an
  alias correction; the two agree to its stated 1e-4 of each harmonic, in practice far closer).
* The peak force uses the angle set of :mod:`stability.forced` (4096 angles plus both sides of every
  entry/exit angle) per distinct (engagement, feed, depth).
* The surface location error takes the receptance at the harmonics of the tooth-passing frequency,
  for all distinct (model, frame, force shape, speed) at once (Schmitz & Mann, IJMTM 46, 2006):
  at the tool tip, and its largest magnitude on the whole finished wall (formats.md), where the
  slice at height ``z`` is finished ``kappa z / Omega`` after the tip, so harmonic ``h`` turns by
  ``exp(i h N kappa z)`` (the profile of :func:`stability.forced.forced_response`). The largest
  ``|SLE|`` over ``0 <= z <= depth``: a grid of ``_WALL_POINTS_PER_TURN`` heights per turn of the
  highest harmonic summed (the tip and the top included), then Newton steps on ``dSLE/dz = 0``
  from its two largest local maxima, each kept between its neighbours on the grid.
"""

from __future__ import annotations

import math

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Tool, engagement_angles
from stability.oriented import engaged_axial_integral, force_coefficients, helix_lag_per_m, torque_coefficients

__all__ = ["force_shapes", "surface_errors"]

_TWO_PI = 2.0 * math.pi
#: Angles of the peak-force search, as in ``stability.forced`` (grid over a tooth pitch).
_PEAK_GRID = 4096
#: Heights of the wall search per turn of the highest harmonic over the depth (a sampled maximum
#: within ~(pi / 8)^2 / 2 of that harmonic's amplitude; Newton then converges from it).
_WALL_POINTS_PER_TURN = 8
#: Most heights of the wall search per forced group, and Newton steps from each candidate.
_WALL_MAX_POINTS = 4097
_WALL_NEWTON = 5
#: Complex values per block of the wall search (groups x heights).
_WALL_BLOCK = 2**18


def _exp_integrals(st: float, ex: float, nu: np.ndarray) -> np.ndarray:
    """``int_st^ex exp(i nu psi) dpsi`` for integer ``nu`` (any shape)."""
    nu = np.asarray(nu, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        val = (np.exp(1j * nu * ex) - np.exp(1j * nu * st)) / (1j * nu)
    return np.where(nu == 0, ex - st, val)


# Basis (1, sin, cos, sin^2, cos^2, sin cos) as sums of exp(i m psi), m = -2..2 (columns).
_BASIS_EXP = np.array([
    [0, 0, 1, 0, 0],
    [0, 0.5j, 0, -0.5j, 0],
    [0, 0.5, 0, 0.5, 0],
    [-0.25, 0, 0.5, 0, -0.25],
    [0.25, 0, 0.5, 0, 0.25],
    [0.25j, 0, 0, 0, -0.25j],
], dtype=complex)


def force_shapes(tool: Tool, coefficients: CuttingCoefficients, cut: Cut, depths, n_harm: int):
    """Rigid-tool force of one engagement (radial depth, milling, feed) at many axial depths.

    Returns
    -------
    unit_harmonics : ndarray, shape (3, n_harm + 1), complex
        Exact Fourier coefficients of the straight-flute force per unit depth in the cut frame
        (f, n, a) over a tooth period, ``t = 0`` with tooth 0 at ``phi = 0``:
        ``(N / 2 pi) int_st^ex b(psi) exp(-i h N psi) dpsi`` (closed form), N/m. Times
        :func:`_helix_filter` they are the coefficients at any depth.
    mean_torque : ndarray, shape (n_depths,)
        Mean spindle torque, N m.
    peak : ndarray, shape (n_depths,)
        Largest resultant force in the (f, n) plane over a tooth period, N.
    """
    depths = np.asarray(depths, dtype=float)
    st, ex = engagement_angles(tool, cut)
    h = np.arange(n_harm + 1)
    nu = np.arange(-2, 3)[None, :] - tool.teeth * h[:, None]  # (H+1, 5)
    basis = (_exp_integrals(st, ex, nu) @ _BASIS_EXP.T) * tool.teeth / _TWO_PI  # (H+1, 6)
    fc = force_coefficients(coefficients, cut.feed_per_tooth_m)
    tc = torque_coefficients(coefficients, cut.feed_per_tooth_m, tool.diameter_m / 2.0)
    straight = np.abs(helix_lag_per_m(tool) * depths) < _STRAIGHT_LAG_RAD
    return ((basis @ fc.T).T, float((basis[0] @ tc).real) * depths,
            _peak_forces(tool, cut, fc, depths, straight))


def _helix_filter(tool: Tool, depths, n_harm: int) -> np.ndarray:
    """``int_0^a exp(-i h N kappa z) dz`` for h = 0..n_harm at each depth ``a``, (n_depths, n_harm + 1), m:
    the axial integral of a force whose immersion lags by ``kappa z`` at height ``z``."""
    depths = np.asarray(depths, dtype=float)
    kappa = helix_lag_per_m(tool)
    out = np.empty((depths.size, n_harm + 1), dtype=complex)
    out[:] = depths[:, None]
    helix = np.abs(kappa * depths) >= _STRAIGHT_LAG_RAD
    if helix.any():
        hh = np.arange(1, n_harm + 1)[None, :] * tool.teeth
        out[helix, 1:] = (1.0 - np.exp(-1j * hh * kappa * depths[helix, None])) / (1j * hh * kappa)
    return out


#: As ``stability.oriented._STRAIGHT_LAG_RAD``: a helix lag below this over the depth is straight.
_STRAIGHT_LAG_RAD = 1e-9


def _primitives(psi):
    """Primitives of the basis (1, sin, cos, sin^2, cos^2, sin cos), shape psi.shape + (6,)."""
    s2 = np.sin(2.0 * psi)
    return np.stack([psi, -np.cos(psi), np.sin(psi), psi / 2 - s2 / 4, psi / 2 + s2 / 4, -np.cos(2.0 * psi) / 4],
                    axis=-1)


def _engaged_primitive(u, st: float, ex: float):
    """``P(u) = int_0^u b(psi) g(psi) dpsi`` on the unwrapped angle, ``g`` the indicator of the
    window ``[st, ex]`` repeated every 2 pi (as ``stability.oriented``), shape u.shape + (6,)."""
    k = np.floor(u / _TWO_PI)
    v = u - _TWO_PI * k
    f_st = _primitives(np.array(st))
    total = _primitives(np.array(ex)) - f_st
    return k[..., None] * total + _primitives(np.clip(v, st, ex)) - f_st


def _peak_forces(tool: Tool, cut: Cut, fc: np.ndarray, depths: np.ndarray, straight: np.ndarray) -> np.ndarray:
    """Peak resultant force in the (f, n) plane at each depth, N, on the angle set of
    ``stability.forced`` (4096 angles over a tooth pitch plus both sides of every angle where a
    tooth enters or leaves the cut at the tip or at the top of the depth). The force at tip angle
    ``phi`` is ``sum_j (P(phi_j) - P(phi_j - kappa a)) / kappa`` with straight flutes ``a`` times the
    engaged sum (:func:`stability.oriented.engaged_axial_integral`, vectorised over depth here)."""
    pitch = _TWO_PI / tool.teeth
    st, ex = engagement_angles(tool, cut)
    kappa = helix_lag_per_m(tool)
    grid = pitch * np.arange(_PEAK_GRID) / _PEAK_GRID
    tooth = pitch * np.arange(tool.teeth)
    eps = 1e-9 * pitch
    out = np.empty(depths.size)

    def resultant(force):
        return np.max(np.hypot(force[..., 0], force[..., 1]), axis=-1)

    if straight.any():  # a times the force per unit depth: the straight-flute angle set, once
        crit = np.mod(np.array([st, ex, st, ex])[:, None] - tooth, pitch).ravel()
        phi = np.concatenate([grid, crit - eps, crit, crit + eps])
        unit = engaged_axial_integral(tool, cut, phi, 1.0) @ fc.T  # = engaged_sum for zero lag
        out[straight] = resultant(depths[straight, None, None] * unit[None, :, :])
    idx = np.flatnonzero(~straight)
    if idx.size:
        ang = grid[:, None] + tooth[None, :]  # (grid, teeth)
        p_tip = _engaged_primitive(ang, st, ex)
        idx = idx[np.argsort(depths[idx], kind="stable")]
        chunk = max(1, 4_000_000 // (grid.size * tool.teeth * 6))
        for j0 in range(0, idx.size, chunk):
            sel = idx[j0:j0 + chunk]
            lag = kappa * depths[sel]
            # only angles at which some tooth cuts somewhere on the depth (elsewhere the force is 0)
            cuts = np.any(np.mod(ang - st, _TWO_PI) <= ex - st + lag.max(), axis=1)
            top = _engaged_primitive(ang[None, cuts, :] - lag[:, None, None], st, ex)
            e = np.sum(p_tip[None, cuts] - top, axis=2) / kappa  # (n, angles, 6)
            out[sel] = resultant(e @ fc.T) if cuts.any() else 0.0
        # both sides of the entry and exit angles at the tip and at the top of the depth
        lag = kappa * depths[idx]
        ends = np.stack([np.full(idx.size, st), np.full(idx.size, ex), st + lag, ex + lag], axis=1)
        crit = np.mod(ends[:, :, None] - tooth[None, None, :], pitch).reshape(idx.size, -1)
        phi = np.concatenate([crit - eps, crit, crit + eps], axis=1)[:, :, None] + tooth  # (n, 12 N, teeth)
        e = np.sum(_engaged_primitive(phi, st, ex) - _engaged_primitive(phi - lag[:, None, None], st, ex),
                   axis=2) / kappa
        out[idx] = np.maximum(out[idx], resultant(e @ fc.T))
    return out


def _harmonic_sum(a, p):
    """``sum_h a_h p^h`` (h = 1..H) by Horner's rule: a (G, H), p (G, K); (G, K)."""
    total = np.zeros(p.shape, dtype=complex)
    for h in range(a.shape[1], 0, -1):
        total += a[:, h - 1, None]
        total *= p
    return total


def _harmonic_sums(a, p):
    """``sum_h h^k a_h p^h`` for k = 0, 1, 2 (h = 1..H): a (G, H), p (G, K); each (G, K)."""
    s0, s1, s2 = (np.zeros(p.shape, dtype=complex) for _ in range(3))
    pw = np.ones(p.shape, dtype=complex)
    for h in range(1, a.shape[1] + 1):
        pw *= p
        term = a[:, h - 1, None] * pw
        s0 += term
        s1 += h * term
        s2 += (h * h) * term
    return s0, s1, s2


def _wall_maxima(a, static, theta_1: float, depth, n_harm):
    """Largest ``|static + 2 Re sum_h a_h exp(i h theta_1 z)|`` over ``0 <= z <= depth`` per row
    and its height ``z``, m (module docstring). a (G, H) complex, static, depth, n_harm (G,)."""
    g = a.shape[0]
    best, at = np.empty(g), np.zeros(g)
    turns = n_harm * theta_1 * depth / _TWO_PI
    n = int(np.clip(np.ceil(_WALL_POINTS_PER_TURN * turns.max(initial=0.0)) + 1, 9, _WALL_MAX_POINTS))
    frac = np.linspace(0.0, 1.0, n)
    step = max(1, _WALL_BLOCK // n)
    for j0 in range(0, g, step):
        s = slice(j0, min(g, j0 + step))
        aa, st, d = a[s], static[s], depth[s]
        z = d[:, None] * frac[None, :]  # (G, n): the tip and the top included
        v = np.abs(st[:, None] + 2.0 * _harmonic_sum(aa, np.exp(1j * theta_1 * z)).real)
        pad = np.pad(v, ((0, 0), (1, 1)), constant_values=-np.inf)
        local = np.where((v >= pad[:, :-2]) & (v >= pad[:, 2:]), v, -np.inf)
        cand = np.argsort(local, axis=1)[:, -2:]  # the two largest local maxima (G, 2)
        rows = np.arange(cand.shape[0])[:, None]
        zc, vc = z[rows, cand], v[rows, cand]
        lo, hi = z[rows, np.maximum(cand - 1, 0)], z[rows, np.minimum(cand + 1, n - 1)]
        for _ in range(_WALL_NEWTON):  # on dSLE/dz = 0, within the neighbours; only towards a peak
            s0, s1, s2 = _harmonic_sums(aa, np.exp(1j * theta_1 * zc))
            f = st[:, None] + 2.0 * s0.real
            d1, d2 = -2.0 * theta_1 * s1.imag, -2.0 * theta_1**2 * s2.real
            peak = f * d2 < 0.0
            zc = np.where(peak, np.clip(zc - d1 / np.where(peak, d2, 1.0), lo, hi), zc)
        vn = np.abs(st[:, None] + 2.0 * _harmonic_sum(aa, np.exp(1j * theta_1 * zc)).real)
        better = vn > vc  # never below the sampled maximum
        vc, zc = np.where(better, vn, vc), np.where(better, zc, z[rows, cand])
        k = np.argmax(vc, axis=1)
        best[s], at[s] = vc[rows[:, 0], k], zc[rows[:, 0], k]
    return best, at


def surface_errors(tool, models, frames, unit_h, fg_model, fg_frame, fg_eng, fg_depth, fg_rpm, fg_harm, fg_sign):
    """Surface location error of every forced group (vectorised, chunked): at the tool tip,
    ``sign n . (G(0) F_0 + 2 Re sum_h G(h f_T) F_h exp(i h N phi_fin))`` (stability.forced), with
    ``n . u_r (u_r . F) = v_r[1] (v_r . c)`` for the mode directions ``v_r`` in the cut frame; and
    the largest ``|SLE|`` on the whole finished wall, with the height above the tip where it is
    (module docstring; straight flutes: the tip's, at 0).

    Returns
    -------
    tip : ndarray, shape (n_groups,)
        Signed, m (positive: material left on the wall).
    wall : ndarray, shape (n_groups,)
        ``max_z |SLE(z)|``, m (``>= |tip|``).
    height : ndarray, shape (n_groups,)
        Where on the wall that is, m above the tip.
    """
    teeth = tool.teeth
    theta_1 = teeth * helix_lag_per_m(tool)
    out = np.empty(fg_model.size)
    wall, height = np.empty(fg_model.size), np.zeros(fg_model.size)
    n_modes = models.fn.shape[1]
    h_max = int(fg_harm.max())
    chunk = max(1, 2_000_000 // (h_max * n_modes + 1))
    h = np.arange(1, h_max + 1)
    for j0 in range(0, fg_model.size, chunk):
        s = slice(j0, min(fg_model.size, j0 + chunk))
        mid, rot = fg_model[s], frames[fg_frame[s]]
        c = unit_h[fg_eng[s]] * _helix_filter(tool, fg_depth[s], h_max)[:, None, :]  # (G, 3, H+1), cut frame
        v = np.einsum("gij,gmj->gmi", rot, models.dirs[mid])  # (G, m, 3) cut frame
        res_n = np.einsum("gp,gpq,gkq->gk", rot[:, 1], models.res[mid], rot)  # n . Res R^T  (G, 3)
        proj = np.einsum("gmi,gih->gmh", v, c)  # v_r . c_h   (G, m, H+1)
        static = np.sum(v[:, :, 1] * proj[:, :, 0].real / models.stiff[mid], axis=1) + np.einsum(
            "gk,gk->g", res_n, c[:, :, 0].real)
        f_h = (teeth * fg_rpm[s] / 60.0)[:, None] * h[None, :]  # (G, H)
        rho = f_h[:, None, :] / models.fn[mid][:, :, None]
        modal = 1.0 / (models.stiff[mid][:, :, None] * (1.0 - rho**2 + 2j * models.zeta[mid][:, :, None] * rho))
        x_h = np.sum(v[:, :, 1, None] * proj[:, :, 1:] * modal, axis=1) + np.einsum("gk,gkh->gh", res_n, c[:, :, 1:])
        phase = np.where(fg_sign[s][:, None] > 0, (-1.0) ** (h[None, :] * teeth), 1.0)  # exp(i h N phi_fin)
        keep = h[None, :] <= fg_harm[s][:, None]
        out[s] = fg_sign[s] * (static + 2.0 * np.sum(np.where(keep, (x_h * phase).real, 0.0), axis=1))
        wall[s] = np.abs(out[s])
        helix = np.flatnonzero(np.abs(theta_1 / teeth * fg_depth[s]) >= _STRAIGHT_LAG_RAD)
        if helix.size:  # straight flutes finish every height at the tip's instant
            w, z = _wall_maxima(np.where(keep, x_h * phase, 0.0)[helix], static[helix], theta_1,
                                fg_depth[s][helix], fg_harm[s][helix])
            wall[s][helix], height[s][helix] = np.maximum(w, wall[s][helix]), z
    return out, wall, height
