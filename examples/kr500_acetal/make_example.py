"""Regenerate the bundled example robot cell, deterministically (``make example``).

Everything written here is SIMULATED, by robomill's own time-domain simulator, with the parameters
below. They reproduce the experiment of Nguyen & Melkote (Procedia Manufacturing 2020): a KUKA
KR500-3 slot-side milling acetal at 2700 rpm with a 25.4 mm 2-flute end mill (fz 0.5 mm, ae 6 mm,
ap 6 mm, feed along Y), forces from a flange force sensor and tool-tip displacement from a laser
tracker, both at 1 kHz.

Written files (relative to this directory):

- ``records/cut_short/``: 1.1 s, as long as the paper's 50 mm cut, with ``reference_frf.csv``;
- ``records/cut_long/``: 20 s of the same cut, with ``reference_frf.csv``;
- ``truth/robot_at_cut.yaml``: the modal model the records were simulated with;
- ``models/tool_mode.yaml``: the spindle/tool mode, in series with the robot;
- ``models/planning_model.yaml``: robot + tool, what the planner uses before identification;
- ``poses/pose_*.yaml``: modal models at six robot poses (pose-dependent dynamics);
- ``setup.yaml``: the planning setup; ``toolpath.yaml`` + ``toolpath.csv``: a path across the poses.

Run with ``python examples/kr500_acetal/make_example.py [--out DIR]``.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Material, Sensors, Tool
from oma.frf_io import write_frf_csv
from oma.frf_table import FRFTable
from oma.modal import ModalModel, in_series
from oma.modal_io import write_modal_model
from oma.record import Record
from oma.record_io import write_record
from planner.toolpath import Toolpath
from planner.toolpath_io import write_toolpath
from stability.setup import Limits, Setup
from stability.setup_io import write_setup
from stability.simulate import BackgroundForce, SensorModel, simulate

HERE = Path(__file__).resolve().parent
SEED = 20200532  # fixed: the example is regenerated bit for bit

# --- the paper's cell ---------------------------------------------------------------------------
PAPER_JOINTS_DEG = np.array([88.44, -13.62, 72.42, 180.90, 59.55, -0.67])
TOOL = Tool(teeth=2, diameter_m=0.0254, helix_rad=np.deg2rad(30.0))
ACETAL = Material(
    name="acetal",
    cutting_coefficients=CuttingCoefficients(
        Ktc_N_m2=1.2e8, Krc_N_m2=4.5e7, Kac_N_m2=2.0e7, Kte_N_m=2.0e3, Kre_N_m=3.0e3, Kae_N_m=5.0e2
    ),
)
PAPER_CUT = Cut(
    spindle_rpm=2700.0,
    feed_per_tooth_m=0.0005,
    radial_depth_m=0.006,
    axial_depth_m=0.006,
    milling="down",
    feed_direction=[0, 1, 0],
    normal_direction=[-1, 0, 0],
)
# Background (non-harmonic) force variance per machine axis, N^2: the paper's measured values.
BACKGROUND_VARIANCE_N2 = (232.0, 278.0, 251.0)
BACKGROUND_BANDWIDTH_HZ = 250.0  # well inside the 400 Hz anti-alias filter of the record
SENSORS = Sensors(force_noise_variance_N2=0.56, force_resolution_N=0.75, displacement_resolution_m=1.5e-5)

# Robot modes at the paper's pose: ~10 Hz in X and Z, ~25 Hz in Y (the paper's Fig. 6). Stiffness
# and damping are chosen so that the paper's detectability figure holds: white force noise of about
# 75 N^2 through the Y mode gives a peak-to-valley response near the tracker's 15 um in 1.1 s.
ROBOT_AT_CUT = ModalModel(
    natural_frequency_hz=[10.5, 24.8, 9.6],
    damping_ratio=[0.05, 0.04, 0.05],
    stiffness_N_m=[1.5e6, 3.0e6, 2.0e6],
    directions=[[1, 0, 0], [0, 1, 0], [0, 0, 1]],
    joints_deg=PAPER_JOINTS_DEG,
    source={"method": "simulated truth", "records": []},
)
# The spindle/tool mode in series with the robot (compliances add): it puts lobes at usual spindle
# speeds (tooth-passing 720 Hz at 21600 rpm with 2 teeth) and dips below the robot's limit between them.
TOOL_MODE = ModalModel(
    natural_frequency_hz=[720.0, 735.0],
    damping_ratio=[0.02, 0.02],
    stiffness_N_m=[4.0e6, 4.4e6],
    directions=[[1, 0, 0], [0, 1, 0]],
    source={"method": "assumed spindle/tool mode (simulated example)"},
)

# Pose dependence: six poses along the cell's working line. Natural frequencies, stiffness and the
# in-plane mode directions vary smoothly with the joints (the base joint q1 turns the arm's principal
# compliance directions about Z). Synthetic but of the size measured on real arms (10-30 %).
POSE_JOINTS_DEG = np.array(
    [
        [78.0, -20.0, 80.0, 180.9, 59.55, -0.67],
        [82.0, -17.5, 77.0, 180.9, 59.55, -0.67],
        [86.0, -15.0, 74.5, 180.9, 59.55, -0.67],
        [90.0, -12.5, 71.0, 180.9, 59.55, -0.67],
        [94.0, -10.0, 68.0, 180.9, 59.55, -0.67],
        [98.0, -7.5, 65.0, 180.9, 59.55, -0.67],
    ]
)


def robot_model_at(joints_deg) -> ModalModel:
    """The (synthetic) robot modal model at a pose: smooth in the joints, equal to ROBOT_AT_CUT at
    the paper's pose."""
    q = np.deg2rad(np.asarray(joints_deg, dtype=float) - PAPER_JOINTS_DEG)
    reach = np.sin(q[1]) - 0.8 * np.sin(q[2])  # arm stretching out: softer, lower modes
    freq = ROBOT_AT_CUT.natural_frequency_hz * (1.0 - 0.6 * reach) * np.array([1.0, 1.0 + 0.3 * q[0], 1.0])
    stiff = ROBOT_AT_CUT.stiffness_N_m * (1.0 - 1.0 * reach)
    zeta = ROBOT_AT_CUT.damping_ratio * (1.0 + 0.5 * reach)
    c, s = np.cos(q[0]), np.sin(q[0])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    dirs = ROBOT_AT_CUT.directions @ rot.T
    return ModalModel(freq, zeta, stiff, dirs, joints_deg=np.asarray(joints_deg, dtype=float),
                      source={"method": "simulated truth (pose model)"})


def hammer_reference(model: ModalModel, rng: np.random.Generator) -> FRFTable:
    """A hammer-test FRF of the robot modes: the model's direct receptances, 2-60 Hz at 0.25 Hz,
    with 3 % complex measurement noise (a good impact test; the hammer test is a separate measurement
    and is used only to validate identification)."""
    freq = np.arange(2.0, 60.0 + 1e-9, 0.25)
    g = model.receptance(freq)
    entries = {}
    for i, name in enumerate(("XX", "YY", "ZZ")):
        noise = 0.03 * (rng.standard_normal(freq.size) + 1j * rng.standard_normal(freq.size)) / np.sqrt(2)
        entries[name] = g[i, i] * (1.0 + noise)
    return FRFTable.from_entries(freq, entries, meta={"method": "impact hammer (simulated)"})


# The simulator starts with the tool fully engaged and the structure at rest; the 10 Hz modes take
# about 1/(zeta w) = 0.3 s to settle, so each record is cut from a longer run after this lead-in
# (the paper's records are of steady cutting).
LEAD_IN_S = 2.0


def steady_part(record: Record, start_s: float) -> Record:
    """The record from ``start_s`` on, its clock restarted at 0."""
    n0 = int(round(start_s * record.sample_rate_hz))
    return replace(record, data=record.data[:, n0:],
                   time_s=None if record.time_s is None else record.time_s[n0:] - record.time_s[n0])


def write_records(out: Path, rng: np.random.Generator) -> None:
    reference = hammer_reference(ROBOT_AT_CUT, rng)
    for name, duration in (("cut_short", 1.1), ("cut_long", 20.0)):
        result = simulate(
            ROBOT_AT_CUT, TOOL, PAPER_CUT, ACETAL.cutting_coefficients,
            duration_s=LEAD_IN_S + duration, sample_rate_hz=1000.0,
            background=BackgroundForce(variance_N2=BACKGROUND_VARIANCE_N2, bandwidth_hz=BACKGROUND_BANDWIDTH_HZ),
            sensors=SensorModel(force_noise_variance_N2=SENSORS.force_noise_variance_N2,
                                displacement_resolution_m=SENSORS.displacement_resolution_m),
            seed=int(rng.integers(2**31)),
        )
        record = result.to_record(TOOL, PAPER_CUT, material=ACETAL, name=f"kr500-acetal-2700rpm-{name}",
                                  joints_deg=PAPER_JOINTS_DEG)
        record = replace(steady_part(record, LEAD_IN_S), sensors=SENSORS, robot_model="KUKA KR500-3 (simulated)")
        directory = out / "records" / name
        write_record(record, directory)
        write_frf_csv(reference, directory / "reference_frf.csv")


def write_models(out: Path) -> None:
    write_modal_model(ROBOT_AT_CUT, out / "truth" / "robot_at_cut.yaml")
    write_modal_model(TOOL_MODE, out / "models" / "tool_mode.yaml")
    write_modal_model(
        in_series(ROBOT_AT_CUT, TOOL_MODE, joints_deg=PAPER_JOINTS_DEG,
               source={"method": "robot truth + tool mode (simulated example)"}),
        out / "models" / "planning_model.yaml",
    )
    for i, joints in enumerate(POSE_JOINTS_DEG):
        write_modal_model(in_series(robot_model_at(joints), TOOL_MODE, joints_deg=joints,
                                 source={"method": "simulated truth (pose model) + tool mode"}),
                          out / "poses" / f"pose_{i + 1}.yaml")


LIMITS = Limits(
    spindle_rpm=(500.0, 24000.0),
    axial_depth_m=(0.0005, 0.03),
    feed_per_tooth_m=(0.00005, 0.0006),
    spindle_power_W=8000.0,
    spindle_torque_N_m=40.0,
    max_force_N=1500.0,
    surface_location_error_m=0.0003,
    stability_margin=0.8,
)


def write_setup_and_toolpath(out: Path) -> None:
    setup_cut = replace(PAPER_CUT, spindle_rpm=None, axial_depth_m=None)
    write_setup(Setup(tool=TOOL, cut=setup_cut, material=ACETAL, limits=LIMITS, name="kr500 acetal side milling"),
                out / "setup.yaml")
    # The path: 0.3 m along +Y at the table, the joints moving through the six poses; the last 8 %
    # of the path runs past the last identified pose (flagged by `check`), and a middle stretch is cut
    # 2.5x deeper (where chatter is expected).
    n = 240
    s = np.linspace(-0.02, 1.08, n)  # path parameter; 0..1 spans the identified poses
    positions = np.column_stack([np.full(n, 1.2), -0.15 + 0.3 * s, np.full(n, 0.4)])
    knots = np.linspace(0.0, 1.0, len(POSE_JOINTS_DEG))
    joints = np.column_stack([np.interp(s, knots, POSE_JOINTS_DEG[:, j], left=np.nan, right=np.nan)
                              for j in range(6)])
    # beyond the identified span the joints keep moving at the same rate (linear extrapolation)
    for j in range(6):
        slope = (POSE_JOINTS_DEG[-1, j] - POSE_JOINTS_DEG[0, j]) / (knots[-1] - knots[0])
        joints[:, j] = np.where(s < 0, POSE_JOINTS_DEG[0, j] + slope * s, joints[:, j])
        joints[:, j] = np.where(s > 1, POSE_JOINTS_DEG[-1, j] + slope * (s - 1), joints[:, j])
    depth = np.where((s > 0.4) & (s < 0.6), 0.015, 0.006)
    toolpath = Toolpath(
        tool=TOOL, material=ACETAL, tool_axis=[0.0, 0.0, 1.0], positions_m=positions, joints_deg=joints,
        spindle_rpm=np.full(n, 2700.0), feed_per_tooth_m=np.full(n, 0.0005), radial_depth_m=np.full(n, 0.006),
        axial_depth_m=depth, milling=np.full(n, "down"), limits=LIMITS,
    )
    write_toolpath(toolpath, out / "toolpath.yaml")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(SEED)
    write_models(args.out)
    write_setup_and_toolpath(args.out)
    write_records(args.out, rng)
    print(f"example written to {args.out}")


if __name__ == "__main__":
    main()
