"""The cut's view of the structure: oriented receptance and directional factors.

Two things connect a 3-D tool-tip model to the 2-D regenerative chip of one cut (formats.md):

* the **oriented receptance**: the machine-frame receptance rotated into the cutting frame
  ``(f, n, a)``; the chip thickness sees the displacement along ``f`` and ``n`` only, but all three
  force components act, so the ``(f, n)`` rows and all three columns are kept (an oblique robot mode
  couples feed and normal directions, and a non-zero axial coefficient feeds back through the
  ``f-a``/``n-a`` cross receptance: mode-coupling chatter, Pan et al. 2006);
* the **directional factors**: how a dynamic chip ``(q(t) - q(t - T)) . (sin phi f + cos phi n)``
  turns into a force on the tool, per unit axial depth.

Convention (formats.md). A tooth at immersion ``phi`` sits at ``sin(phi) f + cos(phi) n`` and moves
from ``n`` towards ``f``. Per unit chip width, the forces on the tool are ``F_f = -Ft cos(phi) -
Fr sin(phi)``, ``F_n = Ft sin(phi) - Fr cos(phi)``, ``F_a = +Fa`` with ``Ft = Ktc h``, ``Fr = Krc h``,
``Fa = Kac h``. The dynamic chip is ``h = r(phi) . dq`` with ``r = (sin phi, cos phi)``, so the
dynamic force is ``dF = A(phi) dq`` with the (3, 2) matrix (rows ``f, n, a``, columns ``dq_f, dq_n``)::

    A = [[-Kt s c - Kr s^2,   -Kt c^2 - Kr s c],
         [ Kt s^2 - Kr s c,    Kt s c - Kr c^2],
         [ Ka s,               Ka c           ]]      s = sin(phi), c = cos(phi)

With ``f -> x`` and ``n -> y`` this is exactly Altintas's convention, so the mean of ``A`` over a
tooth period is ``Kt N / (4 pi) [alpha]`` with the ``alpha`` of Altintas & Budak (CIRP Annals
44(1), 1995) (checked in ``tests/test_oriented.py``).

Helix: the immersion at height ``z`` lags the tip by ``kappa z`` with ``kappa = 2 tan(helix) / D``.
Integrals over the axial depth are done exactly here (the limit of infinitely many axial slices)
from closed-form primitives of the trigonometric integrands, and so are averages over a time step;
every time-varying quantity of this package is built from the one engaged-integral machinery below.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from oma._arrays import readonly
from oma.cutting import CuttingCoefficients, Cut, Tool, engagement_angles

__all__ = [
    "cut_receptance",
    "oriented_receptance",
    "helix_lag_per_m",
    "dynamic_coefficients",
    "damping_coefficients",
    "force_coefficients",
    "torque_coefficients",
    "average_directional_matrix",
    "directional_matrix",
    "directional_matrix_step_mean",
    "engaged_sum",
    "engaged_axial_integral",
    "engaged_axial_step_mean",
    "engaged_in_step",
]

TWO_PI = 2.0 * np.pi


#: A read-only copy that keeps its dtype (complex harmonics and eigenvalues, integer lobe numbers,
#: bool masks): the arrays of this package's frozen results.
_readonly = partial(readonly, dtype=None)


# Basis of the integrands, in this order: 1, sin, cos, sin^2, cos^2, sin*cos.
N_BASIS = 6


# ------------------------------------------------------------------------------------ receptance
def cut_receptance(structure, cut: Cut, freq_hz) -> np.ndarray:
    """Receptance in the cutting frame ``(f, n, a)``, shape (3, 3, n_freq), m/N.

    ``G_cut = R G R^T`` with ``R = cut.frame`` (rows ``f, n, a`` in machine coordinates).

    Parameters
    ----------
    structure : ModalModel or FRFTable
        Anything with ``receptance(freq_hz) -> (3, 3, n)`` in the machine frame.
    cut : Cut
        Gives the feed and normal directions.
    freq_hz : array_like, shape (n_freq,)
        Frequencies, Hz.
    """
    g = np.asarray(structure.receptance(np.atleast_1d(np.asarray(freq_hz, dtype=float))))
    r = cut.frame
    return np.einsum("ip,pqk,jq->ijk", r, g, r)


def oriented_receptance(structure, cut: Cut, freq_hz) -> np.ndarray:
    """The oriented receptance: rows ``(f, n)``, columns ``(f, n, a)``, shape (2, 3, n_freq), m/N.

    Displacement in the plane of the chip per unit force along feed, normal and tool axis. The
    cross terms (``G_fn``, ``G_nf`` and the axial columns) are kept: an oblique mode couples them.
    """
    return cut_receptance(structure, cut, freq_hz)[:2]


def helix_lag_per_m(tool: Tool) -> float:
    """``kappa = 2 tan(helix) / D``: immersion lag per unit height above the tip, rad/m."""
    return 2.0 * float(np.tan(tool.helix_rad)) / float(tool.diameter_m)


# ------------------------------------------------------------------------- integrand coefficients
def dynamic_coefficients(coefficients: CuttingCoefficients) -> np.ndarray:
    """Basis coefficients of the dynamic directional matrix ``A(phi)``, shape (3, 2, 6), N/m^2.

    ``A(phi) = sum_k C[:, :, k] b_k(phi)`` with the basis ``(1, s, c, s^2, c^2, s c)``; rows are
    the force components ``f, n, a``, columns the displacement components ``f, n``.
    """
    kt, kr, ka = coefficients.Ktc_N_m2, coefficients.Krc_N_m2, coefficients.Kac_N_m2
    c = np.zeros((3, 2, N_BASIS))
    c[0, 0, 5], c[0, 0, 3] = -kt, -kr
    c[0, 1, 4], c[0, 1, 5] = -kt, -kr
    c[1, 0, 3], c[1, 0, 5] = kt, -kr
    c[1, 1, 5], c[1, 1, 4] = kt, -kr
    c[2, 0, 1] = ka
    c[2, 1, 2] = ka
    return c


def damping_coefficients() -> np.ndarray:
    """Basis coefficients of ``r r^T`` (rows ``f, n, a``, columns ``f, n``), shape (3, 2, 6).

    The process-damping force on the tool is ``-(C / V) r r^T v`` per unit height while the tooth
    is engaged, ``r = sin(phi) f + cos(phi) n`` (see :mod:`stability.sdm`).
    """
    c = np.zeros((3, 2, N_BASIS))
    c[0, 0, 3] = 1.0
    c[0, 1, 5] = c[1, 0, 5] = 1.0
    c[1, 1, 4] = 1.0
    return c


def force_coefficients(coefficients: CuttingCoefficients, feed_per_tooth_m: float) -> np.ndarray:
    """Basis coefficients of the nominal (rigid-tool) force per unit height, shape (3, 6), N/m.

    Chip ``h = fz sin(phi)``; ``F_f = -Ft c - Fr s``, ``F_n = Ft s - Fr c``, ``F_a = Fa`` with the
    linear-plus-edge model ``Ft = Ktc h + Kte`` etc. (formats.md).
    """
    k = coefficients
    fz = float(feed_per_tooth_m)
    c = np.zeros((3, N_BASIS))
    c[0, 5], c[0, 2], c[0, 3], c[0, 1] = -k.Ktc_N_m2 * fz, -k.Kte_N_m, -k.Krc_N_m2 * fz, -k.Kre_N_m
    c[1, 3], c[1, 1], c[1, 5], c[1, 2] = k.Ktc_N_m2 * fz, k.Kte_N_m, -k.Krc_N_m2 * fz, -k.Kre_N_m
    c[2, 1], c[2, 0] = k.Kac_N_m2 * fz, k.Kae_N_m
    return c


def torque_coefficients(coefficients: CuttingCoefficients, feed_per_tooth_m: float,
                        radius_m: float) -> np.ndarray:
    """Basis coefficients of the spindle torque per unit height ``R Ft``, shape (6,), N m/m."""
    c = np.zeros(N_BASIS)
    c[1] = radius_m * coefficients.Ktc_N_m2 * float(feed_per_tooth_m)
    c[0] = radius_m * coefficients.Kte_N_m
    return c


# ---------------------------------------------------------------------------- basis primitives
def _basis(psi):
    s, c = np.sin(psi), np.cos(psi)
    return np.stack([np.ones_like(psi), s, c, s * s, c * c, s * c], axis=-1)


def _primitive(psi):
    """``F_k(psi) = int b_k``, shape (..., 6)."""
    s2 = np.sin(2.0 * psi)
    return np.stack([psi, -np.cos(psi), np.sin(psi), psi / 2 - s2 / 4, psi / 2 + s2 / 4,
                     -np.cos(2.0 * psi) / 4], axis=-1)


def _primitive2(psi):
    """``F2_k(psi) = int F_k``, shape (..., 6)."""
    c2 = np.cos(2.0 * psi)
    q = psi * psi
    return np.stack([q / 2, -np.sin(psi), -np.cos(psi), q / 4 + c2 / 8, q / 4 - c2 / 8,
                     -np.sin(2.0 * psi) / 8], axis=-1)


class _Window:
    """Engagement window ``[st, ex]`` (0 <= st <= ex <= 2 pi) of one tooth, repeated every 2 pi.

    ``P(u) = int_{0}^{u} b(psi) g(psi) dpsi`` and ``Q(u) = int_0^u P`` on the unwrapped angle, in
    closed form: with ``u = 2 pi k + v``, ``0 <= v < 2 pi``::

        P(u) = k I + G(v),               G(v) = F(clip(v, st, ex)) - F(st)
        Q(u) = pi I k (k - 1) + k H(2 pi) + k I v + H(v)
        H(v) = F2(vc) - F2(st) - F(st) (vc - st) + I max(v - ex, 0),   vc = clip(v, st, ex)

    with ``I = F(ex) - F(st)``; ``dQ/du = P`` and ``dP/du = b g`` hold for every integer ``k``.
    """

    def __init__(self, st: float, ex: float):
        self.st, self.ex = float(st), float(ex)
        self.f_st = _primitive(np.array(self.st))
        self.f2_st = _primitive2(np.array(self.st))
        self.total = _primitive(np.array(self.ex)) - self.f_st
        self.h_2pi = self._h(np.array(TWO_PI))

    def _h(self, v):
        vc = np.clip(v, self.st, self.ex)
        return (_primitive2(vc) - self.f2_st - self.f_st * (vc - self.st)[..., None]
                + self.total * np.maximum(v - self.ex, 0.0)[..., None])

    def _split(self, u):
        u = np.asarray(u, dtype=float)
        k = np.floor(u / TWO_PI)
        return k, u - TWO_PI * k

    def overlaps(self, lo, hi):
        """Whether ``[lo, hi]`` (unwrapped, ``lo <= hi``) meets the window with positive length."""
        lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        k = np.ceil((hi - self.st) / TWO_PI) - 1.0  # last window starting strictly before hi
        return self.ex + TWO_PI * k > lo

    def indicator(self, u):
        _, v = self._split(u)
        return (v >= self.st) & (v <= self.ex)

    def P(self, u):
        k, v = self._split(u)
        g = _primitive(np.clip(v, self.st, self.ex)) - self.f_st
        return k[..., None] * self.total + g

    def Q(self, u):
        k, v = self._split(u)
        kk = k[..., None]
        return (np.pi * self.total * kk * (kk - 1.0) + kk * self.h_2pi + kk * self.total * v[..., None]
                + self._h(v))


def _tooth_angles(phi, teeth: int):
    """``phi_j = phi + 2 pi j / N`` for every tooth, shape phi.shape + (N,)."""
    return np.asarray(phi, dtype=float)[..., None] + TWO_PI * np.arange(teeth) / teeth


# Below this axial lag (rad) the helix is treated as straight: (P(phi) - P(phi - lag)) / kappa
# would lose digits to cancellation, and a lag this small changes the integrand by < 1e-9 relative.
_STRAIGHT_LAG_RAD = 1e-9


def engaged_sum(tool: Tool, cut: Cut, phi) -> np.ndarray:
    """``sum_j b(phi_j) g(phi_j)`` over the teeth at tip angle ``phi`` (tooth 0), shape (..., 6).

    ``g`` is 1 inside the engagement window of the cut (including its ends), 0 outside.
    """
    st, ex = engagement_angles(tool, cut)
    w = _Window(st, ex)
    ang = _tooth_angles(phi, tool.teeth)
    return np.sum(_basis(ang) * w.indicator(ang)[..., None], axis=-2)


def engaged_axial_integral(tool: Tool, cut: Cut, phi, axial_depth_m: float) -> np.ndarray:
    """``sum_j int_0^a b(phi_j - kappa z) g dz`` at tip angle ``phi``, shape (..., 6), m.

    Exact in ``z`` (infinitely many axial slices). For straight flutes it is ``a`` times
    :func:`engaged_sum`.
    """
    a = float(axial_depth_m)
    kappa = helix_lag_per_m(tool)
    if abs(kappa * a) < _STRAIGHT_LAG_RAD:
        return a * engaged_sum(tool, cut, phi)
    st, ex = engagement_angles(tool, cut)
    w = _Window(st, ex)
    ang = _tooth_angles(phi, tool.teeth)
    return np.sum(w.P(ang) - w.P(ang - kappa * a), axis=-2) / kappa


def engaged_in_step(tool: Tool, cut: Cut, phi_lo, phi_hi, axial_depth_m) -> np.ndarray:
    """Whether any tooth cuts anywhere on the depth while the tip turns over ``[phi_lo, phi_hi]``.

    Decided from the geometry (not from the size of an integral, which rounding leaves a few ulps
    off zero). ``axial_depth_m`` broadcasts with ``phi_lo``; the result has their common shape.
    """
    st, ex = engagement_angles(tool, cut)
    w = _Window(st, ex)
    lag = np.maximum(helix_lag_per_m(tool) * np.asarray(axial_depth_m, dtype=float), 0.0)[..., None]
    lo_j = _tooth_angles(phi_lo, tool.teeth) - lag
    hi_j = _tooth_angles(phi_hi, tool.teeth)
    return np.any(w.overlaps(lo_j, hi_j), axis=-1)


def engaged_axial_step_mean(tool: Tool, cut: Cut, phi_lo, phi_hi, axial_depth_m) -> np.ndarray:
    """Mean of :func:`engaged_axial_integral` over tip angles ``[phi_lo, phi_hi]``, shape (..., 6), m.

    Exact (closed-form double integral); the average over a time step at constant spindle speed.
    Exactly zero where :func:`engaged_in_step` is False. ``axial_depth_m`` may be an array that
    broadcasts with ``phi_lo`` (one depth per step mean).
    """
    a = np.asarray(axial_depth_m, dtype=float)
    lo = np.asarray(phi_lo, dtype=float)
    hi = np.asarray(phi_hi, dtype=float)
    lo, hi, a = np.broadcast_arrays(lo, hi, a)
    width = (hi - lo)[..., None]
    st, ex = engagement_angles(tool, cut)
    w = _Window(st, ex)
    lo_j, hi_j = _tooth_angles(lo, tool.teeth), _tooth_angles(hi, tool.teeth)
    inside = engaged_in_step(tool, cut, lo, hi, a)[..., None]
    straight = a[..., None] * np.sum(w.P(hi_j) - w.P(lo_j), axis=-2) / width
    kappa = helix_lag_per_m(tool)
    lag = kappa * a
    if np.all(np.abs(lag) < _STRAIGHT_LAG_RAD):
        return np.where(inside, straight, 0.0)
    lag_j = lag[..., None]
    q = w.Q(hi_j) - w.Q(lo_j) - w.Q(hi_j - lag_j) + w.Q(lo_j - lag_j)
    with np.errstate(divide="ignore", invalid="ignore"):
        helical = np.sum(q, axis=-2) / (kappa * width)
    mean = np.where((np.abs(lag) < _STRAIGHT_LAG_RAD)[..., None], straight, helical)
    return np.where(inside, mean, 0.0)


# ---------------------------------------------------------------------------- directional matrices
def average_directional_matrix(tool: Tool, cut: Cut, coefficients: CuttingCoefficients) -> np.ndarray:
    """Mean dynamic directional matrix per unit depth, shape (3, 2), N/m^2.

    ``B0 = (N / 2 pi) int_{phi_st}^{phi_ex} A(phi) dphi``: the mean over a tooth period of the force
    per unit depth and unit displacement difference (rows ``f, n, a``; columns ``f, n``). It does
    not depend on the helix. Equal to ``N Kt / (4 pi) [alpha]`` of Altintas & Budak (1995) with
    ``x = f``, ``y = n`` (and an axial row ``N Ka / (2 pi) [cos, sin]``-terms when ``Kac != 0``).
    """
    st, ex = engagement_angles(tool, cut)
    total = _Window(st, ex).total
    return tool.teeth / TWO_PI * dynamic_coefficients(coefficients) @ total


def directional_matrix(tool: Tool, cut: Cut, coefficients: CuttingCoefficients, phi,
                       *, axial_depth_m: float) -> np.ndarray:
    """Time-varying dynamic directional matrix of the whole cut, shape (..., 3, 2), N/m.

    ``K(phi) = sum_j int_0^a A(phi_j - kappa z) g dz``: the dynamic force on the tool per unit
    displacement difference ``q(t) - q(t - T)`` (in ``f, n``) when tooth 0's tip is at ``phi``.
    Its mean over a tooth period is ``a B0`` (:func:`average_directional_matrix`).
    """
    e = engaged_axial_integral(tool, cut, phi, axial_depth_m)
    return np.einsum("ijk,...k->...ij", dynamic_coefficients(coefficients), e)


def directional_matrix_step_mean(tool: Tool, cut: Cut, coefficients: CuttingCoefficients,
                                 phi_lo, phi_hi, *, axial_depth_m: float) -> np.ndarray:
    """Mean of :func:`directional_matrix` over ``[phi_lo, phi_hi]``, shape (..., 3, 2), N/m."""
    e = engaged_axial_step_mean(tool, cut, phi_lo, phi_hi, axial_depth_m)
    return np.einsum("ijk,...k->...ij", dynamic_coefficients(coefficients), e)
