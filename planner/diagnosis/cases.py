"""Hidden-effect cases: simulated records of a paper-like robot cell with one effect the model lacks.

The tests and the benchmark of the diagnosis draw an effect's parameters from a realistic range,
simulate records with it (:func:`stability.simulate.simulate`), and hand robomill a model without
it; the diagnosis must name the effect and recover its main parameter.

The cell (Nguyen & Melkote 2020, as in ``examples/kr500_acetal``): a KUKA KR500-like arm with
modes at 10.5 Hz (X, 1.5e6 N/m, 5 %), 24.8 Hz (Y, 3.0e6 N/m, 4 %) and 9.6 Hz (Z, 2.0e6 N/m, 5 %);
a 25.4 mm two-flute 30 deg helix end mill down-milling acetal at 2700 rpm, fz 0.5 mm, ae 6 mm, ap
6 mm, feed along Y; background force 250 N^2 per axis (band 400 Hz); force sensor noise 0.56 N^2;
a laser tracker quantising the displacement to 15 um; 1 kHz; 8 s of steady cutting after a 2 s
lead-in that is cut off (16 s for process damping). For pose drift the cell has a 1 um displacement
sensor (e.g. a laser interferometer or a tracker in its precise mode): fitted on the first half of
the record alone, the drift rate from a 15 um tracker scatters by 14 % rms (1 um: 5 %).

Parameter ranges (drawn uniformly from a seeded ``numpy.random.default_rng``):

=====================  ===================================================================
runout                 effective radial runout of the two teeth ``A |cos(phase)|`` 5-30 um,
                       phase within +-60 deg (with two teeth only ``A cos(phase)`` acts)
force_sensor_dynamics  resonance 150-400 Hz, damping 2-8 %
channel_delay          displacement lagging the force by 2-20 ms
process_damping        ``C`` 4e6-8e6 N/m in a 900 rpm cut (cutting speed 1.2 m/s), where it
                       raises the damping of the X mode 3-5 times and of the Y mode 2-3.5
                       times during the cut (16 s recorded: the notches it digs into the
                       closed-loop force spectrum at the modes are a few lines wide, and
                       their depth needs many cycles of the slow modes)
unmodeled_mode         40-60 Hz, 1.5e6-3e6 N/m, 2-5 %, random direction
cross_coupling         the X or the Y mode turned 20-45 deg out of its axis, about a random
                       axis perpendicular to it
pose_drift             natural frequencies changing by 5-15 % (either sign) over the record
nonlinear_cutting      size-effect exponent p 0.2-0.4 (reference chip: the feed per tooth)
cutting_coefficients   Ktc 12-30 % off (either sign), Krc, Kac and the edge terms up to 20 %
=====================  ===================================================================

Forms (``form=``, :data:`FORMS`; the first is the simulator's own): runout as an eccentric axis or
as unequal tooth radii (one tooth standing out by ``2 A``: :class:`~planner.diagnosis.forcemodel.
ToothRadiiRunout`); a delay of the displacement or of the force channel (the truth's sign says
which); a pose drift gradual or as a step at 15-40 % of the record (inside the fit half: the
displacement recomputed from the simulated force through the model with its frequencies stepped,
then quantised); a size effect as a power law or as the saturating law ``K ((h + h0) / (fz +
h0))^-q``, ``h0`` 5-20 % of the feed (the force difference of the two laws on a rigid tool,
through the record's anti-alias filter, added to the force and its response to the displacement;
the truth is the law's log-slope between ``fz / 4`` and ``fz``). Post-processed records come from
the simulator's ideal sensors, then get the cell's noise and quantisation.

Nuisance (``nuisance=True``), drawn per record from its own stream: the six coefficients off by up
to 20 % each (the record states the nominal ones), background variance 100-800 N^2 per axis and
band 300-450 Hz, helix 30 +- 5 deg (the record states 30 deg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Material, Sensors, Tool
from oma.modal import ModalModel
from stability.simulate import (BackgroundForce, Effects, ForceSensorDynamics, NonlinearCutting, PoseDrift,
                                ProcessDamping, Runout, SensorModel, simulate)

from .forcemodel import ToothRadiiRunout

__all__ = ["CAUSES", "FORMS", "HiddenEffectCase", "paper_like_cell", "hidden_effect_case", "MAIN_PARAMETER",
           "expected_cause"]

#: The causes robomill can name, ``none`` first.
CAUSES = ("none", "runout", "force_sensor_dynamics", "channel_delay", "process_damping", "unmodeled_mode",
          "cross_coupling", "pose_drift", "nonlinear_cutting", "cutting_coefficients")

#: The forms each effect can take in a record (the first is the simulator's own and the default).
FORMS = {
    "runout": ("eccentric_axis", "tooth_radii"),
    "channel_delay": ("displacement", "force"),
    "pose_drift": ("gradual", "step"),
    "nonlinear_cutting": ("power_law", "saturating"),
}

#: The parameter of each cause that a diagnosis must recover.
MAIN_PARAMETER = {
    "runout": "runout_amplitude_m",
    "force_sensor_dynamics": "sensor_frequency_hz",
    "channel_delay": "delay_s",
    "process_damping": "process_damping_coefficient_N_m",
    "unmodeled_mode": "natural_frequency_hz",
    "cross_coupling": "rotation_deg",
    "pose_drift": "relative_change",
    "nonlinear_cutting": "exponent_p",
    "cutting_coefficients": "Ktc_relative_change",
}

LEAD_IN_S = 2.0


@dataclass(frozen=True)
class Cell:
    """A robot cell: model, tool, cut, material, sensors, background."""

    model: ModalModel
    tool: Tool
    cut: Cut
    material: Material
    background: BackgroundForce
    sensors: SensorModel


def paper_like_cell(*, displacement_resolution_m: float = 1.5e-5) -> Cell:
    """The paper-like cell of the module notes."""
    model = ModalModel(
        natural_frequency_hz=[10.5, 24.8, 9.6], damping_ratio=[0.05, 0.04, 0.05],
        stiffness_N_m=[1.5e6, 3.0e6, 2.0e6], directions=np.eye(3),
        source={"method": "paper-like cell (simulated)"})
    tool = Tool(teeth=2, diameter_m=0.0254, helix_rad=math.radians(30.0))
    cut = Cut(feed_per_tooth_m=0.0005, radial_depth_m=0.006, milling="down", feed_direction=[0, 1, 0],
              normal_direction=[-1, 0, 0], spindle_rpm=2700.0, axial_depth_m=0.006)
    material = Material(name="acetal", cutting_coefficients=CuttingCoefficients(
        Ktc_N_m2=1.2e8, Krc_N_m2=4.5e7, Kac_N_m2=2.0e7, Kte_N_m=2.0e3, Kre_N_m=3.0e3, Kae_N_m=5.0e2))
    return Cell(model, tool, cut, material, BackgroundForce((250.0, 250.0, 250.0), 400.0),
                SensorModel(force_noise_variance_N2=0.56, displacement_resolution_m=displacement_resolution_m))


@dataclass(frozen=True)
class HiddenEffectCase:
    """Records with one hidden effect, the model robomill is given, and the truth.

    Attributes
    ----------
    cause : str
    seed : int
    records : tuple of Record
    model : ModalModel
        The model without the effect.
    truth : dict
        The effect's parameters, keyed like the diagnosis reports them.
    true_model : ModalModel
        The model the records were simulated with.
    effects : Effects
    """

    cause: str
    seed: int
    records: tuple
    model: ModalModel
    truth: dict
    true_model: ModalModel = field(repr=False)
    effects: Effects = field(repr=False, default=Effects())
    form: str = "default"
    nuisance: dict = field(default_factory=dict)


def _rotate(u, axis, angle):
    axis = axis / np.linalg.norm(axis)
    return (u * math.cos(angle) + np.cross(axis, u) * math.sin(angle)
            + axis * (axis @ u) * (1 - math.cos(angle)))


#: Recorded duration per cause, s: process damping needs more cycles of the slow robot modes (module notes).
DURATION_S = {"process_damping": 16.0}
#: Causes whose cell has a finer displacement sensor than the 15 um tracker (module notes).
FINE_RESOLUTION_M = {"pose_drift": 1e-6}


#: Ranges of the nuisance every record of a robust benchmark carries (module notes).
NUISANCE_COEFFICIENT = 0.20
NUISANCE_BACKGROUND_N2 = (100.0, 800.0)
NUISANCE_BANDWIDTH_HZ = (300.0, 450.0)
NUISANCE_HELIX_DEG = 5.0
#: Smallest relative change of Ktc or of Krc / Ktc that :func:`expected_cause` counts as a coefficient
#: error a diagnosis must name (the floor of :mod:`~planner.diagnosis.floors`).
COEFFICIENT_FLOOR = 0.10


def _law_force(tool: Tool, cut: Cut, coefficients: CuttingCoefficients, scale_of_chip, n_angles: int = 1024):
    """Rigid-tool force over a revolution with the cutting coefficients times ``scale_of_chip(h)``
    (a chip-thickness law of any form), machine frame, shape (3, n_angles); same discretisation as
    :func:`~planner.diagnosis.forcemodel.periodic_force`."""
    from stability.simulate import default_axial_slices
    from oma.cutting import engagement_angles

    teeth, depth = int(tool.teeth), float(cut.axial_depth_m)
    n_sl = default_axial_slices(tool, depth)
    dz = depth / n_sl
    lag = 2.0 * (np.arange(n_sl) + 0.5) * dz * math.tan(tool.helix_rad) / tool.diameter_m
    st, ex = engagement_angles(tool, cut)
    base = 2.0 * np.pi * np.arange(n_angles) / n_angles
    phi = (base[:, None, None] + 2.0 * np.pi * np.arange(teeth)[None, :, None] / teeth - lag) % (2.0 * np.pi)
    h = float(cut.feed_per_tooth_m) * np.sin(phi)
    on = (phi >= st) & (phi <= ex) & (h > 0.0)
    sc = np.where(on, scale_of_chip(np.where(on, h, 1.0)), 0.0)
    k = coefficients
    dft = np.where(on, (k.Ktc_N_m2 * sc * h + k.Kte_N_m) * dz, 0.0)
    dfr = np.where(on, (k.Krc_N_m2 * sc * h + k.Kre_N_m) * dz, 0.0)
    dfa = np.where(on, (k.Kac_N_m2 * sc * h + k.Kae_N_m) * dz, 0.0)
    cp, sp = np.cos(phi), np.sin(phi)
    f = np.vstack([np.sum(-dft * cp - dfr * sp, axis=(1, 2)), np.sum(dft * sp - dfr * cp, axis=(1, 2)),
                   np.sum(dfa, axis=(1, 2))])
    return np.asarray(cut.frame).T @ f


def _periodic_signal(f_rev, spindle_hz, t, sample_rate_hz):
    """A force given over one revolution, as the record samples it at times ``t`` (the record's
    zero-phase anti-alias filter applied to each harmonic), shape (3, t.size)."""
    from .forcemodel import anti_alias_gain

    n = f_rev.shape[1]
    spec = np.fft.rfft(f_rev, axis=-1) / n
    h = np.arange(spec.shape[1])
    gain = anti_alias_gain(h * spindle_hz, sample_rate_hz)
    coef = 2.0 * spec * gain[None, :]
    coef[:, 0] = spec[:, 0].real
    out = np.zeros((3, t.size))
    w = 2.0 * np.pi * spindle_hz * t
    for k in range(h.size):
        if gain[k] < 1e-6:
            break
        out += np.real(coef[:, k:k + 1] * np.exp(1j * k * w)[None, :])
    return out


def _quantise(x, step, rng):
    if not step:
        return x
    off = rng.uniform(0.0, step)
    return np.round((x + off) / step) * step - off


def _perturbed(coefficients: CuttingCoefficients, rel) -> CuttingCoefficients:
    k = coefficients
    return CuttingCoefficients(k.Ktc_N_m2 * (1 + rel[0]), k.Krc_N_m2 * (1 + rel[1]), k.Kac_N_m2 * (1 + rel[2]),
                               k.Kte_N_m * (1 + rel[3]), k.Kre_N_m * (1 + rel[4]), k.Kae_N_m * (1 + rel[5]))


def coefficient_changes(nominal: CuttingCoefficients, true: CuttingCoefficients) -> dict:
    """Relative changes of Ktc, Krc, Kac and of the ratio Krc / Ktc from ``nominal`` to ``true``."""
    return {"Ktc_relative_change": true.Ktc_N_m2 / nominal.Ktc_N_m2 - 1.0,
            "Krc_relative_change": true.Krc_N_m2 / nominal.Krc_N_m2 - 1.0,
            "Kac_relative_change": (true.Kac_N_m2 / nominal.Kac_N_m2 - 1.0) if nominal.Kac_N_m2 else 0.0,
            "ratio_relative_change": (true.Krc_N_m2 / true.Ktc_N_m2) / (nominal.Krc_N_m2 / nominal.Ktc_N_m2) - 1.0}


def expected_cause(case: "HiddenEffectCase") -> str:
    """The answer a diagnosis should give: the hidden effect; for a clean record whose (nuisance)
    coefficients are off by more than :data:`COEFFICIENT_FLOOR` in Ktc or in Krc / Ktc,
    ``cutting_coefficients`` (that record's only disagreement); else ``none``."""
    if case.cause != "none":
        return case.cause
    ch = case.nuisance.get("coefficients", {})
    big = max(abs(ch.get("Ktc_relative_change", 0.0)), abs(ch.get("ratio_relative_change", 0.0)))
    return "cutting_coefficients" if big >= COEFFICIENT_FLOOR else "none"


def hidden_effect_case(cause: str, seed: int, *, duration_s: float | None = None, sample_rate_hz: float = 1000.0,
                       cell: Cell | None = None, form: str | None = None, nuisance: bool = False) -> HiddenEffectCase:
    """Simulate a record of ``cell`` (default :func:`paper_like_cell`) with a hidden ``cause``.

    Parameters
    ----------
    cause : str
        One of :data:`CAUSES`.
    seed : int
        Seeds the parameter draw and the simulation's noise.
    duration_s : float, optional
        Steady cutting recorded, s (after a lead-in of 2 s that is discarded); default 8 s, 16 s for
        process damping.
    form : str, optional
        The effect's form (:data:`FORMS`; default the first, the simulator's own).
    nuisance : bool
        Give the record the nuisance of the module notes: cutting coefficients off by up to 20 %
        each, another background level and band, a helix 5 deg off (the record states the nominal
        ones).
    """
    if cause not in CAUSES:
        raise ValueError(f"cause must be one of {', '.join(CAUSES)}, not {cause!r}")
    forms = FORMS.get(cause, ("default",))
    form = forms[0] if form is None else form
    if form not in forms:
        raise ValueError(f"form of {cause} must be one of {', '.join(forms)}, not {form!r}")
    if cell is None:
        cell = paper_like_cell(displacement_resolution_m=FINE_RESOLUTION_M.get(cause, 1.5e-5))
    if duration_s is None:
        duration_s = DURATION_S.get(cause, 8.0)
    rng = np.random.default_rng([seed, CAUSES.index(cause)])
    model, cut = cell.model, cell.cut
    true_model = model
    effects = Effects()
    truth: dict = {}
    total = LEAD_IN_S + duration_s
    post = None  # post-processing of the record for forms the simulator does not make
    nominal_coef = cell.material.cutting_coefficients
    true_coef = nominal_coef
    if cause == "runout":
        a_eff = rng.uniform(5e-6, 30e-6)
        phase = rng.uniform(-math.pi / 3, math.pi / 3)
        if form == "eccentric_axis":
            effects = Effects(runout=Runout(a_eff / math.cos(phase), phase))
        else:  # one tooth stands out by 2 a_eff (rho = (2 a_eff, 0)); which one is random
            off = (2 * a_eff, 0.0) if phase >= 0 else (0.0, 2 * a_eff)
            effects = Effects(runout=ToothRadiiRunout(0.0, 0.0, off))
        truth = {"runout_amplitude_m": a_eff}
    elif cause == "force_sensor_dynamics":
        fs_hz, zeta = rng.uniform(150.0, 400.0), rng.uniform(0.02, 0.08)
        effects = Effects(force_sensor=ForceSensorDynamics(fs_hz, zeta))
        truth = {"sensor_frequency_hz": fs_hz, "sensor_damping_ratio": zeta}
    elif cause == "channel_delay":
        tau = rng.uniform(2e-3, 20e-3)
        # a force channel late by tau is a displacement channel early by tau
        tau = tau if form == "displacement" else -tau
        effects = Effects(channel_delay_s=tau)
        truth = {"delay_s": tau}
    elif cause == "process_damping":
        c = rng.uniform(4.0e6, 8.0e6)
        effects = Effects(process_damping=ProcessDamping(c))
        cut = replace(cut, spindle_rpm=900.0)
        truth = {"process_damping_coefficient_N_m": c}
    elif cause == "unmodeled_mode":
        fn, k, zeta = rng.uniform(40.0, 60.0), rng.uniform(1.5e6, 3.0e6), rng.uniform(0.02, 0.05)
        u = rng.standard_normal(3)
        u /= np.linalg.norm(u)
        true_model = ModalModel(np.append(model.natural_frequency_hz, fn), np.append(model.damping_ratio, zeta),
                                np.append(model.stiffness_N_m, k), np.vstack([model.directions, u]))
        truth = {"natural_frequency_hz": fn, "stiffness_N_m": k, "damping_ratio": zeta, "direction": u.tolist()}
    elif cause == "cross_coupling":
        r = int(rng.integers(2))
        angle = math.radians(rng.uniform(20.0, 45.0))
        u = model.directions[r]
        axis = rng.standard_normal(3)
        axis -= (axis @ u) * u
        dirs = np.array(model.directions)
        dirs[r] = _rotate(u, axis, angle)
        true_model = replace(model, directions=dirs)
        truth = {"rotation_deg": math.degrees(angle), "mode_index": r, "direction": dirs[r].tolist()}
    elif cause == "pose_drift":
        change = rng.uniform(0.05, 0.15) * (1 if rng.uniform() < 0.5 else -1)
        if form == "gradual":
            # the simulator drifts from its t = 0: choose the rate so the record itself sees `change`
            rate = change / (1.0 - LEAD_IN_S / total * (1.0 + change))
            effects = Effects(pose_drift=PoseDrift(rate))
        else:
            # a step inside the fit half (a step in the validation half leaves nothing to fit)
            t_step = LEAD_IN_S + rng.uniform(0.15, 0.4) * duration_s
            post = ("step_drift", t_step, change)
        truth = {"relative_change": change}
    elif cause == "nonlinear_cutting":
        p = rng.uniform(0.2, 0.4)
        if form == "power_law":
            effects = Effects(nonlinear_cutting=NonlinearCutting(p))
        else:
            # K ~ ((h + h0) / (fz + h0))^-q: finite as h -> 0; q such that the log-slope of K
            # between fz / 4 and fz (the effective exponent) is p
            fz = float(cut.feed_per_tooth_m)
            h0 = rng.uniform(0.05, 0.2) * fz
            q = p * math.log(4.0) / math.log((fz + h0) / (fz / 4 + h0))
            post = ("saturating", h0, q)
        truth = {"exponent_p": p}
    elif cause == "cutting_coefficients":
        # 12-30 % in Ktc (either sign), up to 20 % in Krc and Kac, edge terms up to 20 %
        rel = rng.uniform(-NUISANCE_COEFFICIENT, NUISANCE_COEFFICIENT, 6)
        rel[0] = rng.uniform(0.12, 0.30) * (1 if rng.uniform() < 0.5 else -1)
        true_coef = _perturbed(nominal_coef, rel)
        truth = coefficient_changes(nominal_coef, true_coef)
    # ---- nuisance: every record's own coefficients, background and helix
    nrng = np.random.default_rng([seed, CAUSES.index(cause), 99])
    sim_tool, background = cell.tool, cell.background
    nuis: dict = {}
    if nuisance:
        if cause != "cutting_coefficients":
            true_coef = _perturbed(nominal_coef, nrng.uniform(-NUISANCE_COEFFICIENT, NUISANCE_COEFFICIENT, 6))
        var = nrng.uniform(*NUISANCE_BACKGROUND_N2, 3)
        background = BackgroundForce(tuple(var), float(nrng.uniform(*NUISANCE_BANDWIDTH_HZ)))
        helix = cell.tool.helix_rad + math.radians(nrng.uniform(-NUISANCE_HELIX_DEG, NUISANCE_HELIX_DEG))
        sim_tool = replace(cell.tool, helix_rad=helix)
        nuis = {"background_variance_N2": var.tolist(), "background_bandwidth_hz": background.bandwidth_hz,
                "helix_deg": math.degrees(helix)}
    nuis["coefficients"] = coefficient_changes(nominal_coef, true_coef)
    sensors = cell.sensors
    if post is not None:  # the simulator's ideal sensors; noise and quantisation added after
        sensors = SensorModel()
    sim = simulate(true_model, sim_tool, cut, true_coef, duration_s=total, sample_rate_hz=sample_rate_hz,
                   effects=effects, background=background, sensors=sensors, seed=int(rng.integers(2**31)))
    rec = sim.to_record(cell.tool, cut, material=cell.material, name=f"{cause}-{seed}")
    if post is not None:
        rec = replace(rec, data=_post_process(post, sim, rec, true_model, sim_tool, cut, true_coef, cell,
                                              sample_rate_hz, rng))
    n0 = int(round(LEAD_IN_S * sample_rate_hz))
    rec = replace(rec, data=rec.data[:, n0:], time_s=None,
                  sensors=Sensors(force_noise_variance_N2=cell.sensors.force_noise_variance_N2,
                                  displacement_resolution_m=cell.sensors.displacement_resolution_m or None))
    return HiddenEffectCase(cause=cause, seed=seed, records=(rec,), model=model, truth=truth,
                            true_model=true_model, effects=effects, form=form, nuisance=nuis)


def _post_process(post, sim, rec, true_model, tool, cut, coef, cell, fs, rng):
    """Record data (force X Y Z, displacement X Y Z) of the forms the simulator does not make,
    from its run with ideal sensors; then the cell's sensor noise and quantisation."""
    from .response import modal_response

    force = np.array(sim.measured_force_N, dtype=float)
    disp = np.array(sim.measured_displacement_m, dtype=float)
    t = sim.record_time_s
    spindle_hz = float(cut.spindle_rpm) / 60.0
    if post[0] == "saturating":
        _, h0, q = post
        fz = float(cut.feed_per_tooth_m)
        sat = _law_force(tool, cut, coef, lambda h: ((h + h0) / (fz + h0)) ** (-q))
        lin = _law_force(tool, cut, coef, lambda h: np.ones_like(h))
        extra = _periodic_signal(sat - lin, spindle_hz, t, fs)
        force = force + extra
        disp = disp + modal_response(true_model, extra, fs)
    elif post[0] == "step_drift":
        _, t_step, change = post
        k = int(round(t_step * fs))
        disp = modal_response(true_model, force, fs, frequency_scale=[1.0, 1.0 + change], segment_starts=[0, k])
    force = force + math.sqrt(cell.sensors.force_noise_variance_N2) * rng.standard_normal(force.shape)
    disp = _quantise(disp, cell.sensors.displacement_resolution_m, rng)
    data = np.array(rec.data, dtype=float)
    data[:3], data[3:6] = force, disp
    return data
