"""Time-domain simulation of a milling cut on a structure given by a modal model.

The simulator produces what a test cell would record: the force on the tool and the tool-tip
displacement, both as the truth at the internal integration rate and as measured by sensors at the
record's sample rate. It follows the force model and sign conventions of formats.md ("Frames and
signs", "Force model"):

* structure: the modes of an :class:`oma.modal.ModalModel`, ``m_r q_r'' + c_r q_r' + k_r q_r =
  u_r . F``, tool tip ``sum_r u_r q_r + residual_compliance @ F``;
* regenerative chip ``h = fz sin(phi) + (q(t) - q(t - T)) . (sin(phi) f + cos(phi) n)`` per axial
  slice and tooth, cutting only between the entry and exit angles and where ``h > 0``;
* linear-plus-edge forces ``dFt = (Ktc h + Kte) dz`` ... projected on ``f, n, a``;
* broadband background force (the excitation operational modal analysis relies on, Nguyen &
  Melkote 2020) acting on the structure and seen by the force sensor;
* sensor models: anti-alias filter, sampling, noise, resolution;
* optional effects (:class:`Effects`), each off by default.

Integration (see :mod:`stability._sim_kernel`): exact first-order-hold discretisation of every mode
(matrix exponential, force linear between steps), an integer number of steps per tooth period so the
delay line is exact, one predictor step for the force at the new time. A residual compliance enters
the chip thickness with the force of the previous step (one step of lag breaks the algebraic loop
it would close); the reported displacement uses the force of the same step.

Step rule (when ``steps_per_tooth`` is not given)::

    steps_per_tooth = max(50, ceil(20 f_hi T), ceil(4 fs T), ceil(4 B T))

with ``T`` the tooth period, ``f_hi`` the highest natural frequency (after pose drift) or the
force-sensor resonance, ``fs`` the record's sample rate and ``B`` the background bandwidth: at least
50 steps per tooth period, 20 per period of the fastest mode, an internal rate of at least four
times the record rate (the cubic resampling then errs by < 1e-3 at 0.4 fs) and of four times the
background bandwidth.

Measured signals: the internal-rate signals pass a zero-phase 8th-order Butterworth low-pass at
0.4 fs (``scipy.signal.sosfiltfilt``: |H|^2 of order 8, flat to 1 % up to 0.3 fs, -28 dB at the
first frequency that aliases onto 0.4 fs), are resampled at the record times with a cubic spline,
then get white noise and are quantised. Zero phase means force and displacement stay aligned: an
FRF estimated from them is not biased by the filter.

References
----------
Altintas, Y., & Budak, E. (1995). Analytical prediction of stability lobes in milling. CIRP Annals,
44(1), 357-362.
Budak, E., & Tunc, L. T. (2009). A new method for identification and modeling of process damping in
machining. CIRP Annals, 58(1), 81-84.
Nguyen, V., & Melkote, S. (2020). Identification of industrial robot frequency response function
for robotic milling using operational modal analysis. Procedia Manufacturing, 48, 154-159.

The simulation itself is here; the effects, background force and sensor model are in
:mod:`stability._sim_settings`, the result type in :mod:`stability._sim_result`, and every public
name is imported from this module.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Material, Tool, engagement_angles
from oma.errors import InputError
from oma.modal import ModalModel

from . import _sim_kernel
from ._sim_result import SimulationResult
from ._sim_settings import (BackgroundForce, Effects, ForceSensorDynamics, NonlinearCutting, PoseDrift,
                            ProcessDamping, Runout, SensorModel, _positive)

__all__ = [
    "Runout",
    "ForceSensorDynamics",
    "ProcessDamping",
    "PoseDrift",
    "NonlinearCutting",
    "Effects",
    "BackgroundForce",
    "SensorModel",
    "SimulationResult",
    "SimulationDiverged",
    "simulate",
    "default_steps_per_tooth",
    "default_axial_slices",
]

#: Minimum internal steps per tooth period.
MIN_STEPS_PER_TOOTH = 50
#: Minimum internal steps per period of the fastest mode (or sensor resonance).
STEPS_PER_MODE_PERIOD = 20
#: Minimum ratio of the internal rate to the record rate and to the background bandwidth.
OVERSAMPLING = 4
#: Anti-alias cut-off as a fraction of the record's sample rate, and filter order (per pass).
ANTI_ALIAS_FRACTION = 0.4
ANTI_ALIAS_ORDER = 8
#: Default axial slices with a helix: at least this many ...
MIN_HELIX_SLICES = 12
#: ... and at most this much helix lag per slice, rad.
MAX_SLICE_LAG_RAD = math.radians(2.0)
#: Order of the Butterworth low-pass that shapes the background force.
BACKGROUND_ORDER = 4
#: Pose drift: at most this many piecewise-constant segments of the modal parameters.
MAX_DRIFT_SEGMENTS = 2048


class SimulationDiverged(InputError):
    """The response grew past the tool's own diameter: no milling model holds there.

    Raised by :func:`simulate` for a cut so far beyond its stability limit that the vibration
    grows without bound within the simulated time (the linear force model with the tool leaving
    the cut still lets it grow where the cutting stiffness exceeds the structure's). Such a cut
    is violent chatter; the record the simulation would give is not one a sensor could take.
    ``time_s`` is when the tool-tip displacement first exceeded ``bound_m``.
    """

    def __init__(self, axial_depth_m: float, time_s: float, bound_m: float):
        super().__init__(None, "axial_depth_m",
                         f"a depth whose response stays below the tool diameter ({bound_m * 1e3:g} mm) over the "
                         "simulated time",
                         f"{axial_depth_m:g} m (diverged at t = {time_s:.4g} s: violent chatter)")
        self.time_s = float(time_s)
        self.bound_m = float(bound_m)


# ----------------------------------------------------------------------------- discretisation
def default_steps_per_tooth(model: ModalModel, tooth_period_s: float, *, sample_rate_hz: float,
                            effects: Effects = Effects(), background: BackgroundForce | None = None) -> int:
    """Internal steps per tooth period by the module's step rule.

    ``max(50, ceil(20 f_hi T), ceil(4 fs T), ceil(4 B T))``, ``f_hi`` the highest natural frequency
    over the record (after pose drift) or the force-sensor resonance, whichever is higher.
    """
    f_hi = float(np.max(model.natural_frequency_hz)) if model.n_modes else 0.0
    if effects.pose_drift is not None:
        f_hi *= max(1.0, 1.0 + effects.pose_drift.relative_change)
    if effects.force_sensor is not None:
        f_hi = max(f_hi, effects.force_sensor.frequency_hz)
    candidates = [MIN_STEPS_PER_TOOTH, STEPS_PER_MODE_PERIOD * f_hi * tooth_period_s,
                  OVERSAMPLING * sample_rate_hz * tooth_period_s]
    if background is not None:
        candidates.append(OVERSAMPLING * background.bandwidth_hz * tooth_period_s)
    return int(math.ceil(max(candidates) - 1e-9))


def default_axial_slices(tool: Tool, axial_depth_m: float) -> int:
    """Axial slices: 1 for straight flutes (all slices would be equal), else ``max(12, ceil(lag /
    2 deg))`` with ``lag = 2 a tan(helix) / D`` the helix lag over the depth."""
    lag = 2.0 * axial_depth_m * math.tan(tool.helix_rad) / tool.diameter_m
    if lag == 0.0:
        return 1
    return max(MIN_HELIX_SLICES, int(math.ceil(abs(lag) / MAX_SLICE_LAG_RAD)))


# ----------------------------------------------------------------------------------- simulate
def simulate(model: ModalModel, tool: Tool, cut: Cut, coefficients: CuttingCoefficients | Material, *,
             duration_s: float, spindle_rpm: float | None = None, axial_depth_m: float | None = None,
             sample_rate_hz: float = 1000.0, effects: Effects = Effects(),
             background: BackgroundForce | None = None, sensors: SensorModel | None = None,
             regeneration: bool = True, axial_slices: int | None = None, steps_per_tooth: int | None = None,
             seed=None, progress: bool = False) -> SimulationResult:
    """Simulate a milling cut in the time domain.

    The tool starts fully engaged at ``t = 0`` with the structure at rest and an empty delay line
    (the surface ahead is the nominal one).

    Parameters
    ----------
    model : ModalModel
        Tool-tip dynamics, machine frame.
    tool : Tool
    cut : Cut
        Feed per tooth, radial depth, milling direction and the cutting frame ``f, n, a``.
    coefficients : CuttingCoefficients or Material
        Linear-plus-edge force model (a material must carry coefficients).
    duration_s : float
        Simulated time, s.
    spindle_rpm, axial_depth_m : float, optional
        Default: the cut's.
    sample_rate_hz : float
        Record rate of the measured signals, Hz.
    effects : Effects
        Effects beyond the simple model; all off by default.
    background : BackgroundForce, optional
        Broadband force on the structure (and in the measured force).
    sensors : SensorModel, optional
        Default: ideal sensors (no noise, no quantisation) with the anti-alias filter.
    regeneration : bool
        ``False``: forced vibration only, ``h = fz sin(phi)``.
    axial_slices : int, optional
        Default :func:`default_axial_slices`.
    steps_per_tooth : int, optional
        Default :func:`default_steps_per_tooth`.
    seed : int or numpy.random.Generator or None
        Seeds ``numpy.random.default_rng`` for the background force and the sensor noise.
    progress : bool
        Show a tqdm progress bar on standard error.

    Returns
    -------
    SimulationResult

    Raises
    ------
    InputError
        A parameter out of range (message ``<input>: field: expected ..., found ...``).
    SimulationDiverged
        The tool-tip displacement grew past the tool diameter (a cut far beyond its limit).
    """
    if isinstance(coefficients, Material):
        if coefficients.cutting_coefficients is None:
            raise InputError(None, "material.cutting_coefficients", "cutting coefficients", "None")
        coefficients = coefficients.cutting_coefficients
    rpm = _positive(cut.spindle_rpm if spindle_rpm is None else spindle_rpm, "spindle_rpm")
    depth = _positive(cut.axial_depth_m if axial_depth_m is None else axial_depth_m, "axial_depth_m",
                      allow_zero=True)
    duration = _positive(duration_s, "duration_s")
    fs = _positive(sample_rate_hz, "sample_rate_hz")
    fz = _positive(cut.feed_per_tooth_m, "cut.feed_per_tooth_m", allow_zero=True)
    teeth = int(tool.teeth)
    if teeth < 1:
        raise InputError(None, "tool.teeth", "an integer >= 1", repr(tool.teeth))
    diameter = _positive(tool.diameter_m, "tool.diameter_m")
    sensors = SensorModel() if sensors is None else sensors
    frame = np.asarray(cut.frame, dtype=float)
    if not np.allclose(frame @ frame.T, np.eye(3), atol=1e-6):
        raise InputError(None, "cut.normal_direction", "a unit vector perpendicular to the unit feed_direction",
                         f"f = {cut.feed_direction.tolist()}, n = {cut.normal_direction.tolist()}")
    cut = replace(cut, spindle_rpm=rpm, axial_depth_m=depth)

    tooth_period = 60.0 / (teeth * rpm)
    if steps_per_tooth is None:
        spt = default_steps_per_tooth(model, tooth_period, sample_rate_hz=fs, effects=effects,
                                      background=background)
    else:
        spt = int(steps_per_tooth)
        if spt < 2 or spt != steps_per_tooth:
            raise InputError(None, "steps_per_tooth", "an integer >= 2", repr(steps_per_tooth))
    if spt / tooth_period < 2.0 * fs:
        raise InputError(None, "steps_per_tooth", f"an internal rate >= twice the record rate ({2 * fs:g} Hz)",
                         f"{spt / tooth_period:g} Hz")
    n_slices = default_axial_slices(tool, depth) if axial_slices is None else int(axial_slices)
    if n_slices < 1 or (axial_slices is not None and n_slices != axial_slices):
        raise InputError(None, "axial_slices", "an integer >= 1", repr(axial_slices))

    step = tooth_period / spt
    n_steps = int(math.ceil(duration / step - 1e-9))
    n_rec = int(math.floor(duration * fs + 1e-9))
    if n_rec < 2:
        raise InputError(None, "duration_s", f"at least two record samples (>= {2 / fs:g} s)", repr(duration_s))
    rng = np.random.default_rng(seed)

    # ---- structure: piecewise-constant modal parameters (one segment unless the pose drifts)
    omega0 = model.omega_rad_s
    mass = model.modal_mass_kg
    n_periods = int(math.ceil(n_steps / spt))
    if effects.pose_drift is not None and effects.pose_drift.relative_change != 0.0:
        seg_len = spt * int(math.ceil(n_periods / MAX_DRIFT_SEGMENTS))
        n_seg = int(math.ceil(n_steps / seg_len))
        t_mid = (np.arange(n_seg) + 0.5) * seg_len * step
        scale = 1.0 + effects.pose_drift.relative_change * np.minimum(t_mid, duration) / duration
        omegas = scale[:, None] * omega0[None, :]
    else:
        seg_len = max(n_steps, 1)
        omegas = omega0[None, :]
    phi_mats, g0, g1 = _sim_kernel.foh_matrices(omegas, model.damping_ratio, mass, step)

    # ---- cutting
    phi_st, phi_ex = engagement_angles(tool, cut)
    dz = depth / n_slices
    z_mid = (np.arange(n_slices) + 0.5) * dz
    lag = 2.0 * z_mid * math.tan(tool.helix_rad) / diameter
    coef = np.array([coefficients.Ktc_N_m2, coefficients.Krc_N_m2, coefficients.Kac_N_m2,
                     coefficients.Kte_N_m, coefficients.Kre_N_m, coefficients.Kae_N_m], dtype=float)
    drho = effects.runout.chip_increments(teeth) if effects.runout is not None else np.zeros(teeth)
    pd_coef = 0.0
    if effects.process_damping is not None:
        speed = np.pi * diameter * rpm / 60.0
        pd_coef = effects.process_damping.coefficient_N_m / speed
    nl_p, nl_href = 0.0, 1.0
    if effects.nonlinear_cutting is not None:
        nl_p = float(effects.nonlinear_cutting.exponent_p)
        href = effects.nonlinear_cutting.reference_chip_m
        nl_href = float(fz if href is None else href)
        if nl_p != 0.0 and nl_href <= 0.0:
            raise InputError(None, "effects.nonlinear_cutting.reference_chip_m", "a number > 0", repr(nl_href))

    bg = np.zeros((n_steps + 1, 3))
    if background is not None:
        if background.bandwidth_hz >= 0.5 / step:
            raise InputError(None, "background.bandwidth_hz", f"below the internal Nyquist frequency {0.5 / step:g} Hz",
                             f"{background.bandwidth_hz:g}")
        bg[:] = _sim_kernel.band_limited_noise(background.variance_N2, background.bandwidth_hz, BACKGROUND_ORDER,
                                              n_steps + 1, step, rng).T

    # ---- time stepping
    force = np.zeros((n_steps + 1, 3))
    disp = np.zeros((n_steps + 1, 3))
    q = np.zeros(model.n_modes)
    v = np.zeros(model.n_modes)
    args = (teeth, spt, lag, dz, coef, fz, float(phi_st), float(phi_ex), np.ascontiguousarray(drho),
            bool(regeneration), float(pd_coef), nl_p, nl_href, np.ascontiguousarray(frame),
            np.ascontiguousarray(model.directions), phi_mats, g0, g1, int(seg_len),
            np.ascontiguousarray(model.residual_compliance_m_N, dtype=float), bg, q, v, force, disp)
    if progress:
        from tqdm import tqdm

        chunk = max(spt, n_steps // 200)
        with tqdm(total=n_steps, unit="step", file=sys.stderr, desc="simulate") as bar:
            k = 0
            while k < n_steps:
                k_end = min(k + chunk, n_steps)
                _sim_kernel.run(k, k_end, *args)
                bar.update(k_end - k)
                k = k_end
                if not np.all(np.abs(disp[k]) <= diameter):
                    break
    else:
        _sim_kernel.run(0, n_steps, *args)
    out = ~(np.abs(disp) <= diameter).all(axis=1)  # NaN and inf count as out
    if out.any():
        raise SimulationDiverged(depth, float(np.argmax(out)) * step, diameter)
    force = force.T
    disp = disp.T

    # ---- sensors
    t_rec = np.arange(n_rec) / fs
    f_seen = force
    if effects.force_sensor is not None:
        f_seen = _sim_kernel.resonance_filter(effects.force_sensor.frequency_hz, effects.force_sensor.damping_ratio,
                                              force, step)
    cutoff = ANTI_ALIAS_FRACTION * fs if sensors.anti_alias else None
    f_meas = _sim_kernel.resample(f_seen, step, t_rec, cutoff_hz=cutoff, order=ANTI_ALIAS_ORDER)
    x_meas = _sim_kernel.resample(disp, step, t_rec - effects.channel_delay_s, cutoff_hz=cutoff,
                                  order=ANTI_ALIAS_ORDER)
    if sensors.force_noise_variance_N2 > 0.0:
        f_meas = f_meas + math.sqrt(sensors.force_noise_variance_N2) * rng.standard_normal(f_meas.shape)
    if sensors.displacement_noise_m > 0.0:
        x_meas = x_meas + sensors.displacement_noise_m * rng.standard_normal(x_meas.shape)
    f_meas = _sim_kernel.quantise(f_meas, sensors.force_resolution_N)
    x_meas = _sim_kernel.quantise(x_meas, sensors.displacement_resolution_m)

    return SimulationResult(
        time_s=np.arange(n_steps + 1) * step,
        force_N=force,
        displacement_m=disp,
        record_time_s=t_rec,
        measured_force_N=f_meas,
        measured_displacement_m=x_meas,
        sample_rate_hz=fs,
        steps_per_tooth=spt,
        axial_slices=n_slices,
        tool=tool,
        cut=cut,
        coefficients=coefficients,
        effects=effects,
        sensors=sensors,
        background=background,
        regeneration=bool(regeneration),
    )
