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
=====================  ===================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Material, Sensors, Tool
from oma.modal import ModalModel
from stability.simulate import (BackgroundForce, Effects, ForceSensorDynamics, NonlinearCutting, PoseDrift,
                                ProcessDamping, Runout, SensorModel, simulate)

__all__ = ["CAUSES", "HiddenEffectCase", "paper_like_cell", "hidden_effect_case", "MAIN_PARAMETER"]

#: The causes robomill can name, ``none`` first.
CAUSES = ("none", "runout", "force_sensor_dynamics", "channel_delay", "process_damping", "unmodeled_mode",
          "cross_coupling", "pose_drift", "nonlinear_cutting")

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


def _rotate(u, axis, angle):
    axis = axis / np.linalg.norm(axis)
    return (u * math.cos(angle) + np.cross(axis, u) * math.sin(angle)
            + axis * (axis @ u) * (1 - math.cos(angle)))


#: Recorded duration per cause, s: process damping needs more cycles of the slow robot modes (module notes).
DURATION_S = {"process_damping": 16.0}
#: Causes whose cell has a finer displacement sensor than the 15 um tracker (module notes).
FINE_RESOLUTION_M = {"pose_drift": 1e-6}


def hidden_effect_case(cause: str, seed: int, *, duration_s: float | None = None, sample_rate_hz: float = 1000.0,
                       cell: Cell | None = None) -> HiddenEffectCase:
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
    """
    if cause not in CAUSES:
        raise ValueError(f"cause must be one of {', '.join(CAUSES)}, not {cause!r}")
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
    if cause == "runout":
        a_eff = rng.uniform(5e-6, 30e-6)
        phase = rng.uniform(-math.pi / 3, math.pi / 3)
        effects = Effects(runout=Runout(a_eff / math.cos(phase), phase))
        truth = {"runout_amplitude_m": a_eff}
    elif cause == "force_sensor_dynamics":
        fs_hz, zeta = rng.uniform(150.0, 400.0), rng.uniform(0.02, 0.08)
        effects = Effects(force_sensor=ForceSensorDynamics(fs_hz, zeta))
        truth = {"sensor_frequency_hz": fs_hz, "sensor_damping_ratio": zeta}
    elif cause == "channel_delay":
        tau = rng.uniform(2e-3, 20e-3)
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
        # the simulator drifts from its t = 0: choose the rate so the record itself sees `change`
        rate = change / (1.0 - LEAD_IN_S / total * (1.0 + change))
        effects = Effects(pose_drift=PoseDrift(rate))
        truth = {"relative_change": change}
    elif cause == "nonlinear_cutting":
        p = rng.uniform(0.2, 0.4)
        effects = Effects(nonlinear_cutting=NonlinearCutting(p))
        truth = {"exponent_p": p}
    sim = simulate(true_model, cell.tool, cut, cell.material, duration_s=total, sample_rate_hz=sample_rate_hz,
                   effects=effects, background=cell.background, sensors=cell.sensors,
                   seed=int(rng.integers(2**31)))
    rec = sim.to_record(cell.tool, cut, material=cell.material, name=f"{cause}-{seed}")
    n0 = int(round(LEAD_IN_S * sample_rate_hz))
    rec = replace(rec, data=rec.data[:, n0:], time_s=None,
                  sensors=Sensors(force_noise_variance_N2=cell.sensors.force_noise_variance_N2,
                                  displacement_resolution_m=cell.sensors.displacement_resolution_m or None))
    return HiddenEffectCase(cause=cause, seed=seed, records=(rec,), model=model, truth=truth,
                            true_model=true_model, effects=effects)
