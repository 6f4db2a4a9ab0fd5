"""Chatter detection (part (c)): simulated stable and chattering cuts, aliasing, the measured CNC cuts.

Ground truth: the simulator's cuts at depths the stability analysis puts on either side of the
limit (zero-order approximation: Hopf lobe at 2700 rpm; semi-discretization: flip lobe at 1000
rpm), synthetic signals with known aliased lines, and what is known about the Hurco files (spindle
speed and flutes from the file name).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from oma.errors import InputError
from planner.diagnosis.cases import paper_like_cell
from planner.diagnosis.chatter import detect_chatter, refine_spindle_frequency_aliased
from planner.diagnosis.compare import compare_records
from planner.diagnosis.hurco import DEFAULT_DIRECTORY, hurco_table, read_hurco_csv
from planner.diagnosis.spectral import fold_frequency
from stability.lobes import predict_point
from stability.simulate import SensorModel, simulate

CELL = paper_like_cell()
COEF = CELL.material.cutting_coefficients


def _force(rpm, depth, seconds=6.0, seed=1):
    sim = simulate(CELL.model, CELL.tool, CELL.cut, COEF, duration_s=seconds + 2.0, spindle_rpm=rpm,
                   axial_depth_m=depth, background=CELL.background, sensors=SensorModel(0.56), seed=seed)
    return sim.measured_force_N[:, 2000:]


def test_stable_cut_has_no_chatter():
    res = detect_chatter(_force(2700.0, 0.006), 1000.0, 45.0, 2)
    assert not res.chatter and res.kind == "none"
    assert res.tooth_hz == pytest.approx(90.0, abs=0.01)  # the simulator turns at exactly 2700 rpm


def test_hopf_chatter_beyond_the_limit_is_found_at_the_predicted_frequency():
    """25 mm at 2700 rpm is beyond the 19 mm limit of the zero-order approximation; the chatter
    line sits within 1.5 Hz of the predicted chatter frequency (the limit cycle's frequency moves
    a little from the onset value)."""
    op = predict_point(CELL.model, CELL.tool, CELL.cut, COEF, spindle_rpm=2700.0, axial_depth_m=0.025)
    assert not op.stable
    res = detect_chatter(_force(2700.0, 0.025), 1000.0, 45.0, 2)
    assert res.chatter and res.kind == "hopf"
    assert res.frequency_hz == pytest.approx(op.chatter_frequency_hz, abs=1.5)
    assert res.energy_ratio > 0.1 and res.prominence > 10.0


def test_flip_chatter_of_a_two_flute_tool_sits_on_the_odd_spindle_harmonics():
    """At 1000 rpm the semi-discretization limit is a flip lobe near 16 mm: period doubling puts
    the chatter at half the tooth frequency, i.e. the spindle frequency of a two-flute tool."""
    res = detect_chatter(_force(1000.0, 0.02), 1000.0, 1000.0 / 60.0, 2)
    assert res.chatter and res.kind == "flip"
    assert res.frequency_hz == pytest.approx(1000.0 / 60.0, rel=1e-3)
    assert res.flip_ratio > 0.5
    stable = detect_chatter(_force(1000.0, 0.006), 1000.0, 1000.0 / 60.0, 2)
    assert not stable.chatter and stable.flip_ratio < 0.05


def test_aliased_lines_are_folded_and_not_mistaken_for_chatter():
    """A 3-flute tool at 12000 rpm sampled at 1000 Hz: the tooth line (600 Hz) folds to 400 Hz and
    the harmonics above Nyquist fold over the band; a chatter line at 730 Hz folds to 270 Hz."""
    rng = np.random.default_rng(3)
    fs, n = 1000.0, 8000
    t = np.arange(n) / fs
    f0 = 200.0
    x = sum(a * np.cos(2 * np.pi * h * f0 * t + h) for h, a in ((1, 1.0), (2, 0.7), (3, 10.0), (4, 0.5),
                                                              (5, 0.4), (6, 3.0), (7, 0.3)))
    x = x + rng.normal(0.0, 0.2, n)
    quiet = detect_chatter(x[None, :], fs, f0 * 1.004, 3)  # nominal speed 0.4 % off
    assert quiet.tooth_hz == pytest.approx(fold_frequency(600.0, fs), abs=fs / n)
    assert quiet.spindle_hz == pytest.approx(f0, rel=1e-5)
    assert not quiet.chatter
    loud = detect_chatter((x + 4.0 * np.cos(2 * np.pi * 730.0 * t))[None, :], fs, f0, 3)
    assert loud.chatter and loud.frequency_hz == pytest.approx(270.0, abs=0.5)


@pytest.mark.parametrize("amplitude,chatter,confidence", [
    (0.02, False, 1.0),  # a trace: energy ratio 4e-4 of the tooth line, 2.4 decades under 0.1
    (0.29, False, 0.1),  # a clean line 16 % under the strength threshold: "no", but barely
    (0.60, True, 0.56),  # ratio 0.36 (0.56 decades over 0.1); prominence decades higher
])
def test_confidence_is_the_margin_of_the_decisive_statistic(amplitude, chatter, confidence):
    """A 2-flute tool at 2700 rpm (tooth line 90 Hz, amplitude 1) and a non-harmonic line at 137 Hz
    of the given amplitude in weak noise: energy ratio ``amplitude^2`` (same noise, same window),
    prominence far above 10 dB in every case, so the strength criterion decides. The confidence is
    its distance from 0.1 in decades, clipped to [0.1, 1]."""
    rng = np.random.default_rng(0)
    fs, n = 1000.0, 16000
    t = np.arange(n) / fs
    x = np.cos(2 * np.pi * 90.0 * t) + amplitude * np.cos(2 * np.pi * 137.0 * t) + rng.normal(0, 1e-3, n)
    res = detect_chatter(x[None, :], fs, 45.0, 2, refine=False)
    assert res.prominence > 100.0
    assert res.energy_ratio == pytest.approx(amplitude ** 2, rel=0.03)
    assert res.chatter == chatter
    assert res.confidence == pytest.approx(confidence, abs=0.02)


def test_refinement_uses_folded_harmonics():
    fs = 1000.0
    t = np.arange(4000) / fs
    x = np.cos(2 * np.pi * 3 * 233.0 * t)  # only the aliased tooth line (699 Hz -> 301 Hz) is present
    assert refine_spindle_frequency_aliased(x[None, :], fs, 230.0, teeth=3) == pytest.approx(233.0, rel=1e-5)


def test_comparison_reports_chatter_and_the_predicted_limit():
    sim = simulate(CELL.model, CELL.tool, CELL.cut, CELL.material, duration_s=6.0, axial_depth_m=0.025,
                   background=CELL.background, sensors=SensorModel(0.56, displacement_resolution_m=1.5e-5), seed=2)
    rec = sim.to_record(CELL.tool, replace(CELL.cut, axial_depth_m=0.025), material=CELL.material)
    rec = replace(rec, data=rec.data[:, 2000:], time_s=None)
    cmp = compare_records([rec], CELL.model)
    r = cmp.records[0]
    assert r.chatter.chatter and not r.predicted_stable
    assert r.depth_limit_m == pytest.approx(0.0189, rel=0.05)


def test_detect_chatter_rejects_empty_signals():
    with pytest.raises(ValueError, match="no finite signal"):
        detect_chatter(np.full((3, 100), np.nan), 1000.0, 45.0, 2)
    # a channel that overflowed is not a quiet one: no verdict rather than "stable"
    x = np.sin(2 * np.pi * 90.0 * np.arange(4000) / 1000.0)[None, :].repeat(2, axis=0)
    x[1, 3000:] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        detect_chatter(x, 1000.0, 45.0, 2)


# --------------------------------------------------------------------------- measured CNC cuts
HURCO = sorted(DEFAULT_DIRECTORY.glob("EBI_*.csv")) if DEFAULT_DIRECTORY.exists() else []
needs_hurco = pytest.mark.skipif(len(HURCO) != 16, reason="milling-vibration-hurco data not available")


@needs_hurco
def test_hurco_files_are_read():
    rec = read_hurco_csv(HURCO[0])
    assert rec.acceleration_m_s2.shape == (3, 25600)
    assert rec.sample_rate_hz == pytest.approx(1650.0, abs=2.0)
    assert rec.teeth == 4 and rec.spindle_rpm == (4000.0,) and rec.material == "4140 steel"
    assert rec.radial_engagement_percent == 100.0 and rec.axial_depth_in == 0.05 and rec.feed_in_min == 20.0


@needs_hurco
def test_hurco_tooth_frequency_matches_the_file_name():
    """For every file the tooth-passing frequency found is ``rpm * teeth / 60`` (folded; here all
    below Nyquist): within 0.2 % for the 15 constant-speed cuts (a CNC spindle's regulation; the
    12000 rpm cuts run 0.05-0.1 % slow), and between the two speeds for the cut whose speed
    changed from 7000 to 6000 rpm."""
    rows = hurco_table()
    assert len(rows) == 16
    for row in rows:
        if len(row["spindle_rpm"]) == 1:
            assert row["tooth_hz"] == pytest.approx(row["tooth_hz_nominal"][0], rel=0.002), row["file"]
        else:
            lo, hi = sorted(row["tooth_hz_nominal"])
            assert 0.98 * lo <= row["tooth_hz"] <= 1.02 * hi, row["file"]
        assert set(row) >= {"file", "tooth_hz", "chatter", "chatter_hz", "ci_median", "ci_chatter", "agrees_with_ci"}


def test_bad_hurco_file_is_rejected(tmp_path):
    path = tmp_path / "EBI_T50_0p125IN_12000RPM.csv"
    path.write_text("t,ax,ay,az\n0,1,2,3\n")
    with pytest.raises(InputError, match="header"):
        read_hurco_csv(path)
    path.write_text("Time (s),Accel X (m/s^2),Accel Y (m/s^2),Accel Z (m/s^2),CI Value\n"
                    + "".join(f"{0.001 * k},0,0,0,0\n" for k in range(20)))
    analysis_name = tmp_path / "EBI_T50_no_speed.csv"
    analysis_name.write_text(path.read_text())
    with pytest.raises(InputError, match="RPM"):
        read_hurco_csv(analysis_name)
    assert read_hurco_csv(path).spindle_rpm == (12000.0,)
