"""Output-only stiffness from the background force's level (issue 14, session 14).

Ground truth: the paper-like cell of :mod:`oma.synthetic` (X 10.5 Hz / 5 % / 1.5e6 N/m, Y 24.8 Hz /
4 % / 3.0e6 N/m, Z 10.0 Hz / 5 % / 2.0e6 N/m) driven by a white background force of known variance
per axis (the paper's 232 / 278 / 251 N^2 unless a test says otherwise), 20 s of accelerations at
1 kHz and 2700 rpm; and hand-made scalings whose answers are closed forms.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from oma.output_only.background import ANISOTROPY_LOG_SD, background_level, scale_by_background
from oma.output_only.identify import identify_output_only
from oma.output_only.scaling import StiffnessScaling
from oma.synthetic import PAPER_BACKGROUND_VARIANCE_N2, paper_like_model, synthetic_record

TRUTH = paper_like_model()
FS = 1000.0


def _record(seed, background=PAPER_BACKGROUND_VARIANCE_N2):
    return synthetic_record(duration_s=20.0, rng=seed, spindle_rpm=2700.0, output="acceleration", runout_m=None,
                            background_variance_N2=background)


def _match(model, k):
    d = np.abs(model.natural_frequency_hz / TRUTH.natural_frequency_hz[k] - 1) + \
        (1 - np.abs(model.directions @ TRUTH.directions[k]))
    return int(np.argmin(d))


@pytest.fixture(scope="module")
def paper_cell():
    rec = _record(4)
    return rec, identify_output_only([rec]), identify_output_only([rec], background_anisotropy=None)


def test_input_level_is_the_background_force_over_the_stiffness_squared(paper_cell):
    """``P_r k_r^2`` with the TRUE stiffness is the background force's PSD along the mode (the
    simulation's variance over the sampling rate): the level's normalisation (channel scales, the
    derivative's gain, the DFT's 1/sqrt(fs n)) checked against the physics, within 3 of its stated
    standard errors, which are informative (under 0.5 in log; over 8 benchmark records they were
    0.08-0.40 and conservative: z-scores rms 0.55-0.86)."""
    _, res, _ = paper_cell
    modes = res.modes
    var = np.diag(PAPER_BACKGROUND_VARIANCE_N2)
    for k in range(3):
        j = _match(res.model, k)
        u = modes.directions[j]
        psd_true = u @ var @ u / FS
        se = modes.input_level_log_se[j]
        assert 0 < se < 0.5
        assert abs(np.log(modes.input_level[j] * TRUTH.stiffness_N_m[k] ** 2 / psd_true)) < 3 * se


def test_z_beside_x_is_scaled_by_the_background_level_and_says_what_it_assumes(paper_cell):
    """The Z mode the tooth lines cannot scale (session 10: its line estimate is off by 26-362 % or
    not positive) takes its stiffness from the background level of X and Y: inside its stated
    interval, whose width carries the isotropy allowance; the model is written but not trusted,
    and the lines' own value is still reported. Tolerance 20 %: the largest error over 50 records
    of the issue's cases was 14.6 % with the resonances' levels (docs/output_only.md, session 14),
    7.1 % over 60 since session 18's mass lines (tests/test_output_only_mass_line.py)."""
    _, res, lines_only = paper_cell
    jz = _match(res.model, 2)
    assert res.stiffness.too_far[jz] and res.scaled_by[jz] == "background"
    k = res.model.stiffness_N_m[jz]
    lo, hi = res.stiffness.interval_N_m[jz]
    assert lo <= TRUTH.stiffness_N_m[2] <= hi
    assert abs(k / TRUTH.stiffness_N_m[2] - 1) < 0.20
    # the stated uncertainty holds the assumption's allowance (half the log-PSD spread) and the coefficients'
    assert res.stiffness.statistical_relative_sd[jz] > ANISOTROPY_LOG_SD / 2
    assert res.stiffness.relative_sd[jz] > np.hypot(ANISOTROPY_LOG_SD / 2, res.stiffness.coefficient_relative_sd)
    assert res.scaled and not res.trusted
    assert any("background force's level" in w and "assumes" in w for w in res.warnings)
    # X and Y keep the lines' values to the bit (solved with the directions the mass lines turned,
    # within the isotropy test's 10 % of those with the refinement's); the background comes from them
    for k_ in (0, 1):
        j = _match(res.model, k_)
        assert res.scaled_by[j] == "lines"
        assert res.model.stiffness_N_m[j] == res.lines_scaling.stiffness_N_m[j]
        assert abs(res.model.stiffness_N_m[j] / lines_only.model.stiffness_N_m[j] - 1) < 0.10
    assert sorted(res.background.reference.tolist()) == sorted([_match(res.model, 0), _match(res.model, 1)])
    d = res.to_dict()
    entry = d["modes"][jz]["stiffness_uncertainty"]
    assert entry["scaled_by"] == "background"
    lines_k = res.lines_scaling.stiffness_N_m[jz]
    assert entry["lines"]["stiffness_N_m"] == (float(lines_k) if np.isfinite(lines_k) else None)
    bg = d["background_force"]
    assert bg["white_variance_N2"] == pytest.approx(bg["psd_N2_Hz"] * FS) and bg["consistent"]
    json.dumps(d, allow_nan=False)
    # without the background, Z is what the lines gave (unscaled or flagged), as before session 14
    assert lines_only.background is None and lines_only.scaled_by[jz] in ("lines", "none")


def _scaling(k, stat, too_far, coef_sd=0.15):
    k = np.asarray(k, float)
    stat = np.asarray(stat, float)
    total = np.hypot(stat, coef_sd)
    return StiffnessScaling(stiffness_N_m=k, statistical_relative_sd=stat, coefficient_relative_sd=coef_sd,
                            relative_sd=total, interval_N_m=np.column_stack([k, k]), theta_rad=np.zeros(1),
                            lines_hz=np.array([90.0]), too_far=np.asarray(too_far, bool))


def test_background_level_and_scale_closed_forms():
    s = 0.25  # N^2/Hz
    k = np.array([1.5e6, 3.0e6, 2.0e6])
    se = np.array([0.1, 0.1, 0.2])
    stat = np.array([0.03, 0.03, np.inf])
    sc = _scaling([k[0], k[1], np.nan], stat, [False, False, True])
    level = s / k ** 2
    bg = background_level(sc, level, se)
    var = se[:2] ** 2 + (2 * stat[:2]) ** 2
    # equal levels: the spread is the prior's, the mean the level itself
    assert bg.psd_N2_Hz == pytest.approx(s) and bg.anisotropy_log_sd == ANISOTROPY_LOG_SD and bg.consistent
    assert bg.log_se == pytest.approx(np.sqrt(1 / np.sum(1 / (var + ANISOTROPY_LOG_SD ** 2))))
    out, by = scale_by_background(sc, bg, level, se)
    assert by.tolist() == [False, False, True]
    assert out.stiffness_N_m[2] == pytest.approx(k[2])
    sd = 0.5 * np.sqrt(bg.log_se ** 2 + ANISOTROPY_LOG_SD ** 2 + se[2] ** 2)
    assert out.statistical_relative_sd[2] == pytest.approx(sd)
    total = np.hypot(sd, 0.15)
    zq = stats.norm.ppf(0.975)
    np.testing.assert_allclose(out.interval_N_m[2], k[2] * np.exp([-zq * total, zq * total]))
    np.testing.assert_array_equal(out.stiffness_N_m[:2], k[:2])
    # the scaled modes' levels a factor 4 apart: DerSimonian-Laird's spread for two equal variances is
    # d^2 / 2 - var, the mean the geometric one, and the two are called inconsistent
    level4 = level * np.array([4.0, 1.0, 1.0])
    bg4 = background_level(sc, level4, se)
    d = np.log(4.0)
    assert bg4.anisotropy_log_sd == pytest.approx(np.sqrt(d ** 2 / 2 - var[0]))
    assert bg4.psd_N2_Hz == pytest.approx(2 * s) and not bg4.consistent
    # nothing scaled well by the lines: no level
    assert background_level(_scaling([np.nan] * 3, [np.inf] * 3, [True] * 3), level, se) is None


def test_a_background_unlike_along_the_scaled_modes_widens_the_allowance_and_says_so():
    """X's background four times Y's (928 against 232 N^2): the two scaled modes disagree by far
    more than their errors, the allowed spread grows from the prior's 0.3 to the data's, a warning
    says the modes scaled by the background are doubtful, and Z's interval still holds its truth."""
    rec = _record(4, background=(928.0, 232.0, 251.0))
    res = identify_output_only([rec])
    jz = _match(res.model, 2)
    assert res.scaled_by[jz] == "background"
    assert res.background.anisotropy_log_sd > 2 * ANISOTROPY_LOG_SD and not res.background.consistent
    assert any("differs between the modes the lines scale" in w for w in res.warnings)
    lo, hi = res.stiffness.interval_N_m[jz]
    assert lo <= TRUTH.stiffness_N_m[2] <= hi


def test_cli_writes_the_model_whose_z_the_background_scaled(tmp_path, capsys):
    from oma.record_io import write_record
    from planner.cli import main

    write_record(_record(4), tmp_path / "rec")
    code = main(["identify", str(tmp_path / "rec"), "--output-only", "--json", "-o", str(tmp_path / "m.yaml")])
    payload = json.loads(capsys.readouterr().out)
    assert code == 0 and (tmp_path / "m.yaml").exists()
    assert not any("no model written" in w for w in payload["warnings"])
    assert sorted(m["stiffness_uncertainty"]["scaled_by"] for m in payload["modes"]) == ["background", "lines", "lines"]
    assert payload["background_force"]["white_variance_N2"] > 0 and payload["trusted"] is False
