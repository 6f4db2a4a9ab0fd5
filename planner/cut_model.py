"""The process model of the planner: surface error, peak force, mean torque and power of one cut.

Analytic in the decision variables ``(n, ap, fz)`` so that the NLP of :mod:`planner.optimize` can
use them (NumPy or CasADi).

* **Surface location error** (Schmitz & Mann, IJMTM 46, 2006), exact and analytic for a modal
  model: the force of a straight flute per unit depth has closed-form Fourier coefficients ``F_h``
  over the engagement window (affine in fz: cutting part times fz plus edge part); a helix delays
  the slice at height ``z`` by ``kappa z``, so the cut's harmonic is
  ``F_h (1 - exp(-i h N kappa ap)) / (i h N kappa)``; the receptance of each mode is rational in
  ``n``. At the tip: :meth:`CutModel.sle_parts`, :meth:`CutModel.sle_function`. On the whole
  finished wall (formats.md; :mod:`planner.wall`): the slice at height ``z`` reaches the finishing
  angle ``kappa z / Omega`` after the tip, so harmonic ``h`` of the displacement turns by
  ``exp(i h N kappa z)`` there (the profile of :func:`stability.forced.forced_response`). Hence
  ``SLE(z) = fz S_c(n, ap, z) + S_e(n, ap, z)`` with no interpolation in ``n``, ``ap`` or ``z``:
  :meth:`CutModel.wall_parts`, :meth:`CutModel.wall_function`, :meth:`CutModel.wall_profile`,
  :meth:`CutModel.wall_max` (the largest ``|SLE|``: the search of :func:`planner.wall.wall_maxima`).
* **Peak force** does not depend on speed, and at one depth it is convex in feed (the largest over
  the angle of ``|F_e + fz F_c|``): the largest feed ``B(ap)`` with the peak within the limit is
  exact per depth (:meth:`CutModel.feed_bound`), the smallest over the angles of the root of a
  quadratic in ``fz``. It is continuous in depth with kinks where the helix lag ``kappa ap``
  brings an entry or exit angle onto another (``kappa ap = m pitch`` or ``m pitch +- (exit -
  entry)``): once every angle of the engagement lies on the flute, the peak stops growing with
  depth. (The largest depth per feed would jump there, from a finite depth to none, which no
  smooth function of the feed follows.) The NLP's constraint ``ap fz <= q(ap) = ap B(ap)`` uses
  cubic B-splines of ``q`` (nearly linear in ``ap``), one per smooth piece between the kinks
  (:meth:`CutModel.force_area`).
* **Mean torque and power** are exact: the mean torque is linear in depth (every slice has the
  same mean) and affine in feed, ``tau = ap (tau_c fz + tau_e)``; power is ``2 pi n / 60`` times it.
"""

from __future__ import annotations

import logging
from functools import lru_cache

import casadi as ca
import numpy as np

from oma.cutting import engagement_angles
from stability.forced import default_harmonics
from stability.oriented import engaged_axial_integral, force_coefficients, helix_lag_per_m, torque_coefficients

from .wall import wall_maxima

__all__ = ["CutModel"]

log = logging.getLogger(__name__)

TWO_PI = 2.0 * np.pi

# Angles per tooth pitch of the peak search (as stability.forced).
_PEAK_GRID = 4096
# Relative accuracy of the splines of the peak-force feed bound, checked at their midpoints: far
# below PlanSettings.recheck_rtol, so that the planner's re-check rarely has to back off.
_FORCE_RTOL = 1e-5
# Most nodes of one smooth piece of the force bound (a kink not at a known depth stops there).
_FORCE_MAX_NODES = 257
# Complex values per block of the dense wall evaluations (heights x harmonics): 16 MB.
_CHUNK = 2**20


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


@lru_cache(maxsize=None)
def _harmonic_turns(n_harm: int) -> ca.Function:
    """``phi -> (cos(h phi), sin(h phi))`` for h = 1..n_harm (CasADi) by the Chebyshev recurrence
    ``c_{h+1} = 2 cos(phi) c_h - c_{h-1}``: one sine and one cosine, not ``n_harm`` of each
    (rounding grows like ``h`` ulps)."""
    phi = ca.SX.sym("phi")
    c1, s1 = ca.cos(phi), ca.sin(phi)
    cos_h, sin_h = [c1], [s1]
    prev_c, prev_s = ca.SX(1.0), ca.SX(0.0)
    for _ in range(n_harm - 1):
        nc, ns = 2.0 * c1 * cos_h[-1] - prev_c, 2.0 * c1 * sin_h[-1] - prev_s
        prev_c, prev_s = cos_h[-1], sin_h[-1]
        cos_h.append(nc)
        sin_h.append(ns)
    return ca.Function(f"turns_{n_harm}", [phi], [ca.vertcat(*cos_h), ca.vertcat(*sin_h)])


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
        self._phi_grid = (TWO_PI / self.teeth) * np.arange(_PEAK_GRID) / _PEAK_GRID

    def _wall_modes(self) -> list[int]:
        """The modes that move the tool along the wall's normal (the others leave no surface error)."""
        m, nvec = self.model, self.cut.normal_direction
        return [r for r in range(m.n_modes) if abs(float(nvec @ m.directions[r])) >= 1e-12]

    @property
    def wall_modes_hz(self) -> np.ndarray:
        """Natural frequencies of the modes that move the tool along the wall's normal, Hz."""
        return self.model.natural_frequency_hz[self._wall_modes()]

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
        modes = self._wall_modes()
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

    # ---- surface location error on the whole finished wall (exact, analytic) --------------------
    def _wall_amplitudes(self, n_harm: int, rpm, ap):
        """Static coefficient (2,), harmonic amplitudes at the tip (2, I, J, H) and the turn per unit
        height of each harmonic (H,), rad/m, of ``(S_c, S_e)``: rpm (I,), ap (I, J)."""
        c = self._sle_coeffs(n_harm)
        rpm, ap = np.asarray(rpm, dtype=float), np.asarray(ap, dtype=float)
        rho = c["h"][None, None, :] * (self.teeth * rpm / 60.0)[:, None, None] / c["fn"][None, :, None]
        inv_d = 1.0 / (1.0 - rho**2 + 2j * c["zeta"][None, :, None] * rho)  # (I, R, H)
        acc = c["beta"][:, None, :] + np.einsum("prh,irh->pih", c["alpha"], inv_d)  # (2, I, H)
        theta = c["theta"]
        hel = ((1.0 - np.exp(-1j * theta * ap[..., None])) / (1j * theta) if self.kappa
               else ap[..., None] + 0j * theta)  # (I, J, H)
        return c["static"], acc[:, :, None, :] * hel[None], theta

    def wall_parts(self, rpm, ap, frac, n_harm: int):
        """``(S_c, S_e)`` of the surface error at heights ``z = frac * ap`` on the finished wall, m
        (``SLE(z) = fz S_c + S_e``; ``S_c`` per unit feed); ``frac = 0`` is the tip, as
        :meth:`sle_parts`.

        The slice at height ``z`` reaches the finishing angle ``kappa z / Omega`` after the tip, so
        harmonic ``h`` of the tool's displacement turns by ``exp(i h N kappa z)`` there (the profile
        of :func:`stability.forced.forced_response`); the sum over the harmonics by Horner's rule.

        Parameters
        ----------
        rpm : ndarray, shape (I,)
        ap : ndarray, shape (I, J)
            Depths at each speed, m.
        frac : ndarray, shape (Z,)
            Heights as fractions of the depth, in [0, 1].
        n_harm : int
            Harmonics of the tooth-passing frequency summed.

        Returns
        -------
        S_c, S_e : ndarray, shape (I, J, Z)
        """
        static, amp, theta = self._wall_amplitudes(n_harm, rpm, ap)
        ap = np.asarray(ap, dtype=float)
        turn = np.exp(1j * theta[0] * np.asarray(frac, dtype=float) * ap[..., None])  # (I, J, Z): harmonic 1
        total = np.zeros((2,) + turn.shape, dtype=complex)
        amp = np.ascontiguousarray(np.moveaxis(amp, -1, 0))[..., None]  # (H, 2, I, J, 1)
        for h in range(n_harm - 1, -1, -1):  # sum_h amp_h turn^h, in place
            total += amp[h]
            total *= turn
        out = static[:, None, None, None] * ap[None, ..., None] + 2.0 * total.real
        return out[0], out[1]

    def wall_profile(self, x, n_harm: int):
        """The SLE along the wall at one cut ``x = (rpm, ap, fz)``, m, as a vectorised function of
        the height fraction (the sums of :meth:`wall_parts`, chunked)."""
        rpm, ap, fz = (float(v) for v in x)
        static, amp, theta = self._wall_amplitudes(n_harm, [rpm], [[ap]])
        amp = fz * amp[0, 0, 0] + amp[1, 0, 0]  # (H,)
        base = (fz * static[0] + static[1]) * ap
        step = max(1, _CHUNK // n_harm)

        def fn(frac):
            z = np.atleast_1d(frac) * ap
            return base + 2.0 * np.concatenate([np.real(np.exp(1j * np.multiply.outer(z[i:i + step], theta)) @ amp)
                                                for i in range(0, z.size, step)])

        return fn

    def wall_max(self, x, n_harm: int) -> tuple[float, float]:
        """Largest ``|SLE|`` on the wall at one cut ``x = (rpm, ap, fz)``, m, and its height as a
        fraction of the depth: :func:`planner.wall.wall_maxima` (the search of ``check`` and
        ``predict``) on the sums of :meth:`wall_profile`."""
        rpm, ap, fz = (float(v) for v in x)
        static, amp, theta = self._wall_amplitudes(n_harm, [rpm], [[ap]])
        value, height = wall_maxima((fz * amp[0, 0, 0] + amp[1, 0, 0])[None, :], [(fz * static[0] + static[1]) * ap],
                                    float(theta[0]) if theta.size else 0.0, [ap])
        return abs(float(value[0])), float(height[0]) / ap

    def wall_function(self, n_harm: int, slots: int) -> ca.Function:
        """``(rpm, ap, frac[slots]) -> (S_c, S_e)`` at heights ``frac * ap`` (CasADi, the sums of
        :meth:`wall_parts`), m."""
        c = self._sle_coeffs(n_harm)
        rpm, ap, frac = ca.SX.sym("rpm"), ca.SX.sym("ap"), ca.SX.sym("frac", slots)
        f_tooth = self.teeth * rpm / 60.0
        theta_1 = float(c["theta"][0]) if n_harm else 0.0
        if self.kappa:  # hel_h = (1 - exp(-i theta_h ap)) / (i theta_h)
            cos_a, sin_a = _harmonic_turns(n_harm)(theta_1 * ap)
            th = ca.DM(c["theta"])
            hel_re, hel_im = sin_a / th, -(1.0 - cos_a) / th
        else:
            hel_re, hel_im = ca.DM.ones(n_harm) * ap, ca.DM.zeros(n_harm) * ap
        inv_d = []  # 1 / D_r(h f_T) of each mode, shared by both parts
        for q in range(c["fn"].size):
            rho = ca.DM(c["h"] / c["fn"][q]) * f_tooth
            a_re, a_im = 1.0 - rho**2, 2.0 * c["zeta"][q] * rho
            den = a_re**2 + a_im**2
            inv_d.append((a_re / den, -a_im / den))
        amp = []
        for p in range(2):
            acc_re, acc_im = ca.DM(c["beta"][p].real) + 0 * rpm, ca.DM(c["beta"][p].imag) + 0 * rpm
            for q, (g_re, g_im) in enumerate(inv_d):
                al_re, al_im = ca.DM(c["alpha"][p, q].real), ca.DM(c["alpha"][p, q].imag)
                acc_re = acc_re + al_re * g_re - al_im * g_im
                acc_im = acc_im + al_re * g_im + al_im * g_re
            amp.append((acc_re * hel_re - acc_im * hel_im, acc_re * hel_im + acc_im * hel_re))
        rows = ([], [])
        for k in range(slots):
            cos_z, sin_z = _harmonic_turns(n_harm)(theta_1 * frac[k] * ap)
            for p, (amp_re, amp_im) in enumerate(amp):
                rows[p].append(c["static"][p] * ap + 2.0 * ca.sum1(amp_re * cos_z - amp_im * sin_z))
        return ca.Function(f"wall_{n_harm}_{slots}", [rpm, ap, frac], [ca.vertcat(*r) for r in rows],
                           ["rpm", "ap", "frac"], ["S_c", "S_e"])

    def harmonics_at(self, rpm_lo: float) -> int:
        return default_harmonics(self.model, self.tool, rpm_lo)

    # ---- peak force and torque (speed-independent) ----------------------------------------------
    def _peak_integrals(self, ap: float) -> np.ndarray:
        """The engaged axial integrals (:func:`stability.oriented.engaged_axial_integral`), (M, 6),
        at the angles of the peak search at depth ``ap``: a fine grid over a tooth pitch plus both
        sides of every angle where a tooth enters or leaves the cut at the tip or at the top."""
        pitch = TWO_PI / self.teeth
        lag = self.kappa * ap
        base = np.array([self.st, self.ex, self.st + lag, self.ex + lag])
        crit = np.mod(base[:, None] - pitch * np.arange(self.teeth), pitch).ravel()
        eps = 1e-9 * pitch
        phi = np.concatenate([self._phi_grid, crit - eps, crit, crit + eps])
        return engaged_axial_integral(self.tool, self.cut, phi, ap)

    def peaks(self, ap: float, fz) -> tuple[np.ndarray, np.ndarray]:
        """Largest in-plane force (N) and torque (N m) over a tooth period, at one depth and feeds
        ``fz`` (array): a fine angle grid plus both sides of every entry/exit angle. The peak
        torque is reported only; the spindle's torque limit bounds the mean (:meth:`mean_torque`)."""
        fz = np.atleast_1d(np.asarray(fz, dtype=float))
        e = self._peak_integrals(ap)  # (M, 6)
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

    def feed_bound(self, limit_N: float, depths) -> np.ndarray:
        """Largest feed per tooth, m, with the peak in-plane force within ``limit_N``, per depth (m).

        At one tip angle the force is ``F_e + fz F_c`` (edge plus cutting part), so ``|F|^2 =
        limit^2`` is a quadratic in ``fz``; the bound is the smallest of its positive roots over the
        angles of :meth:`peaks`. Zero where the edge force alone exceeds the limit at some angle.
        """
        out = np.empty(np.size(depths))
        for i, a in enumerate(np.atleast_1d(np.asarray(depths, dtype=float))):
            e = self._peak_integrals(a)
            fe, fc = e @ self.fc_e[:2].T, e @ self.fc_c[:2].T
            qa, qb, qc = np.sum(fc * fc, axis=1), 2.0 * np.sum(fe * fc, axis=1), np.sum(fe * fe, axis=1) - limit_N**2
            if np.any(qc > 0):
                out[i] = 0.0
                continue
            with np.errstate(divide="ignore"):  # -2 c / (b + sqrt(b^2 - 4 a c)): the root, without cancellation
                out[i] = np.min(-2.0 * qc / (qb + np.sqrt(qb * qb - 4.0 * qa * qc)))
        return out

    def force_area(self, limit_N: float, depth_range: tuple[float, float], *, nodes: int,
                   feed_floor_m: float) -> ca.Function:
        """``q(ap) = ap B(ap)``, m^2 (CasADi): the largest chip area ``ap fz`` with the peak force
        within ``limit_N`` (:meth:`feed_bound`), cubic B-splines between the kinks of ``B``.

        Each piece starts with ``nodes`` nodes, doubled until it reproduces ``B`` at the midpoints
        to ``_FORCE_RTOL`` relative to the larger of ``ap B`` and ``ap feed_floor_m`` (the smallest
        feed planned). The splines reach 5 % beyond ``depth_range`` (m): a B-spline is zero
        outside its grid, and IPOPT may step past a bound by its bound relaxation (~1e-8).
        """
        lo, hi = depth_range
        pad = 0.05 * (hi - lo if hi > lo else lo)
        a0, a1 = max(lo - pad, 0.5 * lo), hi + pad
        kinks = np.array([])
        if self.kappa:
            pitch, width = TWO_PI / self.teeth, self.ex - self.st
            m = np.arange(int(self.kappa * a1 / pitch) + 2)
            kinks = np.concatenate([m * pitch, m * pitch + width, m * pitch - width]) / self.kappa
            kinks = np.unique(kinks[(kinks > a0 * (1 + 1e-6)) & (kinks < a1 * (1 - 1e-6))])
        edges = np.concatenate([[a0], kinks, [a1]])
        x = ca.MX.sym("ap")
        expr, worst = None, 0.0
        for e0, e1 in zip(edges[::-1][1:], edges[::-1][:-1]):  # from the deepest piece down
            grid = np.linspace(e0, e1, nodes)
            area = grid * self.feed_bound(limit_N, grid)
            while True:
                fn = ca.interpolant("force_area", "bspline", [grid], area)
                mid = 0.5 * (grid[1:] + grid[:-1])
                want = mid * self.feed_bound(limit_N, mid)
                got = np.asarray(fn.map(mid.size)(mid[None, :])).ravel()
                err = float(np.max(np.abs(got - want) / np.maximum(want, mid * feed_floor_m)))
                if err <= _FORCE_RTOL or grid.size >= _FORCE_MAX_NODES:
                    break
                grid, area = (np.insert(v, np.arange(1, v.size), w) for v, w in ((grid, mid), (area, want)))
            worst = max(worst, err)
            expr = fn(x) if expr is None else ca.if_else(x < e1, fn(x), expr)
        log.info("peak-force bound: %d pieces, spline error %.1e at the midpoints", edges.size - 1, worst)
        return ca.Function("force_area", [x], [expr])
