"""Pieces of the time-domain maximum-likelihood estimator (oma.timefit, oma.quantised)."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal as sps

from oma.identify import identify
from oma.modal import ModalModel
from oma.quantised import input_noise_scale
from oma.timefit import modal_response
from oma.signals import prepare_record
from oma.synthetic import mode_filter, paper_like_model, synthetic_record

TRUTH = paper_like_model()


def _participation(fn, k, directions):
    """Modal-form participation vectors ``phi_r = u_r w_r / sqrt(k_r)``."""
    w = 2 * np.pi * np.asarray(fn)
    return np.asarray(directions, dtype=float) * (w / np.sqrt(k))[:, None]


def test_input_noise_scale_is_the_closed_form_response_to_white_force_noise():
    # white force noise of variance v per sample is a two-sided PSD v / fs; through a single mode
    # G = 1 / (k (1 - r^2 + 2 i zeta r)) the response variance is (v / fs) pi fn / (2 zeta k^2)
    fs, v = 1000.0, 0.6
    fn, zeta, k = np.array([10.0, 31.0]), np.array([0.05, 0.02]), np.array([2e6, 5e6])
    phi = _participation(fn, k, [[1, 0, 0], [0, 0, 1]])
    prob = SimpleNamespace(records=[{"force_noise": v}], fs=fs)
    got = input_noise_scale(prob, fn, zeta, phi)
    expected = np.sqrt(v / fs * np.pi * fn / (2 * zeta * k**2))
    np.testing.assert_allclose(got[[0, 2]], expected, rtol=1e-12)  # X sees the first mode, Z the second
    assert got[1] == 0.0
    assert input_noise_scale(SimpleNamespace(records=[{"force_noise": 0.0}], fs=fs), fn, zeta, phi) is None


def test_input_noise_scale_matches_the_sampled_impulse_responses_with_cross_terms():
    # two close, oblique modes (a robot's X and Z modes, 5 % apart) and a third: the closed-form
    # cross-correlations against the sum of squares of the exactly discretised impulse responses
    # h_oj[n] = sum_r phi_ro phi_rj g_r[n]; 1 %: the first-order hold's spectrum at 1 kHz
    fs, v = 1000.0, 0.56
    fn, zeta, k = np.array([10.0, 10.5, 24.8]), np.array([0.05, 0.05, 0.04]), np.array([2e6, 1.5e6, 3e6])
    dirs = np.array([[0.6, 0.0, 0.8], [0.8, 0.1, 0.3], [0.1, 1.0, 0.2]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    phi = _participation(fn, k, dirs)
    impulse = np.zeros(int(12 * fs / np.min(2 * np.pi * fn * zeta)))
    impulse[0] = 1.0
    g = np.array([sps.lfilter(*mode_filter(f, z, fs), impulse) for f, z in zip(fn, zeta)])
    h = np.einsum("ro,rj,rn->ojn", phi, phi, g)
    sampled = np.sqrt(v * np.sum(h**2, axis=(1, 2)))
    got = input_noise_scale(SimpleNamespace(records=[{"force_noise": v}], fs=fs), fn, zeta, phi)
    np.testing.assert_allclose(got, sampled, rtol=0.01)
    # the cross terms matter here: without them an output would be off by more than 5 %
    alone = np.sqrt(sum(input_noise_scale(SimpleNamespace(records=[{"force_noise": v}], fs=fs),
                                          fn[[r]], zeta[[r]], phi[[r]]) ** 2 for r in range(3)))
    assert np.max(np.abs(alone / sampled - 1)) > 0.05


def test_an_output_crossing_one_rounding_boundary_keeps_its_stiffness():
    # a 20 s record whose Z displacement sits on one boundary of the 15 um grid (two levels): a
    # probit-like likelihood identifies only amplitude / error scale, so the error scale is tied
    # to the response to the force sensor's noise; before that the Z stiffness came out +30 %
    rec = synthetic_record(duration_s=20.0, rng=10_015)
    sig = prepare_record(rec)
    levels = np.unique(np.round(sig.displacement_m[2] / sig.quantisation_step_m))
    assert levels.size == 2  # the situation this test is about
    idn = identify([rec])
    z = int(np.argmax(idn.model.directions[:, 2] ** 2 / (idn.model.stiffness_N_m * idn.model.damping_ratio)))
    assert idn.model.stiffness_N_m[z] == pytest.approx(TRUTH.stiffness_N_m[2], rel=0.10)  # issue 3's 20 s target
    assert idn.trusted


@pytest.mark.parametrize("output", ["acceleration", "velocity"])
def test_accelerometer_and_velocity_records_are_fitted_as_measured(output):
    # the time-domain fit models the measured derivative itself (q' or q'' = p - 2 zeta w q' - w^2 q)
    # instead of the frequency-domain integral, whose edge and low-frequency errors it took for
    # dynamics (measured before: X stiffness -31 % from a 20 s acceleration record); issue 3's 20 s
    # targets on every axis' dominant mode
    rec = synthetic_record(duration_s=20.0, rng=5, output=output)
    assert prepare_record(rec).motion is not None
    m = identify([rec]).model
    for a in range(3):
        j = int(np.argmax(m.directions[:, a] ** 2 / (m.stiffness_N_m * m.damping_ratio)))
        assert m.natural_frequency_hz[j] == pytest.approx(TRUTH.natural_frequency_hz[a], rel=0.01)
        assert m.damping_ratio[j] == pytest.approx(TRUTH.damping_ratio[a], rel=0.15)
        assert m.stiffness_N_m[j] == pytest.approx(TRUTH.stiffness_N_m[a], rel=0.10)


def test_modal_response_derivatives_are_consistent():
    # the three outputs of one mode to the same force: velocity = d/dt displacement and
    # acceleration = d/dt velocity (central differences, to the step's second order)
    fs, f0, z0 = 2000.0, 12.0, 0.04
    p = np.random.default_rng(1).standard_normal((1, 4000))
    p = sps.lfilter(*sps.butter(4, 20.0, fs=fs), p, axis=-1)  # smooth input: differences are accurate
    x, v, acc = (modal_response(p, f0, z0, fs, d)[0] for d in (0, 1, 2))
    dv = np.gradient(x, 1 / fs)[10:-10]
    da = np.gradient(v, 1 / fs)[10:-10]
    np.testing.assert_allclose(dv, v[10:-10], atol=2e-3 * np.abs(v).max())
    np.testing.assert_allclose(da, acc[10:-10], atol=2e-3 * np.abs(acc).max())


def test_a_mode_far_up_the_band_keeps_its_stiffness_from_a_band_limited_record():
    """The record of a continuous structure (:func:`oma.synthetic.band_limited_response`) with its X
    mode at 150 Hz, 0.15 fs: a first-order-hold model answers ``sinc^2(0.15) = 0.928`` short there
    and took the stiffness 6.6 % soft (4 records, session 20). With the force equalised for the
    hold (:func:`oma.synthetic.hold_equalised`) the force-based default finds it within 3 % (the
    scatter over 4 records was 0.4 %), and the frequency within 0.2 %."""
    model = ModalModel([150.0, 24.8, 10.0], [0.03, 0.04, 0.05], [1.5e6, 3.0e6, 2.0e6], np.eye(3))
    rec = synthetic_record(model, duration_s=5.0, rng=1, output="acceleration", spindle_rpm=2700.0)
    m = identify([rec]).model
    j = int(np.argmin(np.abs(m.natural_frequency_hz - 150.0)))
    assert m.natural_frequency_hz[j] == pytest.approx(150.0, rel=2e-3)
    assert m.stiffness_N_m[j] == pytest.approx(1.5e6, rel=0.03)


@pytest.mark.parametrize("derivative", [0, 1, 2])
def test_the_held_mode_driven_by_equalised_samples_answers_as_the_continuous_mode(derivative):
    """A sampled sinusoid (the band-limited force) through :func:`oma.timefit.modal_response`: its
    steady line is the continuous unit-mass mode's ``(i w)^d / (w_n^2 - w^2 + 2 i zeta w_n w)``
    within 4e-3 (complex) at 0.8, 1.0 and 1.1 times modes up to 0.2 fs (measured at most 3.5e-3)
    and 6e-3 at the resonance of a mode at 0.3 fs (measured 2.8-5.3e-3; off resonance there, and
    at 0.4 fs, the hold's aliases leave 1-18 %). The same held filter driven by the raw samples is
    26 % short at that resonance."""
    fs, n = 1000.0, 6000
    t = np.arange(n) / fs
    fit = slice(3000, 5000)

    def error(fm, f, equalise=True):
        p = np.cos(2 * np.pi * f * t)[None, :]
        y = modal_response(p, fm, 0.03, fs, derivative, held=None if equalise else p)[0]
        basis = np.column_stack([np.cos(2 * np.pi * f * t[fit]), np.sin(2 * np.pi * f * t[fit])])
        c = np.linalg.lstsq(basis, y[fit], rcond=None)[0]
        w, wn = 2 * np.pi * f, 2 * np.pi * fm
        return abs((c[0] - 1j * c[1]) * (wn ** 2 - w ** 2 + 2j * 0.03 * wn * w) / (1j * w) ** derivative - 1)

    for fm in (100.0, 200.0):
        for r in (0.8, 1.0, 1.1):
            assert error(fm, r * fm) < 4e-3, (fm, r)
    assert error(300.0, 300.0) < 6e-3
    assert error(300.0, 300.0, equalise=False) > 0.2
