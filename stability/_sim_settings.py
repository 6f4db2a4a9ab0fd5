"""Inputs of the milling simulator beyond the structure and the cut: the optional effects, the
broadband background force and the sensor model, each a frozen dataclass checked on construction.

Private module: every name is imported from :mod:`stability.simulate`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from oma.cutting import Sensors
from oma.errors import InputError

__all__ = [
    "Runout",
    "ForceSensorDynamics",
    "ProcessDamping",
    "PoseDrift",
    "NonlinearCutting",
    "Effects",
    "BackgroundForce",
    "SensorModel",
]


# ------------------------------------------------------------------------------------- checks
def _positive(value, field_name: str, *, allow_zero: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = float("nan")
    ok = math.isfinite(x) and (x >= 0.0 if allow_zero else x > 0.0)
    if not ok:
        raise InputError(None, field_name, "a finite number >= 0" if allow_zero else "a finite number > 0",
                         repr(value))
    return x


def _finite(value, field_name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = float("nan")
    if not math.isfinite(x):
        raise InputError(None, field_name, "a finite number", repr(value))
    return x


# ------------------------------------------------------------------------------------ effects
@dataclass(frozen=True)
class Runout:
    """Radial runout of the teeth.

    Tooth ``j`` (at immersion ``phi_j = Omega t + 2 pi j / N``) cuts on radius ``R + rho_j`` with
    ``rho_j = amplitude_m cos(phase_rad - 2 pi j / N)``: the projection of a tool-axis offset of
    ``amplitude_m`` onto each tooth. The chip of tooth ``j`` grows by ``rho_j - rho_{j+1}``, where
    tooth ``j + 1`` (mod N) is the one that passed the same angle one tooth period earlier. This is
    the usual first-order approximation: it ignores that a tooth following one that left the cut
    removes material left by teeth further back.

    Parameters
    ----------
    amplitude_m : float
        Offset of the tool axis, m (>= 0).
    phase_rad : float
        Angle of the offset from tooth 0, rad.
    """

    amplitude_m: float
    phase_rad: float = 0.0

    def __post_init__(self):
        _positive(self.amplitude_m, "effects.runout.amplitude_m", allow_zero=True)
        _finite(self.phase_rad, "effects.runout.phase_rad")

    def radii_offsets(self, teeth: int) -> np.ndarray:
        """``rho_j`` of each tooth, shape (teeth,), m."""
        j = np.arange(teeth)
        return self.amplitude_m * np.cos(self.phase_rad - 2.0 * np.pi * j / teeth)

    def chip_increments(self, teeth: int) -> np.ndarray:
        """``rho_j - rho_{j+1}``: the chip added to each tooth, shape (teeth,), m."""
        rho = self.radii_offsets(teeth)
        return rho - np.roll(rho, -1)


@dataclass(frozen=True)
class ForceSensorDynamics:
    """A resonance of the force sensor, applied to the MEASURED force only.

    ``H(s) = w_s^2 / (s^2 + 2 zeta_s w_s s + w_s^2)``: unit static gain, the flange sensor and the
    tool-spindle mass as a 2nd-order system. Discretised exactly (first-order hold) at the internal
    rate.

    Parameters
    ----------
    frequency_hz : float
        Resonance frequency, Hz.
    damping_ratio : float
        Damping ratio of the resonance.
    """

    frequency_hz: float
    damping_ratio: float = 0.05

    def __post_init__(self):
        _positive(self.frequency_hz, "effects.force_sensor.frequency_hz")
        _positive(self.damping_ratio, "effects.force_sensor.damping_ratio")

    def response(self, freq_hz) -> np.ndarray:
        """Complex gain ``H`` at frequencies in Hz (measured force / true force)."""
        r = np.asarray(freq_hz, dtype=float) / self.frequency_hz
        return 1.0 / (1.0 - r**2 + 2j * self.damping_ratio * r)


@dataclass(frozen=True)
class ProcessDamping:
    """Process damping from flank rubbing (Budak & Tunc, CIRP Annals 58, 2009).

    Each engaged slice adds a radial force on the tool ``dF_pd = -C (v_r / V) dz`` along the radial
    unit vector ``r = sin(phi) f + cos(phi) n``, with ``v_r = v . r`` the tool velocity along ``r``
    and ``V = pi D n / 60`` the cutting speed. When the tool moves into the surface (``v_r > 0``)
    the force pushes it back: its power ``-C v_r^2 dz / V`` is never positive, so it only removes
    energy. In the force model it is an addition ``C v_r / V dz`` to ``dFr``.

    Parameters
    ----------
    coefficient_N_m : float
        ``C``, N/m (>= 0).
    """

    coefficient_N_m: float

    def __post_init__(self):
        _positive(self.coefficient_N_m, "effects.process_damping.coefficient_N_m", allow_zero=True)


@dataclass(frozen=True)
class PoseDrift:
    """The arm moves along the cut and its modes drift.

    Every natural frequency scales by ``1 + relative_change * t / duration``; the modal mass and
    damping ratio stay constant (so the stiffness scales with ``w^2``). The modal parameters are
    piecewise constant over segments of whole tooth periods (at most 2048 segments), evaluated at
    the segment mid-time.

    Parameters
    ----------
    relative_change : float
        Relative change of every natural frequency from start to end of the record (> -1).
    """

    relative_change: float

    def __post_init__(self):
        x = _finite(self.relative_change, "effects.pose_drift.relative_change")
        if x <= -1.0:
            raise InputError(None, "effects.pose_drift.relative_change", "a number > -1", repr(x))


@dataclass(frozen=True)
class NonlinearCutting:
    """Size effect: ``Ktc, Krc, Kac`` multiplied by ``(h / h_ref)^(-p)``; edge terms unchanged.

    Parameters
    ----------
    exponent_p : float
        ``p`` (0 = linear model; typically 0.1-0.4, < 1).
    reference_chip_m : float, optional
        ``h_ref``, m; default the feed per tooth of the cut.
    """

    exponent_p: float
    reference_chip_m: float | None = None

    def __post_init__(self):
        p = _finite(self.exponent_p, "effects.nonlinear_cutting.exponent_p")
        if p >= 1.0:
            raise InputError(None, "effects.nonlinear_cutting.exponent_p", "a number < 1", repr(p))
        if self.reference_chip_m is not None:
            _positive(self.reference_chip_m, "effects.nonlinear_cutting.reference_chip_m")


@dataclass(frozen=True)
class Effects:
    """Named effects that make real data depart from the simple model; every one off by default.

    Parameters
    ----------
    runout : Runout, optional
    force_sensor : ForceSensorDynamics, optional
    channel_delay_s : float
        The measured displacement lags the measured force by this time, s (negative: leads).
        Applied exactly when resampling (the displacement is read at ``t - delay``).
    process_damping : ProcessDamping, optional
    pose_drift : PoseDrift, optional
    nonlinear_cutting : NonlinearCutting, optional
    """

    runout: Runout | None = None
    force_sensor: ForceSensorDynamics | None = None
    channel_delay_s: float = 0.0
    process_damping: ProcessDamping | None = None
    pose_drift: PoseDrift | None = None
    nonlinear_cutting: NonlinearCutting | None = None

    def __post_init__(self):
        _finite(self.channel_delay_s, "effects.channel_delay_s")


@dataclass(frozen=True)
class BackgroundForce:
    """Broadband background force: zero-mean Gaussian, independent per machine axis.

    White noise shaped by a 4th-order Butterworth low-pass (``bandwidth_hz`` is its -3 dB
    frequency), scaled so that the stationary variance per axis is ``variance_N2``. It acts on the
    structure and is part of the measured force.

    Parameters
    ----------
    variance_N2 : array_like, shape (3,)
        Variance along X, Y, Z, N^2 (Nguyen & Melkote 2020 found 232, 278, 251 N^2).
    bandwidth_hz : float
        Low-pass cut-off, Hz.
    """

    variance_N2: tuple[float, float, float]
    bandwidth_hz: float

    def __post_init__(self):
        v = np.array(self.variance_N2, dtype=float).ravel()
        if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v < 0):
            raise InputError(None, "background.variance_N2", "three finite numbers >= 0 (X, Y, Z)",
                             repr(self.variance_N2))
        object.__setattr__(self, "variance_N2", tuple(float(x) for x in v))
        _positive(self.bandwidth_hz, "background.bandwidth_hz")


@dataclass(frozen=True)
class SensorModel:
    """How the force sensor and the displacement sensor see the truth.

    Parameters
    ----------
    force_noise_variance_N2 : float
        White noise added to each measured force sample, N^2.
    displacement_noise_m : float
        Standard deviation of white noise added to each displacement sample, m.
    displacement_resolution_m : float
        Quantisation step of the displacement, m (0: none; a laser tracker: 1.5e-5).
    anti_alias : bool
        Low-pass before sampling (see the notes of :mod:`stability.simulate`); without it the record samples the
        internal signals directly, aliasing included.
    force_resolution_N : float
        Quantisation step of the force, N (0: none).
    """

    force_noise_variance_N2: float = 0.0
    displacement_noise_m: float = 0.0
    displacement_resolution_m: float = 0.0
    anti_alias: bool = True
    force_resolution_N: float = 0.0

    def __post_init__(self):
        for name in ("force_noise_variance_N2", "displacement_noise_m", "displacement_resolution_m",
                     "force_resolution_N"):
            _positive(getattr(self, name), f"sensors.{name}", allow_zero=True)

    def to_sensors(self) -> Sensors:
        """The record's :class:`oma.cutting.Sensors` (unset where the model has none)."""
        return Sensors(
            force_noise_variance_N2=self.force_noise_variance_N2 or None,
            force_resolution_N=self.force_resolution_N or None,
            displacement_resolution_m=self.displacement_resolution_m or None,
        )

