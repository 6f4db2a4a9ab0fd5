"""Numerics of the milling simulator: discretisation, the time-stepping kernel (numba), and the
signal processing of the sensor models.

Private module: :func:`stability.simulate.simulate` prepares every array (SI units, machine
frame) and calls :func:`run` once, or in chunks when a progress bar is shown. The kernel is a plain
loop over time steps, teeth and axial slices so that numba compiles it to tight machine code; the
same function runs uncompiled through ``run.py_func`` (used as the baseline of the benchmark).

Integration scheme (per mode ``r``, state ``[q_r, q_r']``)::

    x_{k+1} = Phi x_k + G0 p_k + G1 p_{k+1},     p = u_r . F      (force on the structure, N)

``Phi, G0, G1`` are the exact first-order-hold (force linear between steps) discretisation of the
mode (matrix exponential, prepared in Python), so the homogeneous motion of a mode has no
numerical damping or frequency error at any step. ``p_{k+1}`` needs the force at the new step,
which depends on the new displacement (regeneration, process damping); it is evaluated once from a
predictor that holds the force over the step (``x^p = Phi x_k + (G0 + G1) p_k``) and then kept: the
force reported at a step is exactly the force the structure received there. The difference between
the predicted and the corrected state is ``G1 (p_{k+1} - p_k)``, of order ``h^2`` in displacement.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import scipy.linalg
import scipy.signal
from scipy.interpolate import CubicSpline

__all__ = ["run", "cutting_force", "foh_matrices", "band_limited_noise", "resonance_filter", "resample",
           "quantise"]

_TWO_PI = 2.0 * math.pi


@numba.njit(cache=True)
def cutting_force(k, n_teeth, steps_per_rev, lag, dz, coef, fz, phi_st, phi_ex, drho, dq_f, dq_n,
                  v_f, v_n, pd_coef, nl_p, nl_href, frame, out):
    """Cutting force on the tool at step ``k``, machine frame, written into ``out`` (3,), N.

    Parameters
    ----------
    k : int
        Step index; tooth ``j`` sits at ``phi_j = 2 pi (k mod steps_per_rev) / steps_per_rev +
        2 pi j / n_teeth`` at the tool tip (exactly periodic in ``k``).
    lag : ndarray, shape (n_slices,)
        Helix lag of each slice at its mid-height, ``2 z tan(helix) / D``, rad.
    dz : float
        Slice height, m.
    coef : ndarray, shape (6,)
        ``Ktc, Krc, Kac`` (N/m^2), ``Kte, Kre, Kae`` (N/m).
    drho : ndarray, shape (n_teeth,)
        Runout chip increment of each tooth, m (zeros without runout).
    dq_f, dq_n : float
        Regenerative displacement ``q(t) - q(t - T)`` along ``f`` and ``n``, m (0 without
        regeneration).
    v_f, v_n : float
        Tool velocity along ``f`` and ``n``, m/s (used only when ``pd_coef != 0``).
    pd_coef : float
        Process-damping coefficient over cutting speed, ``C / V``, N s/m^2.
    nl_p, nl_href : float
        Size-effect exponent and reference chip, m (``nl_p = 0``: linear model).
    frame : ndarray, shape (3, 3)
        Rows ``f, n, a`` in the machine frame.
    """
    ff = 0.0
    fn = 0.0
    fa = 0.0
    base = _TWO_PI * (k % steps_per_rev) / steps_per_rev
    ktc, krc, kac, kte, kre, kae = coef[0], coef[1], coef[2], coef[3], coef[4], coef[5]
    for j in range(n_teeth):
        phi_j = base + _TWO_PI * j / n_teeth
        for s in range(lag.shape[0]):
            phi = (phi_j - lag[s]) % _TWO_PI
            if phi < phi_st or phi > phi_ex:
                continue
            sp = math.sin(phi)
            cp = math.cos(phi)
            h = fz * sp + drho[j] + sp * dq_f + cp * dq_n
            if h <= 0.0:
                continue
            scale = 1.0
            if nl_p != 0.0:
                scale = (h / nl_href) ** (-nl_p)
            dft = (ktc * scale * h + kte) * dz
            dfr = (krc * scale * h + kre) * dz
            dfa = (kac * scale * h + kae) * dz
            if pd_coef != 0.0:
                # flank rubbing: radial force along +r pushes the tool back when it moves into
                # the surface (v_r > 0); on the tool it is -C v_r / V dz along r.
                dfr += pd_coef * (sp * v_f + cp * v_n) * dz
            ff += -dft * cp - dfr * sp
            fn += dft * sp - dfr * cp
            fa += dfa
    for i in range(3):
        out[i] = ff * frame[0, i] + fn * frame[1, i] + fa * frame[2, i]


@numba.njit(cache=True)
def run(k0, k1, n_teeth, steps_per_tooth, lag, dz, coef, fz, phi_st, phi_ex, drho, regeneration,
        pd_coef, nl_p, nl_href, frame, directions, phi_mats, g0, g1, seg_len, residual, background,
        q, v, force, disp):
    """Advance the simulation from step ``k0`` to step ``k1`` (exclusive of ``k1``'s successor).

    On return ``force[k]`` and ``disp[k]`` are filled for ``k0 <= k <= k1`` and ``q, v`` hold the
    modal state at step ``k1``. With ``k0 == 0`` the state must be at rest and step 0 is
    initialised here.

    Parameters
    ----------
    directions : ndarray, shape (n_modes, 3)
        Unit mode directions ``u_r``.
    phi_mats : ndarray, shape (n_segments, n_modes, 2, 2)
        Transition matrices of each mode per time segment (more than one segment only with
        pose drift).
    g0, g1 : ndarray, shape (n_segments, n_modes, 2)
        First-order-hold input vectors of the modal force at the start and at the end of the
        step, ``1/m_r`` included: displacement (m/N) and velocity (m/(s N)) per newton.
    seg_len : int
        Steps per segment.
    residual : ndarray, shape (3, 3)
        Residual compliance, m/N. In the chip it acts with one step of lag (the force of the
        previous step), which breaks the algebraic loop it would otherwise close.
    background : ndarray, shape (n_steps + 1, 3)
        Background force on the structure at each step, N.
    q, v : ndarray, shape (n_modes,)
        Modal displacement (m) and velocity (m/s), updated in place.
    force, disp : ndarray, shape (n_steps + 1, 3)
        Output: total force on the structure (N) and tool-tip displacement (m).
    """
    n_modes = directions.shape[0]
    steps_per_rev = steps_per_tooth * n_teeth
    fvec = frame[0]
    nvec = frame[1]
    fc = np.zeros(3)
    d_pred = np.zeros(3)
    qp = np.zeros(n_modes)
    vp = np.zeros(n_modes)
    p_old = np.zeros(n_modes)
    p_new = np.zeros(n_modes)

    if k0 == 0:
        # at rest: zero displacement now and in the (empty) delay line
        cutting_force(0, n_teeth, steps_per_rev, lag, dz, coef, fz, phi_st, phi_ex, drho, 0.0, 0.0,
                      0.0, 0.0, pd_coef, nl_p, nl_href, frame, fc)
        for i in range(3):
            force[0, i] = fc[i] + background[0, i]
        for i in range(3):
            acc = 0.0
            for m in range(3):
                acc += residual[i, m] * force[0, m]
            disp[0, i] = acc

    for k in range(k0, k1):
        seg = k // seg_len
        # modal force of the current step
        for r in range(n_modes):
            acc = 0.0
            for i in range(3):
                acc += directions[r, i] * force[k, i]
            p_old[r] = acc
        # predictor: force held over the step
        for r in range(n_modes):
            a00 = phi_mats[seg, r, 0, 0]
            a01 = phi_mats[seg, r, 0, 1]
            a10 = phi_mats[seg, r, 1, 0]
            a11 = phi_mats[seg, r, 1, 1]
            qp[r] = a00 * q[r] + a01 * v[r] + (g0[seg, r, 0] + g1[seg, r, 0]) * p_old[r]
            vp[r] = a10 * q[r] + a11 * v[r] + (g0[seg, r, 1] + g1[seg, r, 1]) * p_old[r]
        for i in range(3):
            acc = 0.0
            for r in range(n_modes):
                acc += directions[r, i] * qp[r]
            for m in range(3):
                acc += residual[i, m] * force[k, m]
            d_pred[i] = acc
        # regenerative and velocity terms at the new step
        dq_f = 0.0
        dq_n = 0.0
        if regeneration:
            kd = k + 1 - steps_per_tooth
            for i in range(3):
                dd = d_pred[i]
                if kd >= 0:
                    dd -= disp[kd, i]
                dq_f += dd * fvec[i]
                dq_n += dd * nvec[i]
        v_f = 0.0
        v_n = 0.0
        if pd_coef != 0.0:
            for i in range(3):
                acc = 0.0
                for r in range(n_modes):
                    acc += directions[r, i] * vp[r]
                v_f += acc * fvec[i]
                v_n += acc * nvec[i]
        cutting_force(k + 1, n_teeth, steps_per_rev, lag, dz, coef, fz, phi_st, phi_ex, drho, dq_f,
                      dq_n, v_f, v_n, pd_coef, nl_p, nl_href, frame, fc)
        for i in range(3):
            force[k + 1, i] = fc[i] + background[k + 1, i]
        # corrector: force linear over the step
        for r in range(n_modes):
            acc = 0.0
            for i in range(3):
                acc += directions[r, i] * force[k + 1, i]
            p_new[r] = acc
        for r in range(n_modes):
            a00 = phi_mats[seg, r, 0, 0]
            a01 = phi_mats[seg, r, 0, 1]
            a10 = phi_mats[seg, r, 1, 0]
            a11 = phi_mats[seg, r, 1, 1]
            qn = a00 * q[r] + a01 * v[r] + g0[seg, r, 0] * p_old[r] + g1[seg, r, 0] * p_new[r]
            vn = a10 * q[r] + a11 * v[r] + g0[seg, r, 1] * p_old[r] + g1[seg, r, 1] * p_new[r]
            q[r] = qn
            v[r] = vn
        for i in range(3):
            acc = 0.0
            for r in range(n_modes):
                acc += directions[r, i] * q[r]
            for m in range(3):
                acc += residual[i, m] * force[k + 1, m]
            disp[k + 1, i] = acc


# --------------------------------------------------------------- preparation and sensors
def foh_matrices(omega: np.ndarray, zeta: np.ndarray, mass: np.ndarray, step_s: float):
    """Exact first-order-hold discretisation of single-DOF modes.

    For ``x = [q, q']``, ``x' = A x + b p`` with ``A = [[0, 1], [-w^2, -2 zeta w]]``, ``b = [0,
    1/m]`` and ``p`` linear over the step, ``x_{k+1} = Phi x_k + g0 p_k + g1 p_{k+1}`` from the
    exponential of the augmented matrix ``[[A, b, 0], [0, 0, 1/h], [0, 0, 0]] h`` (the triangle-hold
    equivalent of Franklin, Powell & Workman, Digital Control of Dynamic Systems, 3rd ed., ch. 6).

    Parameters
    ----------
    omega : ndarray, shape (..., n_modes)
        Natural frequencies, rad/s.
    zeta, mass : ndarray, shape (n_modes,)
        Damping ratios and modal masses, kg.
    step_s : float

    Returns
    -------
    phi : ndarray, shape (..., n_modes, 2, 2)
    g0, g1 : ndarray, shape (..., n_modes, 2)
    """
    omega = np.asarray(omega, dtype=float)
    aug = np.zeros(omega.shape + (4, 4))
    aug[..., 0, 1] = 1.0
    aug[..., 1, 0] = -(omega**2)
    aug[..., 1, 1] = -2.0 * zeta * omega
    aug[..., 1, 2] = 1.0  # unit input; 1/m applied below (keeps the exponent well scaled)
    aug[..., 2, 3] = 1.0 / step_s
    e = scipy.linalg.expm(aug * step_s)
    phi = e[..., :2, :2]
    gam1 = e[..., :2, 2] / mass[:, None]
    gam2 = e[..., :2, 3] / mass[:, None]
    return np.ascontiguousarray(phi), np.ascontiguousarray(gam1 - gam2), np.ascontiguousarray(gam2)


def band_limited_noise(variance, bandwidth_hz: float, order: int, n: int, step_s: float, rng) -> np.ndarray:
    """Zero-mean Gaussian noise through a Butterworth low-pass, shape (len(variance), n).

    White noise scaled by the filter's noise gain (sum of its squared impulse response) so that
    each row has the stationary ``variance``; the filter runs over a warm-up stretch that is then
    dropped, so the noise is stationary from the first sample.
    """
    fs = 1.0 / step_s
    sos = scipy.signal.butter(order, bandwidth_hz, fs=fs, output="sos")
    n_imp = int(math.ceil(40.0 * fs / bandwidth_hz))
    impulse = np.zeros(n_imp)
    impulse[0] = 1.0
    gain2 = float(np.sum(scipy.signal.sosfilt(sos, impulse) ** 2))  # output variance per unit input
    n_warm = int(math.ceil(20.0 * fs / bandwidth_hz))  # reach stationarity before t = 0
    variance = np.asarray(variance, dtype=float)
    white = rng.standard_normal((variance.size, n + n_warm))
    shaped = scipy.signal.sosfilt(sos, white, axis=-1)[:, n_warm:]
    return shaped * np.sqrt(variance / gain2)[:, None]


def resonance_filter(frequency_hz: float, damping_ratio: float, signals: np.ndarray, step_s: float) -> np.ndarray:
    """``w^2 / (s^2 + 2 zeta w s + w^2)`` applied along the last axis, first-order-hold exact."""
    w = 2.0 * np.pi * frequency_hz
    phi, g0, g1 = foh_matrices(np.array([w]), np.array([damping_ratio]), np.array([1.0 / w**2]), step_s)
    # x_{k+1} = Phi x_k + g0 u_k + g1 u_{k+1}, y = x[0]; with xi = x - g1 u: a standard system
    a = phi[0]
    b = (a @ g1[0] + g0[0]).reshape(2, 1)
    c = np.array([[1.0, 0.0]])
    d = np.array([[g1[0][0]]])
    num, den = scipy.signal.ss2tf(a, b, c, d)
    return scipy.signal.lfilter(num[0], den, signals, axis=-1)


def resample(signals: np.ndarray, step_s: float, times: np.ndarray, *, cutoff_hz: float | None,
             order: int) -> np.ndarray:
    """Low-pass (zero phase, ``sosfiltfilt``; none if ``cutoff_hz`` is None) the rows of
    ``signals`` sampled every ``step_s`` from t = 0 and read them at ``times`` by cubic spline;
    times outside the signal read its first or last value."""
    n = signals.shape[1]
    if cutoff_hz is not None:
        sos = scipy.signal.butter(order, cutoff_hz, fs=1.0 / step_s, output="sos")
        signals = scipy.signal.sosfiltfilt(sos, signals, axis=-1)
    t = np.arange(n) * step_s
    t_read = np.clip(times, 0.0, t[-1])  # at rest before the start; hold the end
    return CubicSpline(t, signals, axis=-1)(t_read)


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """Round to multiples of ``step`` (no change for ``step == 0``)."""
    return np.round(x / step) * step if step > 0.0 else x
