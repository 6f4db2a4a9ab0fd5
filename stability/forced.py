"""Forced vibration of a stable cut: surface location error, peak force, torque, power.

In a stable cut the tool-tip motion settles to a motion with the tooth period ``T``, so the
regenerative term ``q(t) - q(t - T)`` of the chip vanishes and the force is the rigid-tool force of
formats.md (chip ``fz sin(phi)``). Its harmonics ``F_h`` at ``h`` times the tooth-passing frequency
pass through the receptance ``G`` (machine frame, 3 x 3, cross terms included); the mean force
passes through ``G(0)``, the static deflection that dominates for a compliant robot::

    x(t) = G(0) F_0 + 2 Re sum_{h >= 1} G(h w_T) F_h exp(i h w_T t)

(Schmitz & Mann, IJMTM 46, 2006). The force harmonics come from exact cell means of the force
(closed-form integrals over angle and over the axial depth, :mod:`stability.oriented`), corrected
for the cell averaging, so a force that jumps at entry or exit still has exact low harmonics.

Time origin: ``t = 0`` when tooth 0's tip is at ``phi = 0`` (along ``n``); tooth ``j`` is at
``phi = Omega t + 2 pi j / N`` (the simulator's convention). The finished wall is generated at
``phi = pi`` in down milling, ``phi = 0`` in up milling; at height ``z`` the helix delays that
instant by ``kappa z / Omega``. The surface location error is the tool-tip displacement away from
the finished wall at that instant: ``+x_n`` in down milling (the wall is on the ``-n`` side),
``-x_n`` in up milling; positive means material left on.

The residual compliance of a modal model (if any) acts on every harmonic. A measured FRF table is
read through its own interpolation; harmonics above its band are left out, and its value at its
lowest frequency (real part) stands in for ``G(0)``, with a warning (a hammer test rarely reaches
0 Hz).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, fields

import numpy as np

from oma.cutting import CuttingCoefficients, Cut, Tool, engagement_angles

from .oriented import (
    _readonly as _ro,
    engaged_axial_integral,
    engaged_axial_step_mean,
    force_coefficients,
    helix_lag_per_m,
    torque_coefficients,
)

__all__ = ["ForcedResponse", "ForcedSweep", "forced_response", "forced_sweep", "default_harmonics"]

TWO_PI = 2.0 * np.pi



def _jsonable(value):
    if isinstance(value, np.ndarray):
        if np.iscomplexobj(value):
            return {"re": value.real.tolist(), "im": value.imag.tolist()}
        return value.tolist()
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    return value


def default_harmonics(structure, tool: Tool, spindle_rpm: float) -> int:
    """Harmonics of the tooth-passing frequency used by default.

    A modal model: enough to reach 4 times the highest natural frequency (beyond it a mode
    responds quasi-statically, ``|G| ~ (f_n / f)^2``), at least 32. An FRF table: every harmonic
    inside the table's band (no extrapolation), at least 1.
    """
    f_tp = tool.teeth * float(spindle_rpm) / 60.0
    if hasattr(structure, "natural_frequency_hz"):
        f_max = 4.0 * float(np.max(structure.natural_frequency_hz))
        return int(min(2000, max(32, np.ceil(f_max / f_tp))))
    if hasattr(structure, "freq_hz"):
        return int(max(1, np.floor(float(np.max(structure.freq_hz)) / f_tp)))
    raise TypeError("structure must be a ModalModel or an FRFTable (with .receptance(freq_hz))")


def _static_receptance(structure) -> np.ndarray:
    """``G(0)`` (3, 3), m/N."""
    if hasattr(structure, "freq_hz"):
        f0 = float(np.min(structure.freq_hz))
        if f0 > 0:
            warnings.warn(f"the FRF table starts at {f0:g} Hz: its value there (real part) stands in for "
                          "the static compliance G(0)", stacklevel=4)
        return np.real(structure.receptance([f0])[:, :, 0])
    return np.real(structure.receptance([0.0])[:, :, 0])


class _ForceShape:
    """Rigid-tool force, torque and their harmonics as functions of the tip angle (rpm-free)."""

    def __init__(self, tool: Tool, cut: Cut, coefficients: CuttingCoefficients, depth: float):
        self.tool, self.cut, self.depth = tool, cut, float(depth)
        self.fc = force_coefficients(coefficients, cut.feed_per_tooth_m)  # (3, 6), cut frame
        self.tc = torque_coefficients(coefficients, cut.feed_per_tooth_m, tool.diameter_m / 2.0)
        self.pitch = TWO_PI / tool.teeth

    def pointwise(self, phi):
        """Force in the cut frame (..., 3), N, and torque (...,), N m, at tip angles ``phi``."""
        e = engaged_axial_integral(self.tool, self.cut, phi, self.depth)
        return e @ self.fc.T, e @ self.tc

    def harmonics(self, n_harm: int):
        """Complex Fourier coefficients ``F_h``, h = 0..n_harm, of force (cut frame, (3, H+1)) and
        torque ((H+1,)) over one tooth period, from exact cell means.

        Cell means ``avg_k`` of ``M`` cells give ``DFT_h = sum_p c_{h+pM} kernel(h+pM)`` with
        ``kernel(j) = (exp(2 pi i j / M) - 1) / (2 pi i j / M)``; ``c_h = DFT_h / kernel(h)`` up to
        the aliased terms, which for ``M >= 16 H`` are below 1e-4 of ``c_h`` even for a jump.
        """
        cells = int(2 ** np.ceil(np.log2(max(1024, 16 * n_harm))))
        edges = self.pitch * np.arange(cells + 1) / cells
        e = engaged_axial_step_mean(self.tool, self.cut, edges[:-1], edges[1:], self.depth)
        sig = np.concatenate([e @ self.fc.T, (e @ self.tc)[:, None]], axis=1)  # (M, 4)
        dft = np.fft.fft(sig, axis=0)[: n_harm + 1] / cells
        h = np.arange(n_harm + 1)
        x = TWO_PI * h / cells
        kern = np.ones(n_harm + 1, dtype=complex)
        kern[1:] = (np.exp(1j * x[1:]) - 1.0) / (1j * x[1:])
        c = dft / kern[:, None]
        return c[:, :3].T, c[:, 3]

    def critical_angles(self):
        """Tip angles in one tooth pitch at which some tooth enters or leaves the cut (at the tip
        or, with a helix, at the top of the depth): where a straight-flute force may jump."""
        st, ex = engagement_angles(self.tool, self.cut)
        lag = helix_lag_per_m(self.tool) * self.depth
        base = np.array([st, ex, st + lag, ex + lag])
        return np.mod(base[:, None] - self.pitch * np.arange(self.tool.teeth), self.pitch).ravel()

    def peaks(self, n_grid: int = 4096):
        """Largest resultant force in the (f, n) plane, N, and largest torque, N m, over a tooth
        period: a fine grid plus both sides of every angle where the force can jump."""
        grid = self.pitch * np.arange(n_grid) / n_grid
        crit = self.critical_angles()
        eps = 1e-9 * self.pitch
        phi = np.concatenate([grid, crit - eps, crit, crit + eps])
        force, torque = self.pointwise(phi)
        return float(np.max(np.hypot(force[:, 0], force[:, 1]))), float(np.max(torque))


def _series(x_h, f_tp: float, time_s) -> np.ndarray:
    """``Re(X_0) + 2 Re sum_h X_h exp(i h 2 pi f_T t)``, (3, n)."""
    t = np.atleast_1d(np.asarray(time_s, dtype=float))
    h = np.arange(x_h.shape[1])
    ph = np.exp(1j * TWO_PI * f_tp * h[:, None] * t[None, :])
    w = np.where(h == 0, 1.0, 2.0)[:, None]
    return np.real(x_h @ (w * ph))


def _harmonic_receptance(structure, freq_hz) -> np.ndarray:
    """Receptance at harmonic frequencies (3, 3, n); zero above a measured table's band (no
    extrapolation of a measured FRF)."""
    f = np.asarray(freq_hz, dtype=float)
    g = structure.receptance(f)
    if hasattr(structure, "freq_hz"):
        g = np.where((f <= float(np.max(structure.freq_hz)))[None, None, :], g, 0.0)
    return g


def _finishing_angle(cut: Cut) -> tuple[float, float]:
    """Tip angle at which the finished wall is cut, and the sign that turns ``x_n`` into the SLE."""
    return (np.pi, 1.0) if cut.milling == "down" else (0.0, -1.0)


@dataclass(frozen=True)
class ForcedResponse:
    """Steady forced vibration of one stable cut at one speed and depth.

    Attributes
    ----------
    spindle_rpm, axial_depth_m : float
    tooth_frequency_hz : float
        ``N n / 60``, Hz.
    harmonics : int
        Harmonics of the tooth-passing frequency summed.
    time_s : ndarray, shape (n_time,)
        One tooth period, ``t = 0`` with tooth 0's tip at ``phi = 0``, s.
    force_N : ndarray, shape (3, n_time)
        Force on the tool, machine frame (rigid-tool force: exact in steady state), N.
    displacement_m : ndarray, shape (3, n_time)
        Steady periodic tool-tip displacement, machine frame, static part included, m.
    displacement_harmonics_m : ndarray, shape (3, harmonics + 1), complex
        ``X_h``: ``x(t) = Re(X_0) + 2 Re sum_{h>=1} X_h exp(i h 2 pi f_T t)``, machine frame, m.
    static_displacement_m : ndarray, shape (3,)
        ``G(0) F_0``: the static deflection by the mean force, machine frame, m.
    mean_force_N : ndarray, shape (3,)
        Mean force on the tool, machine frame, N.
    surface_location_error_m : float
        At the tool tip (z = 0); positive where material is left on the wall, m.
    finishing_time_s : float
        Instant in the tooth period at which the tip generates the finished wall, s.
    wall_displacement_m : ndarray, shape (n_time,)
        Displacement away from the finished wall (``+x_n`` down milling, ``-x_n`` up milling) over
        the period: the SLE is its value at ``finishing_time_s``, m.
    sle_profile_z_m, sle_profile_m : ndarray, shape (n_profile,)
        The surface location error along the depth (heights above the tip), m.
    peak_force_N : float
        Largest resultant force in the (f, n) plane over a revolution, N.
    peak_torque_N_m, mean_torque_N_m : float
        Spindle torque ``sum R Ft``, N m.
    power_W : float
        Mean cutting power, ``mean torque * Omega``, W.
    mrr_m3_s : float
        Material removal rate, m^3/s.
    """

    spindle_rpm: float
    axial_depth_m: float
    tooth_frequency_hz: float
    harmonics: int
    time_s: np.ndarray
    force_N: np.ndarray
    displacement_m: np.ndarray
    displacement_harmonics_m: np.ndarray
    static_displacement_m: np.ndarray
    mean_force_N: np.ndarray
    surface_location_error_m: float
    finishing_time_s: float
    wall_displacement_m: np.ndarray
    sle_profile_z_m: np.ndarray
    sle_profile_m: np.ndarray
    peak_force_N: float
    peak_torque_N_m: float
    mean_torque_N_m: float
    power_W: float
    mrr_m3_s: float

    def displacement_at(self, time_s) -> np.ndarray:
        """Steady displacement at any times, (3, n), machine frame, m."""
        return _series(self.displacement_harmonics_m, self.tooth_frequency_hz, time_s)

    def to_dict(self, *, series: bool = False) -> dict:
        """JSON-ready mapping of the scalars (and, with ``series``, the time series)."""
        skip = set() if series else {"time_s", "force_N", "displacement_m", "displacement_harmonics_m"}
        return {f.name: _jsonable(getattr(self, f.name)) for f in fields(self) if f.name not in skip}


def _mrr(tool: Tool, cut: Cut, spindle_rpm: float, depth: float) -> float:
    return depth * cut.radial_depth_m * cut.feed_per_tooth_m * tool.teeth * float(spindle_rpm) / 60.0


def forced_response(structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients, *,
                    spindle_rpm: float, axial_depth_m: float, harmonics: int | None = None,
                    n_time: int = 256, n_profile: int = 21) -> ForcedResponse:
    """Steady forced vibration, surface location error, force, torque and power of a stable cut.

    Parameters
    ----------
    structure : ModalModel or FRFTable
        Machine-frame receptance ``receptance(freq_hz) -> (3, 3, n)``, m/N.
    tool, cut, coefficients
        The cut; the linear-plus-edge force model (edge forces included).
    spindle_rpm : float
        Spindle speed, rpm.
    axial_depth_m : float
        Axial depth of cut, m.
    harmonics : int, optional
        Harmonics of the tooth-passing frequency; default :func:`default_harmonics`.
    n_time : int
        Samples of the returned time series over one tooth period.
    n_profile : int
        Heights of the surface-location-error profile (0 to the depth).

    Returns
    -------
    ForcedResponse
    """
    rpm, depth = float(spindle_rpm), float(axial_depth_m)
    if not (rpm > 0 and depth > 0):
        raise ValueError(f"spindle_rpm and axial_depth_m must be > 0, found {spindle_rpm} and {axial_depth_m}")
    n_h = default_harmonics(structure, tool, rpm) if harmonics is None else int(harmonics)
    if n_h < 0:
        raise ValueError(f"harmonics must be >= 0, found {harmonics}")
    shape = _ForceShape(tool, cut, coefficients, depth)
    f_tp = tool.teeth * rpm / 60.0
    omega = TWO_PI * rpm / 60.0
    rot = cut.frame  # rows f, n, a: machine -> cut
    c_cut, c_torque = shape.harmonics(n_h)
    c_mach = rot.T @ c_cut  # (3, H+1)
    g0 = _static_receptance(structure)
    x_h = np.empty((3, n_h + 1), dtype=complex)
    x_h[:, 0] = g0 @ c_mach[:, 0].real
    if n_h:
        x_h[:, 1:] = np.einsum("ijh,jh->ih", _harmonic_receptance(structure, f_tp * np.arange(1, n_h + 1)),
                               c_mach[:, 1:])
    t = np.arange(n_time) / (n_time * f_tp)
    force_cut, _ = shape.pointwise(omega * t)
    phi_fin, sign = _finishing_angle(cut)
    z = np.linspace(0.0, depth, max(int(n_profile), 1))
    t_z = (phi_fin + helix_lag_per_m(tool) * z) / omega
    sle = sign * (cut.normal_direction @ _series(x_h, f_tp, t_z))
    disp = _series(x_h, f_tp, t)
    peak_f, peak_t = shape.peaks()
    return ForcedResponse(
        spindle_rpm=rpm, axial_depth_m=depth, tooth_frequency_hz=f_tp, harmonics=n_h, time_s=_ro(t),
        force_N=_ro(rot.T @ force_cut.T), displacement_m=_ro(disp),
        displacement_harmonics_m=_ro(x_h), static_displacement_m=_ro(x_h[:, 0].real),
        mean_force_N=_ro(c_mach[:, 0].real), surface_location_error_m=float(sle[0]),
        finishing_time_s=float(np.mod(t_z[0], 1.0 / f_tp)),
        wall_displacement_m=_ro(sign * (cut.normal_direction @ disp)),
        sle_profile_z_m=_ro(z), sle_profile_m=_ro(sle), peak_force_N=peak_f, peak_torque_N_m=peak_t,
        mean_torque_N_m=float(c_torque[0].real), power_W=float(c_torque[0].real) * omega,
        mrr_m3_s=_mrr(tool, cut, rpm, depth),
    )


@dataclass(frozen=True)
class ForcedSweep:
    """Surface location error, peak force, torque and power versus spindle speed at one depth.

    Attributes
    ----------
    spindle_rpm : ndarray, shape (n,)
    axial_depth_m : float
    surface_location_error_m : ndarray, shape (n,)
        At the tool tip; positive where material is left on, m.
    peak_force_N, peak_torque_N_m, power_W, mrr_m3_s : ndarray, shape (n,)
        As in :class:`ForcedResponse` (force and torque do not depend on speed in this model).
    static_sle_m : float
        The part of the surface location error due to the static deflection alone, m.
    """

    spindle_rpm: np.ndarray
    axial_depth_m: float
    surface_location_error_m: np.ndarray
    peak_force_N: np.ndarray
    peak_torque_N_m: np.ndarray
    power_W: np.ndarray
    mrr_m3_s: np.ndarray
    static_sle_m: float

    def to_dict(self) -> dict:
        return {f.name: _jsonable(getattr(self, f.name)) for f in fields(self)}

    def plot(self, ax=None):
        """Surface location error and peak force versus speed (see :mod:`stability.plots`)."""
        from .plots import plot_forced_sweep

        return plot_forced_sweep(self, ax=ax)


def forced_sweep(structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients, *, rpm,
                 axial_depth_m: float, harmonics: int | None = None) -> ForcedSweep:
    """Surface location error and peak force at many speeds, one depth (vectorised over speed).

    The force's shape over the tip angle does not depend on speed, so its harmonics are computed
    once; only the frequencies at which the receptance is read change.

    Parameters
    ----------
    rpm : array_like, shape (n,)
        Spindle speeds, rpm.
    axial_depth_m : float
        Axial depth, m.
    harmonics : int, optional
        Harmonics; default: :func:`default_harmonics` at the lowest speed.
    """
    rpm = np.asarray(rpm, dtype=float).ravel()
    depth = float(axial_depth_m)
    if rpm.size == 0 or np.any(rpm <= 0) or not depth > 0:
        raise ValueError("rpm and axial_depth_m must be > 0")
    n_h = default_harmonics(structure, tool, rpm.min()) if harmonics is None else int(harmonics)
    shape = _ForceShape(tool, cut, coefficients, depth)
    c_cut, c_torque = shape.harmonics(n_h)
    c_mach = cut.frame.T @ c_cut
    g0 = _static_receptance(structure)
    x0 = g0 @ c_mach[:, 0].real
    phi_fin, sign = _finishing_angle(cut)
    h = np.arange(1, n_h + 1)
    f_tp = tool.teeth * rpm / 60.0
    freqs = (f_tp[:, None] * h[None, :]).ravel()
    g = _harmonic_receptance(structure, freqs).reshape(3, 3, rpm.size, n_h)
    x_h = np.einsum("ijrh,jh->irh", g, c_mach[:, 1:])  # (3, n_rpm, H)
    # at the finishing instant the phase of harmonic h is h * N * phi_fin (tip angle)
    ph = np.exp(1j * h * tool.teeth * phi_fin)
    x_fin = x0[:, None] + 2.0 * np.real(np.einsum("irh,h->ir", x_h, ph))
    sle = sign * (cut.normal_direction @ x_fin)
    peak_f, peak_t = shape.peaks()
    omega = TWO_PI * rpm / 60.0
    ones = np.ones(rpm.size)
    return ForcedSweep(
        spindle_rpm=_ro(rpm), axial_depth_m=depth, surface_location_error_m=_ro(sle),
        peak_force_N=_ro(peak_f * ones), peak_torque_N_m=_ro(peak_t * ones),
        power_W=_ro(float(c_torque[0].real) * omega),
        mrr_m3_s=_ro(np.array([_mrr(tool, cut, r, depth) for r in rpm])),
        static_sle_m=float(sign * (cut.normal_direction @ x0)),
    )
