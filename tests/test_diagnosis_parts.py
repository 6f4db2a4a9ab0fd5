"""The numerics under the diagnosis, checked against closed forms and the time-domain simulator.

Ground truth: the exact first-order-hold discretisation (scipy), the simulator's own signals (an
independent implementation: numba kernel at 4.5 kHz against scipy filters at 1 kHz), Parseval,
least-squares statistics on seeded white noise, and the closed-loop force spectrum of a long
simulated cut.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import signal as sps

from oma.errors import InputError
from planner.diagnosis import diagnose
from planner.diagnosis.cases import hidden_effect_case, paper_like_cell
from planner.diagnosis.closedloop import closed_loop_force_psd
from planner.diagnosis.compare import PartEvaluation, compare_records, prepare_views, significance
from planner.diagnosis.parts import align_angle, rotate
from planner.diagnosis.forcemodel import analytic_harmonics, simulated_harmonics
from planner.diagnosis.response import free_response_basis, mode_filter, modal_response
from planner.diagnosis.spectral import (dft_band_power, expected_welch, fold_frequency, harmonic_coefficients,
                                        harmonic_noise_variance, welch_psd)
from stability.simulate import (BackgroundForce, Effects, NonlinearCutting, PoseDrift, ProcessDamping, Runout,
                                SensorModel, simulate)

CELL = paper_like_cell()


@pytest.mark.parametrize("fn, zeta, fs", [(10.5, 0.05, 1000.0), (250.0, 0.3, 1000.0), (3.0, 0.01, 200.0)])
def test_mode_filter_is_the_exact_first_order_hold_discretisation(fn, zeta, fs):
    w = 2 * np.pi * fn
    ad, bd, cd, dd, _ = sps.cont2discrete((np.array([[0, 1], [-w * w, -2 * zeta * w]]), np.array([[0], [w * w]]),
                                           np.array([[1, 0]]), np.zeros((1, 1))), 1 / fs, method="foh")
    b_ref, a_ref = sps.ss2tf(ad, bd, cd, dd)
    b, a = mode_filter(fn, zeta, fs)
    np.testing.assert_allclose(b, b_ref.ravel(), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(a, a_ref.ravel(), rtol=1e-9, atol=1e-15)
    assert b.sum() / a.sum() == pytest.approx(1.0, rel=1e-9)  # unit static gain


def _ideal_cut(duration_s=6.0, effects=Effects(), **kw):
    return simulate(CELL.model, CELL.tool, CELL.cut, CELL.material, duration_s=duration_s, effects=effects,
                    background=CELL.background, sensors=SensorModel(), seed=3, **kw)


def test_modal_response_reproduces_the_simulated_displacement():
    """The model driven by the measured (anti-aliased, 1 kHz) force gives the displacement the
    simulator integrated at 4.5 kHz: within 1 % of its RMS once the start transient has gone."""
    sim = _ideal_cut()
    x = modal_response(CELL.model, sim.measured_force_N, sim.sample_rate_hz, initial="rest")
    settle = 2000  # 2 s: the slowest mode's transient (zeta w = 3/s) has decayed to 0.25 %
    d = x[:, settle:] - sim.measured_displacement_m[:, settle:]
    assert np.max(np.std(d, axis=1) / np.std(sim.measured_displacement_m[:, settle:], axis=1)) < 0.01


def test_pose_drift_response_reproduces_the_simulator():
    """A 12 % drift over 4 s: with parameters piecewise constant over 50 ms the response follows the
    simulator (whole tooth periods, 11 ms) within 1.5 % of its RMS; 0.2 s steps are visibly worse,
    and ignoring the drift is an order of magnitude worse."""
    drift = 0.12
    sim = _ideal_cut(duration_s=4.0, effects=Effects(pose_drift=PoseDrift(drift)))
    n = sim.record_time_s.size
    xm = sim.measured_displacement_m[:, 2000:]

    def error(step):
        starts = np.arange(0, n, step)
        mids = (starts + step / 2) / sim.sample_rate_hz
        x = modal_response(CELL.model, sim.measured_force_N, sim.sample_rate_hz, initial="rest",
                           frequency_scale=1.0 + drift * mids / 4.0, segment_starts=starts)
        return np.max(np.std(x[:, 2000:] - xm, axis=1) / np.std(xm, axis=1))

    fine, coarse = error(50), error(200)
    assert fine < 0.015
    assert coarse > 2 * fine
    x0 = modal_response(CELL.model, sim.measured_force_N, sim.sample_rate_hz, initial="rest")
    assert np.max(np.std(x0[:, 2000:] - xm, axis=1) / np.std(xm, axis=1)) > 10 * fine


def test_free_responses_absorb_the_initial_state():
    rng = np.random.default_rng(1)
    f = rng.normal(0.0, 20.0, (3, 3000)) + np.array([[-50.0], [30.0], [10.0]])
    rest = modal_response(CELL.model, f, 1000.0, initial="rest")
    static = modal_response(CELL.model, f, 1000.0, initial="static")
    b = free_response_basis(CELL.model, 3000, 1000.0).reshape(9000, -1)
    diff = (static - rest).ravel()
    coef, *_ = np.linalg.lstsq(b, diff, rcond=None)
    assert np.linalg.norm(diff - b @ coef) < 1e-3 * np.linalg.norm(diff)


@pytest.mark.parametrize("effects, kwargs", [
    (Effects(), {}),
    (Effects(runout=Runout(20e-6, 0.4)), {"chip_increments_m": Runout(20e-6, 0.4).chip_increments(2)}),
    (Effects(nonlinear_cutting=NonlinearCutting(0.3)), {"exponent_p": 0.3}),
])
def test_rigid_tool_harmonics_match_the_simulator(effects, kwargs):
    """Analytic rigid-tool harmonics against the simulated cut: they differ only by the vibration
    in the chip, below 1.5 % of the largest harmonic for a robot at 2700 rpm."""
    cut = CELL.cut
    sim = simulated_harmonics(CELL.model, CELL.tool, cut, CELL.material.cutting_coefficients, 6,
                              spindle_hz=45.0, sample_rate_hz=1000.0, effects=effects)
    ana = analytic_harmonics(CELL.tool, cut, CELL.material.cutting_coefficients, 6, spindle_hz=45.0,
                             sample_rate_hz=1000.0, **kwargs)
    assert np.max(np.abs(ana - sim)) < 0.015 * np.max(np.abs(sim))


def test_closed_loop_force_spectrum_matches_a_long_simulation():
    """Regeneration and process damping notch the measured force at the X mode: the averaged
    closed-loop model against 40 s of the 2700 rpm cut, mean log ratio over the notch within 0.08
    (four standard errors of 12 lines of a 19-average Welch estimate; the notch is 0.45 of the
    background without process damping and 0.28 with C = 3e6 N/m). At 1000 rpm the averaging is
    off by 0.2-0.3 (closedloop module notes)."""
    fs = 1000.0
    depths = []
    for c in (0.0, 3e6):
        eff = Effects(process_damping=ProcessDamping(c)) if c else Effects()
        sim = simulate(CELL.model, CELL.tool, CELL.cut, CELL.material, duration_s=42.0, effects=eff,
                       background=BackgroundForce((250.0, 250.0, 250.0), 400.0), sensors=SensorModel(), seed=5)
        force = sim.measured_force_N[:, 2000:]
        _, fitted = harmonic_coefficients(force, fs, 45.0, 11)
        f, p = welch_psd(force - fitted, fs, 4000)
        level = np.median(p[:, (f > 55) & (f < 85)], axis=1)
        fine = np.arange(5.0, 40.0, 0.02)
        pred = closed_loop_force_psd(CELL.model, CELL.tool, CELL.cut, CELL.material.cutting_coefficients, fine,
                                     background_psd=level, process_damping_N_m=c)
        near = (f > 9.9) & (f < 11.1)
        e = expected_welch(fine, pred, f[near], 4000, fs)
        err = np.mean(np.log(p[0, near] / e[0]))
        assert abs(err) < 0.08, f"C = {c}: mean log ratio {err}"
        depths.append(np.mean(p[0, near]) / level[0])
    assert depths[0] < 0.6 and depths[1] < 0.7 * depths[0]  # a notch, deepened by process damping


def test_harmonic_noise_variance_predicts_the_scatter_of_the_coefficients():
    """``E|c - c_true|^2 = 2 S / T`` for white noise of one-sided density ``S``: over 2000 seeded
    trials the empirical variance agrees within 10 % (4 standard errors: 9 %)."""
    rng = np.random.default_rng(12)
    fs, n, f0 = 1000.0, 2000, 45.0
    t = np.arange(n) / fs
    truth = 30 * np.cos(2 * np.pi * 2 * f0 * t + 0.3) + 5.0
    x = truth[None, :] + rng.normal(0.0, 4.0, (2000, n))
    c, fitted = harmonic_coefficients(x, fs, f0, 4)
    emp = np.mean(np.abs(c[:, 2] - 30 * np.exp(0.3j)) ** 2)
    pred = harmonic_noise_variance(x[:50] - fitted[:50], fs, f0, 4)[:, 2]
    assert emp == pytest.approx(2 * (2 * 16.0 / fs) / (n / fs), rel=0.1)
    assert np.mean(pred) == pytest.approx(emp, rel=0.1)
    assert np.mean(np.abs(c[:, 0] - 5.0) ** 2) == pytest.approx(16.0 / n, rel=0.1)  # the mean: S / (2 T)


def test_significance_of_a_spurious_extension_is_negative_with_unit_spread():
    """If the data are noise around the baseline, an extension's reduction ``dE`` has mean
    ``-sum w |delta|^2`` and standard deviation ``sqrt(2 sum w^2 |delta|^2 s)``: z is that mean over
    that spread, with unit scatter (2000 seeded trials; tolerances 4 standard errors)."""
    rng = np.random.default_rng(2)
    m, s = 40, 0.5
    delta = rng.normal(0.0, 0.3, m) + 1j * rng.normal(0.0, 0.3, m)
    zs = []
    for _ in range(2000):
        y = np.sqrt(s / 2) * (rng.standard_normal(m) + 1j * rng.standard_normal(m))
        before = PartEvaluation("force", y, np.zeros(m, complex), np.full(m, s), np.ones(m), 1.0)
        after = PartEvaluation("force", y, delta, np.full(m, s), np.ones(m), 1.0)
        zs.append(significance(before, after))
    zs = np.array(zs)
    expected = -np.sum(np.abs(delta) ** 2) / np.sqrt(2 * np.sum(np.abs(delta) ** 2) * s)
    assert np.mean(zs) == pytest.approx(expected, abs=4 / np.sqrt(2000))
    assert np.std(zs) == pytest.approx(1.0, abs=0.06)
    assert np.mean(zs > 3.0) < 0.002


def test_align_angle_recovers_a_rotation():
    rng = np.random.default_rng(4)
    c = rng.standard_normal((3, 9)) + 1j * rng.standard_normal((3, 9))
    for theta in (0.1, 2.5, 6.0):
        assert align_angle(rotate(c, theta), c) == pytest.approx(theta, abs=1e-6)


def test_dft_band_power_is_parseval():
    rng = np.random.default_rng(5)
    x = rng.standard_normal((2, 1001)) + 3.0
    full = np.ones(501, dtype=bool)
    np.testing.assert_allclose(dft_band_power(x, full), np.sum(x**2, axis=1), rtol=1e-12)
    dc = np.zeros(501, dtype=bool)
    dc[0] = True
    np.testing.assert_allclose(dft_band_power(x, dc), x.shape[1] * np.mean(x, axis=1) ** 2, rtol=1e-12)


def test_expected_welch_keeps_a_flat_density_and_the_area_of_a_notch():
    fine = np.arange(0.0, 50.0, 0.01)
    flat = np.full((1, fine.size), 2.0)
    f = np.arange(10.0, 40.0, 0.5)
    np.testing.assert_allclose(expected_welch(fine, flat, f, 2000, 1000.0), 2.0, rtol=1e-9)
    notch = np.where(np.abs(fine - 25.0) < 0.05, 0.0, 1.0)[None, :]
    smeared = expected_welch(fine, notch, np.arange(20.0, 30.0, 0.01), 2000, 1000.0)
    # a 0.1 Hz notch seen with 0.5 Hz lines: shallower, wider, same missing area
    assert smeared.min() > 0.5
    assert np.sum(1 - smeared) * 0.01 == pytest.approx(np.sum(1 - notch) * 0.01, rel=0.02)


def test_fold_frequency():
    np.testing.assert_allclose(fold_frequency([100.0, 600.0, 1000.0, 1200.0, 1650.0], 1000.0),
                               [100.0, 400.0, 0.0, 200.0, 350.0])


def test_parts_separate_the_causes():
    """A channel delay leaves the force model right and the structure wrong; runout the opposite."""
    delay = compare_records(hidden_effect_case("channel_delay", 0).records, CELL.model)
    assert delay.errors["force"] < 1e-3 < 0.01 < delay.errors["structure"]
    runout = compare_records(hidden_effect_case("runout", 0).records, CELL.model)
    assert runout.errors["structure"] < 1e-3 < 0.01 < runout.errors["force"]


def test_bad_records_are_rejected():
    rec = hidden_effect_case("none", 0).records[0]
    with pytest.raises(InputError, match="spindle_rpm"):
        prepare_views([replace(rec, cut=replace(rec.cut, spindle_rpm=None))])
    with pytest.raises(InputError, match="cutting_coefficients"):
        prepare_views([replace(rec, material=None)])
    with pytest.raises(InputError, match="cut window of at least"):
        prepare_views([replace(rec, data=rec.data[:, :1000])])
    with pytest.raises(InputError, match="at least one record"):
        diagnose([], CELL.model)
