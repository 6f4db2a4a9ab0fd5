"""The OMA pipeline on paper-like simulated records (robomill issue 3 targets)."""

import json
from dataclasses import replace

import numpy as np
import pytest

from oma.errors import RecordError
from oma.identify import identify, modal_mapping
from oma.synthetic import PAPER_BACKGROUND_VARIANCE_N2, paper_like_model, synthetic_record

TRUTH = paper_like_model()  # X 10.5 Hz / 5 % / 1.5e6, Y 24.8 / 4 % / 3e6, Z 10.0 / 5 % / 2e6


def dominant_errors(model):
    """Relative errors (fn, zeta, k) of the dominant mode of each axis, shape (3, 3).

    The dominant mode of axis a is the one with the largest resonant peak in G_aa,
    u_a^2 / (k zeta).
    """
    out = []
    for a in range(3):
        peak = model.directions[:, a] ** 2 / (model.stiffness_N_m * model.damping_ratio)
        j = int(np.argmax(peak))
        out.append([
            model.natural_frequency_hz[j] / TRUTH.natural_frequency_hz[a] - 1,
            model.damping_ratio[j] / TRUTH.damping_ratio[a] - 1,
            model.stiffness_N_m[j] / TRUTH.stiffness_N_m[a] - 1,
        ])
    return np.array(out)


@pytest.fixture(scope="module")
def long_runs():
    """Default identification of two independent 20 s records (more in benchmarks/bench_oma.py)."""
    return [identify([synthetic_record(duration_s=20.0, rng=100 + s)]) for s in range(2)]


@pytest.fixture(scope="module")
def short_runs():
    """Default identification of five independent 1.1 s records (the paper's cut)."""
    return [identify([synthetic_record(duration_s=1.1, rng=200 + s)]) for s in range(5)]


def test_20s_records_meet_the_targets(long_runs):
    # issue 3: 20 s records -> fn within 1 %, damping within 15 %, stiffness within 10 %
    for idn in long_runs:
        err = np.abs(dominant_errors(idn.model))
        assert np.all(err[:, 0] < 0.01), err
        assert np.all(err[:, 1] < 0.15), err
        assert np.all(err[:, 2] < 0.10), err
        assert idn.trusted and not any("NOT trusted" in w for w in idn.warnings)
        assert np.all(idn.excitation_sufficient)
        np.testing.assert_allclose(idn.noise_variance_N2, PAPER_BACKGROUND_VARIANCE_N2, rtol=0.10)


def test_1p1s_records_meet_the_targets_as_a_median(short_runs):
    # issue 3: 1.1 s records -> 3 %, 40 %, 25 %, as a statistic over five records (the median
    # error per axis; the distribution over 20 records is in benchmarks/bench_oma.py)
    err = np.abs(np.array([dominant_errors(idn.model) for idn in short_runs]))  # (seeds, axes, 3)
    med = np.median(err, axis=0)
    assert np.all(med < np.array([0.03, 0.40, 0.25])), med
    # the 10.0 Hz Z and 10.5 Hz X modes are told apart (a merged pole would put one ~5 % off)
    assert np.all(med[:, 0] < 0.02), med
    # Y, well separated from the others, meets the targets on every record
    assert np.all(err[:, 1] < np.array([0.03, 0.40, 0.25])), err[:, 1]


def test_close_x_and_z_modes_are_two_modes_on_every_short_record(short_runs):
    # X 10.5 Hz and Z 10.0 Hz are 5 % apart, 11 cycles in 1.1 s: the search proposes a mode along
    # each axis alone (a mode along X does not explain Z) and the likelihood keeps both. The record
    # of seed 10 000 is one where the free-residue sweep alone proposes no third mode.
    extra = identify([synthetic_record(duration_s=1.1, rng=10_000)])
    for idn in [*short_runs, extra]:
        m = idn.model
        near = np.flatnonzero(np.abs(m.natural_frequency_hz / 10.25 - 1) < 0.1)
        assert near.size == 2, m.natural_frequency_hz
        axes = sorted(int(np.argmax(np.abs(m.directions[j]))) for j in near)
        assert axes == [0, 2], m.directions[near]


def test_default_beats_plain_h1_on_short_records(short_runs):
    # the paper's estimator (Welch H1 + fit) cannot resolve a 1 Hz wide mode from 1.1 s
    recs = [synthetic_record(duration_s=1.1, rng=200 + s) for s in range(2)]
    h1 = [np.abs(dominant_errors(identify([r], method="h1").model)) for r in recs]
    default = [np.abs(dominant_errors(idn.model)) for idn in short_runs[:2]]
    # Y (the well separated mode): stiffness error of the default is smaller on both records
    assert all(d[1, 2] < h[1, 2] for d, h in zip(default, h1))


def test_the_h1_fit_of_a_5khz_accelerometer_record_is_the_truth():
    # 20 s at 5 kHz cut into 6.6 s segments: 4.8 averages, so the noise spectrum at one line has 2.8
    # degrees of freedom. Weighted by it line by line, this record's H1 fit had four modes (the
    # 10.0 / 10.5 Hz pair plus a 9.88 Hz one; 16 seeds at 5 kHz: stiffness off by up to 8.9 %).
    # With the noise averaged over 9 lines, and the ModalModel fit's own selection, the three
    # true modes (16 of 16 seeds: frequency within 0.09 %, stiffness 0.3 %).
    fs = 5000.0
    rec = synthetic_record(paper_like_model(), duration_s=20, sample_rate_hz=fs, rng=15, output="acceleration",
                           background_variance_N2=tuple(np.array(PAPER_BACKGROUND_VARIANCE_N2) * fs / 1000.0))
    idn = identify([rec], method="h1")
    assert idn.model.n_modes == 3
    err = np.abs(dominant_errors(idn.model))
    assert np.all(err[:, 0] < 0.005) and np.all(err[:, 1] < 0.05) and np.all(err[:, 2] < 0.02), err
    assert idn.trusted
    # the record declares the paper's tracker (15 um) beside its accelerometers: a displacement
    # sensor's resolution says nothing of them, so no detectability is assessed (nor simulated)
    assert rec.sensors.displacement_resolution_m == 1.5e-5
    assert not np.any(idn.detectability.assessed) and np.all(np.isnan(idn.detectability.peak_to_valley_m))
    assert any("no displacement recorded" in w for w in idn.warnings), idn.warnings


@pytest.mark.parametrize("seed", [301])
def test_low_background_is_flagged_not_silently_reported(seed):
    # ten times less background force than the paper's: the tracker cannot resolve the response
    rec = synthetic_record(duration_s=1.1, rng=seed, background_variance_N2=np.array(PAPER_BACKGROUND_VARIANCE_N2) / 10)
    idn = identify([rec])
    assert not idn.trusted
    assert any("resolve" in w for w in idn.warnings) and any("NOT trusted" in w for w in idn.warnings)
    flags = idn.to_dict()["excitation_sufficient"]
    # Y (the paper's axis) always, and at least two axes: a model fitted to such a record can
    # itself be too compliant on one axis and pass that axis' check (a known weakness)
    assert flags["Y"] is False and sum(not v for v in flags.values()) >= 2
    assert idn.model.source["trusted"] is False


def test_wrong_rpm_is_refined_and_reported():
    rec = synthetic_record(duration_s=1.1, rng=301, nominal_rpm=2700 * 1.02)
    idn = identify([rec], method="h1")
    assert idn.harmonics[0].spindle_hz == pytest.approx(45.0, rel=5e-4)
    assert any("refined" in w for w in idn.warnings)
    np.testing.assert_allclose(idn.noise_variance_N2, PAPER_BACKGROUND_VARIANCE_N2, rtol=0.15)


def test_to_dict_is_the_cli_json_and_the_model_mapping_is_modal_format(long_runs):
    d = long_runs[0].to_dict()
    for key in ("model", "frf_fit_error", "noise_variance_N2", "min_noise_variance_N2", "excitation_sufficient",
                "warnings"):
        assert key in d
    json.dumps(d)  # plain types only
    assert d["model"]["format"] == "robomill-modal/1"
    assert set(d["noise_variance_N2"]) == {"X", "Y", "Z"}
    mode = d["model"]["modes"][0]
    assert set(mode) == {"natural_frequency_hz", "damping_ratio", "stiffness_N_m", "direction"}
    assert d["model"]["source"]["method"] == "oma-time-domain-ml"
    assert modal_mapping(TRUTH)["modes"][1]["natural_frequency_hz"] == 24.8


def test_two_records_of_the_same_pose_are_combined():
    recs = [synthetic_record(duration_s=3.0, rng=400 + s) for s in range(2)]
    idn = identify(recs)
    assert len(idn.harmonics) == 2 and idn.frf_estimate.table.meta["records"] == 2
    err = np.abs(dominant_errors(idn.model))
    assert np.all(err[:2, 0] < 0.01) and np.all(err[:2, 2] < 0.10)


def test_input_errors():
    rec = synthetic_record(duration_s=1.1, rng=500)
    with pytest.raises(ValueError, match="method must be one of"):
        identify([rec], method="lscf")
    with pytest.raises(ValueError, match="at least one record"):
        identify([])
    other = replace(rec, sample_rate_hz=500.0)
    with pytest.raises(RecordError, match="sample_rate_hz"):
        identify([rec, other])


def test_an_axis_without_motion_is_not_called_sufficiently_excited():
    rec = synthetic_record(duration_s=1.1, rng=10_003)
    keep = [i for i, c in enumerate(rec.channels) if not (c.quantity == "displacement" and c.axis == "Z")]
    idn = identify([replace(rec, channels=tuple(rec.channels[i] for i in keep), data=rec.data[keep])])
    assert idn.to_dict()["excitation_sufficient"]["Z"] is False
    assert any(w.startswith("Z: no tool-tip motion") for w in idn.warnings)
    assert idn.frf_fit_error[2] != idn.frf_fit_error[2]  # NaN: not measured


@pytest.fixture(scope="module")
def calibration_runs():
    """Eight more independent 20 s records for the calibration of the standard errors."""
    return [identify([synthetic_record(duration_s=20.0, rng=300 + s)]) for s in range(8)]


def test_frequency_and_damping_standard_errors_are_calibrated_on_20s_records(calibration_runs):
    """The block sandwich counts the residuals' own correlation: over 8 records the z-scores of the
    Y and Z modes' frequency and damping (32 of them) have rms near 1 (the likelihood's curvature
    alone gives 1.5-3x narrower bars, rms 2-3). The X mode's rms is 1.3-1.5 (bench: coverage
    82-92 %), not asserted here. The intervals hold the estimate and use blocks - 1 degrees of
    freedom."""
    z = []
    for idn in calibration_runs:
        u = idn.to_dict()["uncertainty"]
        assert u["available"] and u["blocks"] >= 8 and u["level"] == 0.95
        tf, m = idn.time_fit, idn.model
        for a in (1, 2):
            j = int(np.argmax(m.directions[:, a] ** 2 / (m.stiffness_N_m * m.damping_ratio)))
            z += [(m.natural_frequency_hz[j] - TRUTH.natural_frequency_hz[a]) / tf.frequency_se_hz[j],
                  (m.damping_ratio[j] - TRUTH.damping_ratio[a]) / tf.damping_se[j]]
            mode = u["modes"][j]
            assert mode["frequency_interval_hz"][0] < mode["natural_frequency_hz"] < mode["frequency_interval_hz"][1]
            assert mode["damping_interval"][0] < mode["damping_ratio"] < mode["damping_interval"][1]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.5 < rms < 1.6, rms


def test_short_records_report_no_standard_errors_rather_than_invented_ones(short_runs):
    """A 1.1 s cut is one block: its own scatter cannot be told, so the errors are null."""
    for idn in short_runs:
        u = idn.to_dict()["uncertainty"]
        assert not u["available"]
        assert all(m["frequency_standard_error_hz"] is None and m["damping_interval"] == [None, None]
                   for m in u["modes"])


def test_least_squares_path_standard_errors_are_calibrated_on_acceleration_records():
    """Accelerometers are not rounded like the tracker: the least-squares path, with its own block
    sandwich. Six 20 s acceleration records at 2700 rpm (tooth lines at 90 Hz and up): the z-scores
    of every axis's dominant mode (36) have rms near 1 (bench over 40 records: 1.04-1.26)."""
    z = []
    for s in range(6):
        rec = synthetic_record(duration_s=20.0, rng=500 + s, output="acceleration", spindle_rpm=2700.0)
        idn = identify([rec])
        tf, m = idn.time_fit, idn.model
        assert not tf.quantised and idn.to_dict()["uncertainty"]["available"]
        for a in range(3):
            j = int(np.argmax(m.directions[:, a] ** 2 / (m.stiffness_N_m * m.damping_ratio)))
            z += [(m.natural_frequency_hz[j] - TRUTH.natural_frequency_hz[a]) / tf.frequency_se_hz[j],
                  (m.damping_ratio[j] - TRUTH.damping_ratio[a]) / tf.damping_se[j]]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.5 < rms < 1.7, rms
