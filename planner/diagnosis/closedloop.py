"""The cut as a closed loop: how regeneration and process damping shape the measured force spectrum
(part (c) of the comparison).

The force sensor measures the total force on the tool, ``F = F_bg + F_dyn``: the broadband
background ``F_bg`` that excites the robot (Nguyen & Melkote 2020) plus the dynamic cutting force
caused by the vibration itself. Averaged over the tooth period (the zero-order approximation of
Altintas & Budak, CIRP Annals 44(1), 1995) and with the process-damping force of Budak & Tunc
(CIRP Annals 58, 2009), in the cutting frame (rows ``f, n, a``; columns ``f, n``)::

    F_dyn(w) = K(w) x(w),   K(w) = R^T [ a B0 (1 - exp(-i w T)) - i w (C a / V) P0 ] R_fn

with ``B0`` the mean directional matrix per unit depth (:func:`stability.oriented.
average_directional_matrix`), ``P0 = (N / 2 pi) int r r^T dphi`` over the engagement (``r = sin(phi)
f + cos(phi) n``), ``T`` the tooth period, ``V`` the cutting speed, ``R`` the cutting frame and
``R_fn`` its ``f, n`` rows. With ``x = G F`` (the structure sees the total force):

    F = (I - K G)^{-1} F_bg,     S_FF = M S_bg M^H,   M = (I - K G)^{-1}.

So even a stable cut notches or lifts the measured force spectrum at the robot's modes, and process
damping deepens the notches; a flat background makes this visible. The averaging is accurate when
the tooth frequency is well above the modes: against 40 s of the simulated paper-like cell, the
mean log ratio over the notch at the X mode is within 0.02 at 2700 rpm (tooth 90 Hz, modes 10-25
Hz), but 0.2-0.3 at 1000 rpm (tooth 33 Hz), where the time-varying directional factors matter
(checked in the tests).
"""

from __future__ import annotations

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Tool, engagement_angles
from stability.oriented import average_directional_matrix

__all__ = ["damping_matrix", "dynamic_stiffness", "closed_loop_force_psd"]


def damping_matrix(tool: Tool, cut: Cut, *, n_quad: int = 721) -> np.ndarray:
    """``P0 = (N / 2 pi) int r r^T dphi`` over the engagement, shape (3, 2) (rows f, n, a)."""
    st, ex = engagement_angles(tool, cut)
    phi = np.linspace(st, ex, n_quad)
    r = np.stack([np.sin(phi), np.cos(phi)])
    p = tool.teeth / (2.0 * np.pi) * np.trapezoid(r[:, None, :] * r[None, :, :], phi, axis=-1)
    return np.vstack([p, np.zeros((1, 2))])


def dynamic_stiffness(tool: Tool, cut: Cut, coefficients: CuttingCoefficients, freq_hz, *,
                      process_damping_N_m: float = 0.0) -> np.ndarray:
    """``K(w)``, machine frame, shape (3, 3, n_freq), N/m: dynamic force per tool-tip displacement.

    ``cut.spindle_rpm`` and ``cut.axial_depth_m`` must be set.
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    w = 2.0 * np.pi * f
    rpm = float(cut.spindle_rpm)
    depth = float(cut.axial_depth_m)
    period = 60.0 / (tool.teeth * rpm)
    speed = np.pi * tool.diameter_m * rpm / 60.0
    frame = np.asarray(cut.frame)
    b0 = average_directional_matrix(tool, cut, coefficients)  # (3, 2)
    p0 = damping_matrix(tool, cut)
    regen = depth * b0[:, :, None] * (1.0 - np.exp(-1j * w * period))[None, None, :]
    damp = -1j * w[None, None, :] * (float(process_damping_N_m) * depth / speed) * p0[:, :, None]
    kc = regen + damp  # (3, 2, n) cutting frame
    return np.einsum("ai,abk,bj->ijk", frame, kc, frame[:2])


def closed_loop_force_psd(model, tool: Tool, cut: Cut, coefficients: CuttingCoefficients, freq_hz, *,
                          background_psd, process_damping_N_m: float = 0.0) -> np.ndarray:
    """Auto spectra of the measured force per axis for an independent background, shape (3, n_freq).

    Parameters
    ----------
    model : ModalModel
        Tool-tip dynamics.
    freq_hz : array_like, shape (n_freq,)
    background_psd : array_like, shape (3,) or (3, n_freq)
        One-sided PSD of the background force per machine axis, N^2/Hz (independent axes).
    process_damping_N_m : float
        ``C`` of :class:`stability.simulate.ProcessDamping`, N/m.

    Returns
    -------
    ndarray, shape (3, n_freq)
        ``diag(M S_bg M^H)``, N^2/Hz.
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    g = model.receptance(f)  # (3, 3, n)
    k = dynamic_stiffness(tool, cut, coefficients, f, process_damping_N_m=process_damping_N_m)
    kg = np.einsum("ijk,jlk->kil", k, g)  # (n, 3, 3)
    m = np.linalg.inv(np.eye(3)[None] - kg)  # (n, 3, 3)
    s = np.asarray(background_psd, dtype=float)
    if s.ndim == 1:
        s = np.repeat(s[:, None], f.size, axis=1)
    return np.einsum("kij,jk->ik", np.abs(m) ** 2, s)
