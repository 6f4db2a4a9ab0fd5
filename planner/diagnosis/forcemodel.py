"""Robomill's prediction of the periodic cutting force of a cut (part (a) of the comparison).

Two routes to the same quantity, the harmonic coefficients ``c_h`` of the force on the tool at
multiples ``h`` of the spindle frequency (tooth 0 at immersion ``phi = 0`` at ``t = 0``):

* :func:`simulated_harmonics`: the time-domain simulator (:func:`stability.simulate.simulate`) run
  without background force until the start transient has died out, the record's anti-alias
  filter included. This is the reference prediction, and the one that validates an extended model.
* :func:`analytic_harmonics`: the rigid-tool force (no vibration in the chip) summed over teeth and
  axial slices exactly as the simulator does (formats.md, "Force model"), over one revolution, and
  its Fourier series. About a millisecond per evaluation, so candidate parameters (runout, size
  effect, sensor resonance) are fitted with it. For a robot the vibration at the tooth frequency
  is a fraction of a micrometre against a chip of a tenth of a millimetre, so both routes agree to
  a fraction of a percent (checked in the tests).
"""

from __future__ import annotations

import math

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Tool, engagement_angles
from oma.modal import ModalModel
from dataclasses import dataclass

from stability.simulate import (ANTI_ALIAS_FRACTION, ANTI_ALIAS_ORDER, Effects, Runout, default_axial_slices,
                                simulate)

from .spectral import harmonic_coefficients

__all__ = ["ToothRadiiRunout", "periodic_force", "analytic_harmonics", "simulated_harmonics", "anti_alias_gain",
           "sensor_gain"]


@dataclass(frozen=True)
class ToothRadiiRunout(Runout):
    """Runout as unequal tooth radii: tooth ``j`` cuts on ``R + offsets_m[j]`` (no eccentric axis).

    The simulator asks a runout only for its chip increments (``rho_j - rho_{j+1}``), so this
    form runs through :func:`stability.simulate.simulate` unchanged; ``amplitude_m`` is unused
    (0). Any pattern of radii is one of these; an eccentric axis is the special case
    ``rho_j = A cos(phase - 2 pi j / N)``.
    """

    offsets_m: tuple = ()

    def radii_offsets(self, teeth: int) -> np.ndarray:
        off = np.zeros(teeth)
        vals = np.asarray(self.offsets_m, dtype=float)[:teeth]
        off[:vals.size] = vals
        return off


def anti_alias_gain(freq_hz, sample_rate_hz: float) -> np.ndarray:
    """Gain of the simulator's zero-phase anti-alias filter: ``1 / (1 + (f / 0.4 fs)^(2 order))``."""
    f = np.asarray(freq_hz, dtype=float) / (ANTI_ALIAS_FRACTION * sample_rate_hz)
    return 1.0 / (1.0 + f ** (2 * ANTI_ALIAS_ORDER))


def sensor_gain(freq_hz, frequency_hz: float, damping_ratio: float) -> np.ndarray:
    """``H(f) = 1 / (1 - r^2 + 2 i zeta r)``, ``r = f / f_s``: measured over true force."""
    r = np.asarray(freq_hz, dtype=float) / float(frequency_hz)
    return 1.0 / (1.0 - r**2 + 2j * float(damping_ratio) * r)


def periodic_force(tool: Tool, cut: Cut, coefficients: CuttingCoefficients, *, n_angles: int = 512,
                   axial_slices: int | None = None, chip_increments_m=None, exponent_p: float = 0.0,
                   reference_chip_m: float | None = None) -> np.ndarray:
    """Force on a rigid tool over one revolution, machine frame, shape (3, n_angles), N.

    Sample ``k`` is tooth 0 at ``phi = 2 pi k / n_angles``. Same discretisation as the simulator:
    axial slices at mid-height with the helix lag ``2 z tan(helix) / D``, chip ``fz sin(phi) +
    drho_j``, no cutting where ``h <= 0``, size effect ``(h / h_ref)^(-p)`` on the cutting (not the
    edge) coefficients.

    Parameters
    ----------
    tool, cut, coefficients
        ``cut.axial_depth_m`` must be set.
    chip_increments_m : array_like, shape (teeth,), optional
        Runout chip increment of each tooth (:meth:`stability.simulate.Runout.chip_increments`), m.
    exponent_p, reference_chip_m : float
        Size effect; ``reference_chip_m`` defaults to the feed per tooth.
    """
    teeth = int(tool.teeth)
    depth = float(cut.axial_depth_m)
    n_slices = default_axial_slices(tool, depth) if axial_slices is None else int(axial_slices)
    dz = depth / n_slices
    z_mid = (np.arange(n_slices) + 0.5) * dz
    lag = 2.0 * z_mid * math.tan(tool.helix_rad) / tool.diameter_m
    phi_st, phi_ex = engagement_angles(tool, cut)
    fz = float(cut.feed_per_tooth_m)
    drho = np.zeros(teeth) if chip_increments_m is None else np.asarray(chip_increments_m, dtype=float)
    base = 2.0 * np.pi * np.arange(n_angles) / n_angles
    phi = (base[:, None, None] + 2.0 * np.pi * np.arange(teeth)[None, :, None] / teeth
           - lag[None, None, :]) % (2.0 * np.pi)
    sp, cp = np.sin(phi), np.cos(phi)
    h = fz * sp + drho[None, :, None]
    on = (phi >= phi_st) & (phi <= phi_ex) & (h > 0.0)
    k = coefficients
    scale = 1.0
    if exponent_p:
        href = fz if reference_chip_m is None else float(reference_chip_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(on, (np.where(on, h, 1.0) / href) ** (-exponent_p), 0.0)
    dft = np.where(on, (k.Ktc_N_m2 * scale * h + k.Kte_N_m) * dz, 0.0)
    dfr = np.where(on, (k.Krc_N_m2 * scale * h + k.Kre_N_m) * dz, 0.0)
    dfa = np.where(on, (k.Kac_N_m2 * scale * h + k.Kae_N_m) * dz, 0.0)
    ff = np.sum(-dft * cp - dfr * sp, axis=(1, 2))
    fn = np.sum(dft * sp - dfr * cp, axis=(1, 2))
    fa = np.sum(dfa, axis=(1, 2))
    return np.asarray(cut.frame).T @ np.vstack([ff, fn, fa])


def analytic_harmonics(tool: Tool, cut: Cut, coefficients: CuttingCoefficients, n_harm: int, *,
                       spindle_hz: float, sample_rate_hz: float | None = None, chip_increments_m=None,
                       exponent_p: float = 0.0, reference_chip_m: float | None = None,
                       sensor: tuple[float, float] | None = None, n_angles: int = 512,
                       axial_slices: int | None = None) -> np.ndarray:
    """Harmonic coefficients of the rigid-tool force, shape (3, n_harm + 1), complex, N.

    ``F(t) = c_0 + sum_h Re(c_h exp(i h Omega t))`` with tooth 0 at ``phi = Omega t``. The
    record's anti-alias filter (when ``sample_rate_hz`` is given) and a force-sensor resonance
    ``sensor = (frequency_hz, damping_ratio)`` multiply the coefficients at ``h * spindle_hz``.
    """
    f = periodic_force(tool, cut, coefficients, n_angles=n_angles, axial_slices=axial_slices,
                       chip_increments_m=chip_increments_m, exponent_p=exponent_p,
                       reference_chip_m=reference_chip_m)
    spec = np.fft.rfft(f, axis=-1) / n_angles
    c = np.empty((3, n_harm + 1), dtype=complex)
    c[:, 0] = spec[:, 0].real
    c[:, 1:] = 2.0 * spec[:, 1:n_harm + 1]
    fh = np.arange(n_harm + 1) * float(spindle_hz)
    gain = np.ones(n_harm + 1, dtype=complex)
    if sample_rate_hz is not None:
        gain = gain * anti_alias_gain(fh, sample_rate_hz)
    if sensor is not None:
        gain = gain * sensor_gain(fh, *sensor)
    return c * gain[None, :]


def settle_time_s(model: ModalModel) -> float:
    """Time for the slowest mode's start transient to fall below 10 % (``2.3 / (zeta w)``), 0.8..3 s.

    The transient rings at the modes' frequencies, not at the spindle harmonics, so what is left of
    it after this leaks into the least-squares harmonics only through the fit window's sidelobes.
    """
    if model.n_modes == 0:
        return 0.8
    rate = np.min(model.damping_ratio * model.omega_rad_s)
    return float(np.clip(2.3 / max(rate, 1e-9), 0.8, 3.0))


def simulated_harmonics(model: ModalModel, tool: Tool, cut: Cut, coefficients: CuttingCoefficients,
                        n_harm: int, *, spindle_hz: float, sample_rate_hz: float,
                        effects: Effects = Effects(), average_s: float = 0.5,
                        settle_s: float | None = None) -> np.ndarray:
    """Harmonic coefficients of the simulated measured force, shape (3, n_harm + 1), complex, N.

    The cut is simulated at ``60 spindle_hz`` rpm without background force or sensor noise, the
    record's sample rate and anti-alias filter included; the coefficients are fitted over the last
    ``average_s`` seconds (whole revolutions) after ``settle_s`` (:func:`settle_time_s`), with the
    phase reference at the simulation's ``t = 0`` (tooth 0 at ``phi = 0``).
    """
    settle = settle_time_s(model) if settle_s is None else float(settle_s)
    rev = 1.0 / float(spindle_hz)
    n_rev = max(int(math.ceil(average_s / rev)), 4)
    duration = settle + n_rev * rev + 2.0 / sample_rate_hz
    sim = simulate(model, tool, cut, coefficients, duration_s=duration, spindle_rpm=60.0 * spindle_hz,
                   sample_rate_hz=sample_rate_hz, effects=effects, background=None, regeneration=True)
    t = sim.record_time_s
    i0 = int(np.searchsorted(t, duration - n_rev * rev - 1.0 / sample_rate_hz))
    n = int(round(n_rev * rev * sample_rate_hz))
    n = min(n, t.size - i0)
    c, _ = harmonic_coefficients(sim.measured_force_N[:, i0:i0 + n], sample_rate_hz, spindle_hz, n_harm, t0=t[i0])
    return c
