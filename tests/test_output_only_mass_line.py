"""The background's scale from the mass lines (``oma/output_only/mass_line.py``, session 18): the
levels against the simulation's background force, their precision against the resonances', the
colour cancelled, a mode missing from the model seen, displacements left to the resonances."""

from __future__ import annotations

import numpy as np
import pytest

from oma.modal import ModalModel
from oma.output_only.identify import MAX_MASS_LINE_MISFIT, identify_output_only
from oma.output_only.mass_line import mass_line_levels
from oma.synthetic import PAPER_BACKGROUND_VARIANCE_N2, paper_like_model, synthetic_record
from test_oma_output_only_spindle import OBLIQUE  # in-plane modes at 30 degrees, Z apart at 17 Hz
from test_output_only_background_colour import coloured_record  # the coloured background's records

TRUTH = paper_like_model()
FS = 1000.0
VAR = np.diag(PAPER_BACKGROUND_VARIANCE_N2)


def _match(model, k):
    d = np.abs(model.natural_frequency_hz / TRUTH.natural_frequency_hz[k] - 1) + \
        (1 - np.abs(model.directions @ TRUTH.directions[k]))
    return int(np.argmin(d))


def _levels(res):
    m = res.modes
    lines = np.concatenate([h.freq_hz for h in m.harmonics])
    return mass_line_levels([h.residual for h in m.harmonics], FS, m.freq_hz, m.damping_ratio, m.directions,
                            m.direction_se_rad, lines_hz=lines, band_hz=m.band_hz)


@pytest.fixture(scope="module")
def paper_cell():
    rec = synthetic_record(duration_s=20.0, rng=4, spindle_rpm=2700.0, output="acceleration", runout_m=None)
    res = identify_output_only([rec])
    return res, _levels(res)


def test_mass_line_levels_are_the_background_force_over_the_stiffness_squared_and_sharper(paper_cell):
    """``P_r k_r^2`` with the TRUE stiffness is the simulation's background PSD along the mode, within
    3 stated standard errors, for X, Y and Z; and the mass lines measure every level at least 3x more
    precisely than the resonance does (this record: 0.03-0.04 in log against 0.13-0.44; the
    resonances' bound is the few independent bins of a narrowband response)."""
    res, ml = paper_cell
    assert ml is not None and ml.misfit <= MAX_MASS_LINE_MISFIT
    for k in range(3):
        j = _match(res.model, k)
        u = res.modes.directions[j]
        se = ml.input_level_log_se[j]
        assert 0 < se < res.modes.input_level_log_se[j] / 3
        assert abs(np.log(ml.input_level[j] * TRUTH.stiffness_N_m[k] ** 2 / (u @ VAR @ u / FS))) < 3 * se


def test_z_beside_x_is_scaled_from_the_mass_lines(paper_cell):
    """In an acceleration record the pipeline takes the background's level from the mass lines: Z
    within 5 % (benchmark, 60 records of the tooth, runout and on-mode cases: max 7.1 %; from the
    resonances 14.6-15.3 %), inside its interval, the JSON saying where the level came from."""
    res, _ = paper_cell
    jz = _match(res.model, 2)
    assert res.scaled_by[jz] == "background" and res.background.source == "mass lines"
    assert abs(res.model.stiffness_N_m[jz] / TRUTH.stiffness_N_m[2] - 1) < 0.05
    lo, hi = res.stiffness.interval_N_m[jz]
    assert lo <= TRUTH.stiffness_N_m[2] <= hi
    assert res.to_dict()["background_force"]["source"] == "mass lines"
    assert any("from the mass lines" in w for w in res.warnings) and not res.trusted


@pytest.mark.parametrize("exponent", [2.0, -1.0])
def test_the_backgrounds_colour_cancels(exponent):
    """Red (f^-2) and blue (f^+1) backgrounds: the mass lines of X, Y and Z share each frequency's
    level, so Z comes out within 6 % (seeds 0-2: -4.1 to +1.7 % over pink, red and blue), where the
    resonances' levels, carried as if white, gave 23-39 % off in the median (session 16)."""
    res = identify_output_only([coloured_record(0, exponent, "acceleration")])
    jz = _match(res.model, 2)
    assert res.scaled_by[jz] == "background" and res.background.source == "mass lines"
    assert abs(res.model.stiffness_N_m[jz] / TRUTH.stiffness_N_m[2] - 1) < 0.06


def test_a_mode_missing_from_the_model_shows_in_the_misfit():
    """A fourth mode at 60 Hz (partly along Z) inside the mass lines' band: left out of the model the
    deviance ratio is far above :data:`MAX_MASS_LINE_MISFIT` (measured 9.8-10.0 on three seeds),
    so the pipeline would fall back to the resonances; with it in, about 1 (0.89-1.03)."""
    model = ModalModel([10.5, 24.8, 10.0, 60.0], [0.05, 0.04, 0.05, 0.03], [1.5e6, 3.0e6, 2.0e6, 3.0e6],
                       [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0.6, 0.8]])
    rec = synthetic_record(model, duration_s=20.0, rng=0, harmonics=False, output="acceleration", runout_m=None)
    y = rec.data[3:]
    d = np.asarray(model.directions, float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    f, z = model.natural_frequency_hz, model.damping_ratio
    full = mass_line_levels([y], FS, f, z, d, np.zeros(4))
    short = mass_line_levels([y], FS, f[:3], z[:3], d[:3], np.zeros(3))
    assert full.misfit < 1.2
    assert short.misfit > 3 * MAX_MASS_LINE_MISFIT


def test_velocities_are_differentiated_for_the_mass_lines():
    """A vibrometer's velocities: differentiated, their mass lines scale Z as accelerations do (the
    audit generator's velocity records, 18 with 0-10 % sensor noise: Z max 4.8 %, from the
    resonances 13.6-26.6 %)."""
    rec = synthetic_record(duration_s=20.0, rng=4, spindle_rpm=2700.0, output="velocity", runout_m=None)
    res = identify_output_only([rec])
    jz = _match(res.model, 2)
    assert res.scaled_by[jz] == "background" and res.background.source == "mass lines"
    assert abs(res.model.stiffness_N_m[jz] / TRUTH.stiffness_N_m[2] - 1) < 0.06


def test_displacements_keep_the_resonances_levels():
    """A tracker's displacements: the mass lines fall as f^-4 under its rounding and the resonances'
    leakage, so the level comes from the resonances (session 18: mass lines there gave Z 20 % soft
    with a stated 3 %, and 20-37 % soft on clean displacements with the deviance ratio about 1)."""
    rec = synthetic_record(duration_s=20.0, rng=0, spindle_rpm=2700.0, output="displacement", runout_m=None)
    res = identify_output_only([rec])
    assert res.background is not None and res.background.source == "resonances"




@pytest.mark.parametrize("z_variance, fires", [(PAPER_BACKGROUND_VARIANCE_N2[2], False), (2500.0, True)])
def test_levels_that_disagree_where_the_lines_scale_every_mode_leave_the_model_untrusted(z_variance, fires):
    """Where the lines scale every mode (the oblique structure: Z apart at 17 Hz), the background's
    level along each is still measured, and one far off the others' says a stiffness is wrong or
    the background is not alike along every direction: a warning, and not trusted. Session 18's
    audit: under a red background the lines gave Z 73 % soft with a stated 19 %, trusted, its level
    10x under X's. Here the record's Z background is 10x stronger than X's and Y's (the alarm's
    other cause; 4x raises none), against the paper's: no alarm, trusted (oblique and damped
    structures, 40 white, 16 pink and 16 red records: no alarm with the colour allowed for). A Z
    background 6x weaker leaves Z to the background's scale instead (the lines too far: not this
    path)."""
    rec = synthetic_record(OBLIQUE, duration_s=20.0, rng=3, spindle_rpm=2700.0, output="acceleration",
                           runout_m=None, background_variance_N2=(232.0, 278.0, z_variance))
    res = identify_output_only([rec])
    assert not np.any(res.stiffness.too_far)
    alarm = any("along the modes the lines scale differs" in w for w in res.warnings)
    assert alarm == fires
    assert res.trusted == (not fires)


def test_directions_with_the_background_free_between_channels_are_not_bent_by_its_anisotropy():
    """In-plane modes at 30 degrees under the paper's background (232 / 278 / 251 N^2 along X / Y /
    Z): the isotropic fit turns the 12 Hz mode away from the truth to explain the 20 % X / Y
    difference; the fit with the channels' levels free (:func:`mass_line_directions`, the directions
    the lines are solved with) does not, and its channel scales are that difference (measured,
    session 19, seeds 0-3: 12 Hz off by 0.3-0.9 degrees against 1.0-1.5, means 0.6 and 1.3; Y / X
    1.10-1.24 against the simulation's 1.20)."""
    from oma.output_only.mass_line import mass_line_directions

    iso_err, free_err, ratio = [], [], []
    for seed in range(3):
        res = identify_output_only([synthetic_record(OBLIQUE, duration_s=20.0, rng=10_000 + seed, spindle_rpm=2700.0,
                                                     output="acceleration", runout_m=None)])
        m = res.modes
        args = ([h.residual for h in m.harmonics], FS, m.freq_hz, m.damping_ratio, m.directions, m.direction_se_rad)
        kw = dict(lines_hz=np.concatenate([h.freq_hz for h in m.harmonics]), band_hz=(m.band_hz[0], 150.0))
        iso = mass_line_levels(*args, **kw).directions
        free, scales = mass_line_directions(*args, **kw)
        j = int(np.argmin(np.abs(m.freq_hz - 12.0)))
        for errs, u in ((iso_err, iso[j]), (free_err, free[j])):
            errs.append(np.degrees(np.arccos(min(1.0, abs(u @ OBLIQUE.directions[0]) / np.linalg.norm(u)))))
        ratio.append(scales[1] / scales[0])
        assert res.directions_source == "mass lines"
        np.testing.assert_allclose(res.model.directions[j], free[j] / np.linalg.norm(free[j]), atol=1e-12)
    assert np.mean(free_err) < 0.7 * np.mean(iso_err), (free_err, iso_err)
    true_ratio = PAPER_BACKGROUND_VARIANCE_N2[1] / PAPER_BACKGROUND_VARIANCE_N2[0]
    assert abs(np.mean(ratio) / true_ratio - 1) < 0.15, ratio


@pytest.mark.parametrize("channel_scale_sd", [None, 1.0])
def test_the_posteriors_analytic_gradient_matches_finite_differences(paper_cell, channel_scale_sd):
    """The mass lines' fit takes the analytic gradient of its negative log posterior (session 22;
    before, BFGS differenced it: 15 000 evaluations on one record, 3.3 s): against central
    differences at a point off the optimum, with the log levels at the knots, the modes' masses,
    the close pair's turned directions and (``channel_scale_sd``) the channels' log scales, and its
    value against the posterior's."""
    from oma.output_only.mass_line import LINE_GUARD_HZ, _fit

    res, _ = paper_cell
    m = res.modes
    fit = _fit([h.residual for h in m.harmonics], FS, m.freq_hz, m.damping_ratio, m.directions, m.direction_se_rad,
               2, np.concatenate([h.freq_hz for h in m.harmonics]), m.band_hz, LINE_GUARD_HZ,
               channel_scale_sd=channel_scale_sd)
    rng = np.random.default_rng(5)
    p = fit.p + 0.05 * rng.normal(size=fit.p.size)
    n_turns = fit.p.size - fit.n_s - (m.freq_hz.size - 1) - (2 if channel_scale_sd else 0)
    assert n_turns >= 2                                   # some directions are turned
    value, grad = fit.objective(p)
    assert value == pytest.approx(fit.posterior(p), rel=1e-10)
    h = 1e-6
    fd = np.array([(fit.posterior(p + h * e) - fit.posterior(p - h * e)) / (2 * h) for e in np.eye(p.size)])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-4 * np.max(np.abs(fd)))
