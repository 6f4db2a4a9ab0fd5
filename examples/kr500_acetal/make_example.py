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
- ``robot/``: the cell's robot, a KUKA KR 500 R2800-2 (URDF from kuka_robot_descriptions, Apache
  2.0, see ``robot/README.md``) with a 120 kg spindle on an offset bracket, ``robot.yaml``
  (``robomill-robot/1`` without joint stiffness: what ``robot calibrate`` fits);
- ``truth/robot_truth.yaml``: the joint stiffness and damping the poses were simulated with, and
  (``x_model_error``) what the truth has beyond the rigid-link model: link masses 12 % heavier
  than the URDF's and tilting compliance of the main bearings (joints 2 and 3 softer in proportion
  to the squared reach);
- ``poses/pose_*.yaml``: modal models "identified" at six robot poses along the path: the truth's
  four most compliant tool-tip modes (with identification noise: 1 % frequency, 10 % damping,
  5 % stiffness, 2 deg direction) in series with the spindle/tool modes;
- ``setup.yaml``: the planning setup; ``toolpath.yaml`` + ``toolpath.csv``: a path in the part
  frame (``workpiece_frame``) with the robot, its joints from inverse kinematics (rotation 0 about
  the tool axis);
- ``cuts.csv``: 12 test cuts with outcomes for ``robomill learn`` (6-18 krpm at the setup's
  engagement, at 0.4-2x the SDM limit of ``models/tool_mode.yaml``, marked by that limit).

The milling records (and ``truth/robot_at_cut.yaml``) are simulated with the paper's modal model
(10.5 / 24.8 / 9.6 Hz, along X / Y / Z) as before; the robot truth at the paper's pose (the middle
of the path) has its dominant modes at 9.0 and 11.0 Hz in the X-Z plane and 24.3 Hz along Y: the
joint stiffnesses were fitted to the paper's modes at that pose (a least-squares fit of the three
frequencies and stiffnesses with a weak prior on DOMAIN.md's KR500 values, rounded).

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
from oma._fields import dump_yaml
from oma.io import atomic_write
from planner.toolpath import Toolpath
from planner.toolpath_io import write_toolpath
from stability.setup import Limits, Setup
from stability.setup_io import write_setup
from stability.simulate import BackgroundForce, SensorModel, simulate

HERE = Path(__file__).resolve().parent
SEED = 20200532  # fixed: the example is regenerated bit for bit

# --- the paper's cell ---------------------------------------------------------------------------
# The robot: the KR 500 R2800-2's URDF (vendored in robot/), a spindle on an offset bracket (the tip
# 0.2 m off the flange axis, so the rotation about the tool axis moves the whole arm).
ROBOT_DIR = "robot"
URDF_NAME = "kr500_r2800_2.urdf"
LICENSE_NAME = "LICENSE-kuka-robot-descriptions"
ROBOT_DOC = {
    "format": "robomill-robot/1",
    "name": "KUKA KR 500 R2800-2 with a 120 kg milling spindle on an offset bracket",
    "urdf": URDF_NAME,
    "base_link": "base_link",
    "flange_link": "tool0",
    "tool": {"tip_m": [0.0, -0.2, 0.38], "axis": [0.0, 0.0, -1.0], "mass_kg": 120.0,
             "center_of_mass_m": [0.0, -0.12, 0.17], "inertia_kg_m2": [[3.5, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 1.2]]},
}
ROBOT_README = (
    "# The cell's robot\n\n"
    "`kr500_r2800_2.urdf` is the KUKA KR 500 R2800-2 description of kuka_robot_descriptions "
    "(Apache License 2.0, `LICENSE-kuka-robot-descriptions`), copied unchanged from the shared data "
    "directory. `robot.yaml` adds the spindle body; it has no joint stiffness: `robomill robot calibrate` "
    "fits it to the identified poses (`../poses/`).\n")
# The truth the identified poses come from: joint stiffness (N m/rad) fitted so that the truth at the
# paper's pose has the paper's modes, joint damping, and the model error beyond rigid links.
TRUTH_JOINT_STIFFNESS_N_M_RAD = (3.2e7, 6.9e6, 2.9e6, 1.1e6, 5.3e5, 7.9e5)
TRUTH_DAMPING_RATIO = (0.05, 0.05, 0.05, 0.04, 0.04, 0.04)
TRUTH_MASS_FACTOR = 1.12  # link masses and inertias 12 % above the URDF's
TRUTH_TILT = 0.6  # compliance of joints 2 and 3 times 1 + 0.6 (reach / reach at the paper's pose)^2
# The part frame: origin in front of the robot, the part's x along the machine's Y.
WORKPIECE_ORIGIN_M = (1.3, 0.0, 0.7)
WORKPIECE_RPY_DEG = (0.0, 0.0, 90.0)
# The paper's pose: the tool tip at the middle of the path (the part frame's origin), tool axis +Z,
# rotation 0 (the flange x axis along the feed +Y): URDF joint values of the KR 500 R2800-2, from
# inverse kinematics (branch 2: see paper_joints_deg()), rounded to 1e-4 deg.
PAPER_JOINTS_DEG = np.array([0.0, -81.2257, 129.0302, 180.0, -42.1955, 90.0])
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

# The path: 0.3 m along the part's x (the machine's +Y) through the part frame's origin; path
# parameter s in -0.02..1.08, 0..1 spanning the six identified poses (s = 0, 0.2, ..., 1).
N_PATH = 240
POSE_PARAMETERS = np.linspace(0.0, 1.0, 6)
POSE_NOISE_SEED = SEED + 1  # identification noise of the poses (its own stream: the records keep theirs)


def path_points_part(s) -> np.ndarray:
    """Tool-tip positions in the part frame at path parameters ``s``, m, (n, 3)."""
    s = np.asarray(s, dtype=float)
    return np.column_stack([-0.15 + 0.3 * s, np.zeros(s.size), np.zeros(s.size)])


def write_robot_files(out: Path):
    """The robot directory (URDF and licence copied when writing elsewhere than here) and the robot."""
    from planner.robot import read_robot

    directory = out / ROBOT_DIR
    directory.mkdir(parents=True, exist_ok=True)
    for name in (URDF_NAME, LICENSE_NAME):
        source, target = HERE / ROBOT_DIR / name, directory / name
        if source.resolve() != target.resolve():
            with atomic_write(target) as tmp:
                tmp.write_bytes(source.read_bytes())
    with atomic_write(directory / "README.md") as tmp:
        tmp.write_text(ROBOT_README, encoding="utf-8")
    with atomic_write(directory / "robot.yaml") as tmp:
        tmp.write_text(dump_yaml(ROBOT_DOC), encoding="utf-8")
    truth = dict(ROBOT_DOC, urdf=f"../{ROBOT_DIR}/{URDF_NAME}",
                 joints={"stiffness_N_m_rad": list(TRUTH_JOINT_STIFFNESS_N_M_RAD),
                         "damping_ratio": list(TRUTH_DAMPING_RATIO)},
                 x_model_error={"link_mass_factor": TRUTH_MASS_FACTOR, "tilting_compliance": TRUTH_TILT,
                                "tilting_joints": [2, 3], "reference": "reach at the paper's pose (joint 2 to tip)"})
    (out / "truth").mkdir(parents=True, exist_ok=True)
    with atomic_write(out / "truth" / "robot_truth.yaml") as tmp:
        tmp.write_text(dump_yaml(truth), encoding="utf-8")
    return read_robot(directory / "robot.yaml")


def machine_path(robot, s):
    """Positions (machine frame), tool axes and feed directions of the path at ``s``, and its joints
    (inverse kinematics at rotation 0, the branch kept along the path), rad."""
    from planner.robot.path import solve_path

    tp = _toolpath(path_points_part(s), None)
    machine = tp.in_machine_frame()
    n = machine.n_points
    axis = np.broadcast_to(np.asarray(machine.tool_axis, float), (n, 3))
    joints = solve_path(robot, machine.positions_m, axis, machine.feed_directions(), np.zeros(n), branch=2)
    return machine, joints


def truth_modes(robot, q):
    """The truth's compliant-joint modes at poses ``q`` (n, 6): the URDF's links 12 % heavier and the
    main bearings' tilting compliance (joints 2 and 3), beyond the rigid-link model."""
    from planner.robot.correction import reach_m
    from planner.robot.dynamics import robot_modes

    heavy = replace(robot, link_mass_kg=robot.link_mass_kg * TRUTH_MASS_FACTOR,
                    link_inertia_kg_m2=robot.link_inertia_kg_m2 * TRUTH_MASS_FACTOR,
                    damping_ratio=np.array(TRUTH_DAMPING_RATIO))
    reach = reach_m(robot, q)
    reference = reach_m(robot, np.radians(PAPER_JOINTS_DEG))[0]
    k = np.tile(np.array(TRUTH_JOINT_STIFFNESS_N_M_RAD), (reach.size, 1))
    tilt = 1.0 + TRUTH_TILT * (reach / reference) ** 2
    k[:, 1] /= tilt
    k[:, 2] /= tilt
    return robot_modes(heavy, q, stiffness=k)


def truth_model_at(robot, joints_deg, *, n_modes: int = 4, rng=None) -> ModalModel:
    """The truth's ``n_modes`` most compliant tool-tip modes at a pose (ascending frequency), with
    identification noise when ``rng`` is given (1 % frequency, 10 % damping, 5 % stiffness, 2 deg
    direction: what OMA of a few records gives)."""
    modes = truth_modes(robot, np.radians(joints_deg)[None])
    keep = np.sort(np.argsort(-modes.compliance_m_N[0])[:n_modes])
    fn, zeta = modes.frequency_hz[0, keep], modes.damping_ratio[0, keep]
    k, dirs = modes.stiffness_N_m[0, keep], np.array(modes.directions[0, keep])
    if rng is not None:
        fn = fn * (1 + 0.01 * rng.standard_normal(fn.size))
        zeta = zeta * (1 + 0.10 * rng.standard_normal(fn.size))
        k = k * (1 + 0.05 * rng.standard_normal(fn.size))
        tilt = np.radians(2.0) * rng.standard_normal((fn.size, 3))
        dirs = dirs + np.cross(tilt, dirs)
        dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    return ModalModel(fn, zeta, k, dirs, joints_deg=np.asarray(joints_deg, dtype=float),
                      source={"method": "simulated truth (robot with model error)"})


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
        record = replace(steady_part(record, LEAD_IN_S), sensors=SENSORS, robot_model="KUKA KR 500 R2800-2 (simulated)")
        directory = out / "records" / name
        write_record(record, directory)
        write_frf_csv(reference, directory / "reference_frf.csv")


def write_models(out: Path, robot) -> None:
    write_modal_model(ROBOT_AT_CUT, out / "truth" / "robot_at_cut.yaml")
    write_modal_model(TOOL_MODE, out / "models" / "tool_mode.yaml")
    write_modal_model(
        in_series(ROBOT_AT_CUT, TOOL_MODE, joints_deg=PAPER_JOINTS_DEG,
               source={"method": "robot truth + tool mode (simulated example)"}),
        out / "models" / "planning_model.yaml",
    )
    _, joints = machine_path(robot, POSE_PARAMETERS)
    rng = np.random.default_rng(POSE_NOISE_SEED)
    for i, q in enumerate(np.round(np.degrees(joints.joints_rad), 4)):
        write_modal_model(in_series(truth_model_at(robot, q, rng=rng), TOOL_MODE, joints_deg=q,
                                    source={"method": "simulated truth (robot with model error, identification "
                                                      "noise) + tool mode"}),
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


def _toolpath(positions_part, joints_deg, depth=None) -> Toolpath:
    n = positions_part.shape[0]
    return Toolpath(
        tool=TOOL, material=ACETAL, tool_axis=[0.0, 0.0, 1.0], positions_m=positions_part, joints_deg=joints_deg,
        spindle_rpm=np.full(n, 2700.0), feed_per_tooth_m=np.full(n, 0.0005), radial_depth_m=np.full(n, 0.006),
        axial_depth_m=np.full(n, 0.006) if depth is None else depth, milling=np.full(n, "down"), limits=LIMITS,
        robot_file=None, workpiece_origin_m=np.array(WORKPIECE_ORIGIN_M), workpiece_rpy_deg=np.array(WORKPIECE_RPY_DEG),
    )


def write_setup_and_toolpath(out: Path, robot) -> None:
    setup_cut = replace(PAPER_CUT, spindle_rpm=None, axial_depth_m=None)
    write_setup(Setup(tool=TOOL, cut=setup_cut, material=ACETAL, limits=LIMITS, name="kr500 acetal side milling"),
                out / "setup.yaml")
    # The path: 0.3 m along the part's x (machine +Y) through the six identified poses; the last 8 %
    # runs past the last one (flagged by `check --models`), and a middle stretch is cut 2.5x deeper
    # (where chatter is expected). Joints by inverse kinematics at rotation 0 (`posture` may do better).
    s = np.linspace(-0.02, 1.08, N_PATH)
    _, joints = machine_path(robot, s)
    depth = np.where((s > 0.4) & (s < 0.6), 0.015, 0.006)
    toolpath = replace(_toolpath(path_points_part(s), np.round(joints.joints_deg, 4), depth),
                       robot_file=str(out / ROBOT_DIR / "robot.yaml"))
    write_toolpath(toolpath, out / "toolpath.yaml")


#: The test cuts of ``cuts.csv``: speeds, and depths as multiples of the SDM limit of the tool
#: mode at the setup's engagement (capped at ``CUT_MAX_DEPTH_M``, under the setup's 30 mm), the
#: outcome that limit's; stable and chattering cuts alternate, as a shop's first cuts bracket it.
CUT_SPEEDS_RPM = (6000.0, 7000.0, 8000.0, 9000.0, 10000.0, 12000.0, 13000.0, 14000.0, 15000.0, 16000.0,
                  17000.0, 18000.0)
CUT_LIMIT_FACTORS = (0.5, 1.5, 0.6, 1.8, 0.4, 1.5, 0.5, 2.0, 0.7, 1.5, 0.5, 1.5)
CUT_MAX_DEPTH_M = 0.029


def write_cuts(out: Path) -> None:
    from planner.learn.likelihood import CHATTER, STABLE
    from planner.learn.outcomes_io import CutTable, write_cuts as write_cut_table
    from planner.learn.tables import reference_limits

    rpm, factor = np.array(CUT_SPEEDS_RPM), np.array(CUT_LIMIT_FACTORS)
    limit = reference_limits(TOOL_MODE, TOOL, PAPER_CUT, ACETAL.cutting_coefficients, rpm, method="sdm")
    depth = np.round(np.minimum(factor * limit, CUT_MAX_DEPTH_M), 5)  # to 10 um, as a shop writes them
    n = rpm.size
    cuts = CutTable(rpm, depth, np.full(n, PAPER_CUT.radial_depth_m), np.full(n, PAPER_CUT.milling == "down"),
                    np.where(depth < limit, STABLE, CHATTER), np.ones(n), np.full(n, np.nan), np.zeros(n, bool))
    write_cut_table(cuts, out / "cuts.csv")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(SEED)
    robot = write_robot_files(args.out)
    _, paper = machine_path(robot, [0.5, 0.6])
    if not np.allclose(paper.joints_deg[0], PAPER_JOINTS_DEG, atol=1e-4, rtol=0):
        raise RuntimeError(f"PAPER_JOINTS_DEG is not the pose at the middle of the path: {paper.joints_deg[0]}")
    write_models(args.out, robot)
    write_setup_and_toolpath(args.out, robot)
    write_cuts(args.out)
    write_records(args.out, rng)
    print(f"example written to {args.out}")


if __name__ == "__main__":
    main()
