"""The process model of the planner: surface error, peak force, mean torque and power of one cut.

Analytic in the decision variables ``(n, ap, fz)`` so that the NLP of :mod:`planner.optimize` can
use them (NumPy or CasADi). Surface location error (Schmitz & Mann, IJMTM 46, 2006), exact for a
modal model: the force of a straight flute per unit depth has closed-form Fourier coefficients over
the engagement window (affine in fz), a helix delays the slice at height ``z`` by ``kappa z``, and
the receptance of each mode is rational in the harmonic's frequency.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from oma.cutting import engagement_angles
from stability.forced import default_harmonics
from stability.oriented import engaged_axial_integral, force_coefficients, helix_lag_per_m, torque_coefficients

__all__ = ["CutModel"]

TWO_PI = 2.0 * np.pi


def _window_harmonics(st: float, ex: float, teeth: int, n_harm: int) -> np.ndarray:
    """``W[h, k] = (N / 2 pi) int_st^ex b_k(psi) exp(-i h N psi) dpsi``, shape (n_harm + 1, 6).

    The Fourier coefficients, over one tooth period, of the engaged basis ``(1, s, c, s^2, c^2, s c)``
    summed over the teeth (straight flute, per unit depth), in closed form from
    ``b_k = sum_m w_km exp(i m psi)``.
    """
    w = {0: {0: 1.0}, 1: {1: -0.5j, -1: 0.5j}, 2: {1: 0.5, -1: 0.5},
         3: {0: 0.5, 2: -0.25, -2: -0.25}, 4: {0: 0.5, 2: 0.25, -2: 0.25}, 5: {2: -0.25j, -2: 0.25j}}
    h = np.arange(n_harm + 1)
    out = np.zeros((n_harm + 1, 6), dtype=complex)
    for k, terms in w.items():
        for m, wk in terms.items():
            mu = (m - h * teeth).astype(float)
            safe = np.where(mu == 0, 1.0, mu)
            integral = np.where(mu == 0, ex - st,
                                (np.exp(1j * safe * ex) - np.exp(1j * safe * st)) / (1j * safe))
            out[:, k] += wk * integral
    return teeth / TWO_PI * out


class CutModel:
    """Surface error, peak force, mean torque and power of one cut as functions of ``(n, ap, fz)``."""

    def __init__(self, model, tool, cut, coef):
        self.model, self.tool, self.cut, self.coef = model, tool, cut, coef
        self.teeth = int(tool.teeth)
        self.kappa = helix_lag_per_m(tool)
        self.st, self.ex = engagement_angles(tool, cut)
        self.phi_fin, self.sign = (np.pi, 1.0) if cut.milling == "down" else (0.0, -1.0)
        self.fc_e = force_coefficients(coef, 0.0)  # (3, 6) cut frame, edge part
        self.fc_c = force_coefficients(coef, 1.0) - self.fc_e  # per unit feed
        radius = tool.diameter_m / 2.0
        self.tc_e = torque_coefficients(coef, 0.0, radius)
        self.tc_c = torque_coefficients(coef, 1.0, radius) - self.tc_e
        w0 = _window_harmonics(self.st, self.ex, self.teeth, 0)[0].real
        self.tau_c, self.tau_e = float(self.tc_c @ w0), float(self.tc_e @ w0)  # mean torque / depth
        self._sle_cache: dict[int, ca.Function] = {}
        self._coeff_cache: dict[int, dict] = {}
        self._phi_grid = (TWO_PI / self.teeth) * np.arange(4096) / 4096

    # ---- mean torque and power (exact) -----------------------------------------------------------
    def mean_torque(self, ap, fz):
        """Mean cutting torque over a revolution, N m (NumPy or CasADi): what a spindle's continuous
        torque rating bounds (formats.md, limits). Linear in depth (every slice has the same mean)
        and affine in feed; independent of speed."""
        return ap * (self.tau_c * fz + self.tau_e)

    def power(self, rpm, ap, fz):
        """Mean spindle power, W (NumPy or CasADi): the mean torque times the spindle's speed."""
        return TWO_PI * rpm / 60.0 * self.mean_torque(ap, fz)

    # ---- surface location error (exact, analytic) ------------------------------------------------
    def _sle_coeffs(self, n_harm: int):
        """Coefficients of ``S_c`` (per unit feed) and ``S_e``, cached per harmonic count.

        ``S = s0 ap + 2 Re sum_h [beta_h + sum_r alpha_hr / D_r(h f_T)] hel_h(ap)`` with the wall
        rotation ``exp(i h N phi_fin)`` folded into ``alpha`` and ``beta``, ``D_r = 1 - rho^2 +
        2 i zeta_r rho`` and ``hel_h = int_0^ap exp(-i theta_h z) dz``.
        """
        if n_harm in self._coeff_cache:
            return self._coeff_cache[n_harm]
        m, n_t = self.model, self.teeth
        nvec = self.cut.normal_direction
        wh = _window_harmonics(self.st, self.ex, n_t, n_harm)  # (H+1, 6)
        h = np.arange(1, n_harm + 1)
        rot = np.exp(1j * h * n_t * self.phi_fin)
        modes = [r for r in range(m.n_modes) if abs(float(nvec @ m.directions[r])) >= 1e-12]
        static, beta, alpha = np.zeros(2), np.zeros((2, n_harm), complex), np.zeros((2, len(modes), n_harm), complex)
        for p, fc in enumerate((self.fc_c, self.fc_e)):
            force_h = self.cut.frame.T @ (fc @ wh.T)  # (3, H+1) machine frame, per unit depth
            static[p] = self.sign * float(nvec @ m.static_compliance_m_N @ force_h[:, 0].real)
            beta[p] = self.sign * (nvec @ m.residual_compliance_m_N @ force_h[:, 1:]) * rot
            for q, r in enumerate(modes):
                proj = self.sign * float(nvec @ m.directions[r])
                alpha[p, q] = proj * (m.directions[r] @ force_h[:, 1:]) * rot / m.stiffness_N_m[r]
        out = dict(h=h, theta=h * n_t * self.kappa, static=static, beta=beta, alpha=alpha,
                   fn=m.natural_frequency_hz[modes], zeta=m.damping_ratio[modes])
        self._coeff_cache[n_harm] = out
        return out

    def sle_parts(self, rpm, ap, n_harm: int):
        """``(S_c, S_e)`` at arrays ``rpm``, ``ap`` of one shape (NumPy; the same sums as
        :meth:`sle_function`), m (``S_c`` per unit feed)."""
        c = self._sle_coeffs(n_harm)
        rpm, ap = np.broadcast_arrays(np.asarray(rpm, dtype=float), np.asarray(ap, dtype=float))
        shape = rpm.shape
        rpm, ap = rpm.ravel()[:, None], ap.ravel()[:, None]
        theta = c["theta"][None, :]
        hel = ap + 0j if not self.kappa else (1.0 - np.exp(-1j * theta * ap)) / (1j * theta)
        rho = c["h"][None, None, :] * (self.teeth * rpm / 60.0)[:, None, :] / c["fn"][None, :, None]
        inv_d = 1.0 / (1.0 - rho**2 + 2j * c["zeta"][None, :, None] * rho)  # (P, R, H)
        out = []
        for p in range(2):
            acc = c["beta"][p][None, :] + np.einsum("rh,prh->ph", c["alpha"][p], inv_d)
            out.append((c["static"][p] * ap[:, 0] + 2.0 * np.real(np.sum(acc * hel, axis=1))).reshape(shape))
        return out

    def sle_function(self, n_harm: int) -> ca.Function:
        """``(rpm, ap) -> (S_c, S_e)`` with ``SLE = fz S_c + S_e``, m (CasADi, for the NLP)."""
        if n_harm in self._sle_cache:
            return self._sle_cache[n_harm]
        c = self._sle_coeffs(n_harm)
        rpm, ap = ca.SX.sym("rpm"), ca.SX.sym("ap")
        f_tooth = self.teeth * rpm / 60.0
        if self.kappa:
            th = ca.DM(c["theta"])
            hel_re, hel_im = ca.sin(th * ap) / th, -(1.0 - ca.cos(th * ap)) / th
        else:
            hel_re, hel_im = ca.DM.ones(n_harm) * ap, ca.DM.zeros(n_harm) * ap
        out = []
        for p in range(2):
            acc_re, acc_im = ca.DM(c["beta"][p].real) + 0 * ap, ca.DM(c["beta"][p].imag) + 0 * ap
            for q in range(c["fn"].size):
                rho = ca.DM(c["h"] / c["fn"][q]) * f_tooth
                a_re, a_im = 1.0 - rho**2, 2.0 * c["zeta"][q] * rho
                den = a_re**2 + a_im**2
                g_re, g_im = a_re / den, -a_im / den  # 1 / D
                al_re, al_im = ca.DM(c["alpha"][p, q].real), ca.DM(c["alpha"][p, q].imag)
                acc_re = acc_re + al_re * g_re - al_im * g_im
                acc_im = acc_im + al_re * g_im + al_im * g_re
            out.append(c["static"][p] * ap + 2.0 * ca.sum1(acc_re * hel_re - acc_im * hel_im))
        fn = ca.Function(f"sle_{n_harm}", [rpm, ap], out, ["rpm", "ap"], ["S_c", "S_e"])
        self._sle_cache[n_harm] = fn
        return fn

    def harmonics_at(self, rpm_lo: float) -> int:
        return default_harmonics(self.model, self.tool, rpm_lo)

    # ---- peak force and torque (speed-independent) ----------------------------------------------
    def peaks(self, ap: float, fz) -> tuple[np.ndarray, np.ndarray]:
        """Largest in-plane force (N) and torque (N m) over a tooth period, at one depth and feeds
        ``fz`` (array): a fine angle grid plus both sides of every entry/exit angle. The peak
        torque is reported only; the spindle's torque limit bounds the mean (:meth:`mean_torque`)."""
        fz = np.atleast_1d(np.asarray(fz, dtype=float))
        pitch = TWO_PI / self.teeth
        lag = self.kappa * ap
        base = np.array([self.st, self.ex, self.st + lag, self.ex + lag])
        crit = np.mod(base[:, None] - pitch * np.arange(self.teeth), pitch).ravel()
        eps = 1e-9 * pitch
        phi = np.concatenate([self._phi_grid, crit - eps, crit, crit + eps])
        e = engaged_axial_integral(self.tool, self.cut, phi, ap)  # (M, 6)
        fe, fcut = e @ self.fc_e[:2].T, e @ self.fc_c[:2].T  # (M, 2): f, n components
        f = fe[None] + fz[:, None, None] * fcut[None]
        force = np.max(np.hypot(f[..., 0], f[..., 1]), axis=1)
        torque = np.max((e @ self.tc_e)[None] + fz[:, None] * (e @ self.tc_c)[None], axis=1)
        return force, torque

    def depth_boundary(self, which: int, limit: float, feeds, ap_lo: float, ap_hi: float) -> np.ndarray:
        """Largest depth (first crossing) with peak force (``which=0``) or peak torque (1) <= limit,
        per feed; ``2 ap_hi`` where the limit is not reached below that."""
        feeds = np.asarray(feeds, dtype=float)
        grid = np.geomspace(0.25 * ap_lo, 2.0 * ap_hi, 25)
        vals = np.array([self.peaks(a, feeds)[which] for a in grid])  # (n_ap, n_feed)
        out = np.full(feeds.size, 2.0 * ap_hi)
        for j in range(feeds.size):
            over = np.flatnonzero(vals[:, j] > limit)
            if over.size == 0:
                continue
            i = over[0]
            if i == 0:  # below the grid: the peak is close to proportional to the depth there
                out[j] = grid[0] * limit / vals[0, j]
                continue
            a, b = grid[i - 1], grid[i]
            ga, gb = vals[i - 1, j] - limit, vals[i, j] - limit
            for _ in range(40):  # Illinois regula falsi
                c = b - gb * (b - a) / (gb - ga)
                gc = self.peaks(c, feeds[j:j + 1])[which][0] - limit
                if gc > 0:
                    b, gb = c, gc
                    ga *= 0.5
                else:
                    a, ga = c, gc
                    gb *= 0.5
                if b - a <= 1e-10 * b or gc == 0:
                    break
            out[j] = a
        return out
