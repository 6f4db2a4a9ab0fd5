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
  ``|SLE|`` over ``0 <= z <= depth``: :func:`planner.wall.wall_maxima`, vectorised over the groups
  (the search ``plan`` and ``predict`` use too).
"""

from __future__ import annotations

import math

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Tool, engagement_angles
from stability.oriented import engaged_axial_integral, force_coefficients, helix_lag_per_m, torque_coefficients

from .wall import wall_maxima

__all__ = ["force_shapes", "surface_errors"]

_TWO_PI = 2.0 * math.pi
#: Angles of the peak-force search, as in ``stability.forced`` (grid over a tooth pitch).
_PEAK_GRID = 4096


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
        amp = fg_sign[s][:, None] * np.where(keep, x_h * phase, 0.0)  # signed as the SLE
        out[s] = fg_sign[s] * static + 2.0 * np.sum(amp.real, axis=1)
        # straight flutes finish every height at the tip's instant (wall_maxima: the tip's, at 0)
        value, height[s] = wall_maxima(amp, fg_sign[s] * static, theta_1, fg_depth[s], fg_harm[s])
        wall[s] = np.abs(value)
    return out, wall, height
