"""Shared fixtures: valid example files of every robomill format (formats.md), for any test.

Each fixture writes a small, valid file (or record directory) under ``tmp_path`` and returns its
path. The YAML texts are the examples of formats.md; signals are deterministic (seeded) so a test
can recompute what the file holds. Keep this module to fixtures for valid files.
"""

from __future__ import annotations

import numpy as np
import pytest

RECORD_YAML = """\
format: robomill-record/1
name: kr500-acetal-2700rpm
sample_rate_hz: 1000.0
signals:
  file: {signal_file}
  columns:
    t:  {{quantity: time, unit: s}}
    Fx: {{quantity: force, axis: X, unit: N}}
    Fy: {{quantity: force, axis: Y, unit: N}}
    Fz: {{quantity: force, axis: Z, unit: N}}
    x:  {{quantity: displacement, axis: X, unit: um}}
    y:  {{quantity: displacement, axis: Y, unit: um}}
    z:  {{quantity: displacement, axis: Z, unit: um}}
tool:
  teeth: 2
  diameter_m: 0.0254
  helix_deg: 30.0
cut:
  spindle_rpm: 2700.0
  feed_per_tooth_m: 0.0005
  radial_depth_m: 0.006
  axial_depth_m: 0.006
  milling: down
  feed_direction: [0, 1, 0]
  normal_direction: [-1, 0, 0]
  window_s: [0.2, 0.9]
material:
  name: acetal
  cutting_coefficients:
    Ktc_N_m2: 1.2e8
    Krc_N_m2: 4.5e7
    Kac_N_m2: 2.0e7
    Kte_N_m: 2.0e3
    Kre_N_m: 3.0e3
    Kae_N_m: 5.0e2
robot:
  model: KUKA KR500-3
  joints_deg: [88.44, -13.62, 72.42, 180.90, 59.55, -0.67]
sensors:
  force: {{noise_variance_N2: 0.56, resolution_N: 0.75}}
  displacement: {{resolution_m: 1.5e-5}}
"""

#: Samples and rate of the example record (1 s at 1 kHz).
RECORD_SAMPLES = 1000
RECORD_RATE_HZ = 1000.0
RECORD_COLUMNS = ("t", "Fx", "Fy", "Fz", "x", "y", "z")


def record_signals() -> dict[str, np.ndarray]:
    """The example record's columns in file units (s, N, um), rounded like a DAQ export.

    Forces: mean cutting force plus the 45 Hz spindle and 90 Hz tooth-passing harmonics of the
    Nguyen & Melkote cut (2700 rpm, 2 flutes) and seeded Gaussian noise; displacements in um.
    """
    rng = np.random.default_rng(20200101)
    n = RECORD_SAMPLES
    t = np.arange(n) / RECORD_RATE_HZ
    out = {"t": np.round(t, 6)}
    for name, mean in (("Fx", -80.0), ("Fy", 120.0), ("Fz", 15.0)):
        f = mean + 40 * np.sin(2 * np.pi * 90 * t) + 10 * np.sin(2 * np.pi * 45 * t)
        out[name] = np.round(f + rng.normal(scale=15.0, size=n), 3)
    for name in ("x", "y", "z"):
        out[name] = np.round(30 * np.sin(2 * np.pi * 10.5 * t) + rng.normal(scale=5.0, size=n), 2)
    return out


def _write_record(directory, signal_file: str):
    directory.mkdir()
    (directory / "record.yaml").write_text(RECORD_YAML.format(signal_file=signal_file))
    cols = record_signals()
    if signal_file.endswith(".npz"):
        np.savez(directory / signal_file, **cols)
    else:
        lines = [",".join(RECORD_COLUMNS)]
        lines += [",".join(repr(float(cols[c][k])) for c in RECORD_COLUMNS)
                  for k in range(RECORD_SAMPLES)]
        (directory / signal_file).write_text("\n".join(lines) + "\n")
    return directory


@pytest.fixture
def valid_record_dir(tmp_path):
    """A ``robomill-record/1`` directory: the formats.md example, signals.csv (s, N, um)."""
    return _write_record(tmp_path / "record_csv", "signals.csv")


@pytest.fixture
def valid_record_npz_dir(tmp_path):
    """The same record with its signals in ``signals.npz``."""
    return _write_record(tmp_path / "record_npz", "signals.npz")


MODAL_YAML = """\
format: robomill-modal/1
pose: {joints_deg: [88.44, -13.62, 72.42, 180.90, 59.55, -0.67]}
modes:
  - {natural_frequency_hz: 10.5, damping_ratio: 0.05, stiffness_N_m: 1.5e6, direction: [1, 0, 0]}
  - {natural_frequency_hz: 24.8, damping_ratio: 0.04, stiffness_N_m: 3.0e6, direction: [0, 1, 0]}
residual_compliance_m_N: [[1.0e-9, 0, 0], [0, 1.0e-9, 0], [0, 0, 2.0e-9]]
source: {method: oma-h1, records: [rec1], fit_error: 0.03}
"""


@pytest.fixture
def valid_modal_file(tmp_path):
    """A ``robomill-modal/1`` file: the formats.md example (two modes, residual compliance)."""
    path = tmp_path / "model.yaml"
    path.write_text(MODAL_YAML)
    return path


SETUP_YAML = """\
format: robomill-setup/1
tool: {teeth: 2, diameter_m: 0.0254, helix_deg: 30.0}
cut:
  milling: down
  radial_depth_m: 0.006
  feed_per_tooth_m: 0.0005
  feed_direction: [0, 1, 0]
  normal_direction: [-1, 0, 0]
material: {name: acetal, cutting_coefficients: {Ktc_N_m2: 1.2e8, Krc_N_m2: 4.5e7, Kac_N_m2: 2.0e7,
           Kte_N_m: 2.0e3, Kre_N_m: 3.0e3, Kae_N_m: 5.0e2}}
limits:
  spindle_rpm: [500, 12000]
  axial_depth_m: [0.0005, 0.02]
  feed_per_tooth_m: [0.00005, 0.0006]
  spindle_power_W: 8000
  spindle_torque_N_m: 40
  max_force_N: 1500
  surface_location_error_m: 0.0001
  stability_margin: 0.8
"""


@pytest.fixture
def valid_setup_file(tmp_path):
    """A ``robomill-setup/1`` file: the formats.md example (no spindle speed or axial depth)."""
    path = tmp_path / "setup.yaml"
    path.write_text(SETUP_YAML)
    return path


TOOLPATH_YAML = """\
format: robomill-toolpath/1
tool: {teeth: 2, diameter_m: 0.0254, helix_deg: 30.0}
material: {name: acetal, cutting_coefficients: {Ktc_N_m2: 1.2e8, Krc_N_m2: 4.5e7}}
tool_axis: [0, 0, 1]
limits: {spindle_rpm: [500, 12000], max_force_N: 1500}
points: toolpath.csv
"""

TOOLPATH_CSV = """\
x_m,y_m,z_m,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,spindle_rpm,feed_per_tooth_m,radial_depth_m,axial_depth_m,milling
1.2,0.0,0.5,88.44,-13.62,72.42,180.90,59.55,-0.67,2700,0.0005,0.006,0.006,down
1.2,0.025,0.5,88.9,-13.5,72.3,180.90,59.6,-0.67,2700,0.0005,0.006,0.006,down
1.2,0.05,0.5,89.3,-13.4,72.2,180.90,59.7,-0.67,2700,0.0005,0.006,0.004,down
1.175,0.05,0.5,89.6,-13.2,72.0,180.90,59.8,-0.67,3000,0.0004,0.004,0.004,up
"""


@pytest.fixture
def valid_toolpath_file(tmp_path):
    """A ``robomill-toolpath/1`` YAML with its ``toolpath.csv`` (4 points: +Y, +Y, then -X)."""
    directory = tmp_path / "toolpath"
    directory.mkdir()
    (directory / "toolpath.csv").write_text(TOOLPATH_CSV)
    path = directory / "toolpath.yaml"
    path.write_text(TOOLPATH_YAML)
    return path


@pytest.fixture
def valid_frf_csv(tmp_path):
    """An FRF CSV (XX, YY, XY) sampled from the example modal model (formats.md), 0.5-60 Hz."""
    from oma.modal import ModalModel

    model = ModalModel([10.5, 24.8], [0.05, 0.04], [1.5e6, 3.0e6], [[1, 0, 0], [0.6, 0.8, 0]])
    freq = np.arange(1, 121) * 0.5
    g = model.receptance(freq)
    path = tmp_path / "frf.csv"
    lines = ["freq_hz,XX_re,XX_im,YY_re,YY_im,XY_re,XY_im"]
    for k, f in enumerate(freq):
        vals = [f, g[0, 0, k].real, g[0, 0, k].imag, g[1, 1, k].real, g[1, 1, k].imag,
                g[0, 1, k].real, g[0, 1, k].imag]
        lines.append(",".join(repr(float(v)) for v in vals))
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def example_record_signals():
    """The columns the example record files hold, in file units (s, N, um)."""
    return record_signals()
