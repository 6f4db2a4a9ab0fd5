"""Welch spectra, H1/H2/Hv, coherence and the Bendat & Piersol random error."""

import numpy as np
import pytest
from scipy import signal as sps

from oma.frf_estimate import _line_average, estimate_frf, frf_agreement, frf_from_spectra, noise_lines
from oma.frf_table import FRFTable
from oma.modal import ModalModel
from oma.signals import PreparedSignals
from oma.spectra import equivalent_averages, pool_spectra, welch_spectra
from oma.synthetic import simulate_response

FS = 1000.0


def test_welch_psd_integrates_to_the_variance_and_layout_matches_scipy():
    rng = np.random.default_rng(0)
    u = rng.standard_normal((2, 40000)) * np.array([[3.0], [1.0]])
    y = np.vstack([u[0] + 0.5 * u[1], u[1]])
    sp = welch_spectra(u, y, FS, nperseg=512)
    var = np.real(np.diagonal(sp.suu)).sum(axis=0) * sp.df_hz
    # 40000 samples: a variance estimate scatters by sqrt(2/N) = 0.7 %; 3 % is > 4 sigma
    np.testing.assert_allclose(var, [9.0, 1.0], rtol=0.03)
    _, ref = sps.csd(u[1], y[0], fs=FS, nperseg=512, detrend="linear")
    np.testing.assert_allclose(sp.syu[0, 1], ref, rtol=1e-12)


def test_equivalent_averages_match_the_monte_carlo_variance_of_welch():
    rng = np.random.default_rng(1)
    nperseg, n = 64, 64 * 8
    est = []
    for _ in range(600):
        x = rng.standard_normal(n)
        _, p = sps.welch(x, fs=1.0, nperseg=nperseg)
        est.append(p[5:25])
    est = np.array(est)
    n_mc = 1.0 / np.mean(np.var(est, axis=0) / np.mean(est, axis=0) ** 2)
    n_welch = equivalent_averages(15, nperseg, nperseg // 2)
    # 600 realisations x 20 lines: the Monte-Carlo value is good to about 3 %
    assert n_welch == pytest.approx(n_mc, rel=0.08)
    assert n_welch < 15  # overlapping segments are not independent


def _mimo_records(seed, *, output_noise=0.0, input_noise=0.0, seconds=30.0):
    """Two-input two-output system with known receptance, white forces, optional sensor noise."""
    rng = np.random.default_rng(seed)
    model = ModalModel([12.0, 30.0], [0.04, 0.03], [1e6, 2e6], [[1, 0.3, 0], [0, 1, 0]])
    n = int(seconds * FS)
    f = np.zeros((3, n + 3000))
    f[:2] = 20.0 * rng.standard_normal((2, n + 3000))
    x = simulate_response(model, f, FS)[:, 3000:]
    f = f[:, 3000:]
    fx = f + input_noise * rng.standard_normal(f.shape) * np.array([[1], [1], [0]])
    xx = x + output_noise * rng.standard_normal(x.shape)
    fx[2] = np.nan
    xx[2] = np.nan
    return model, PreparedSignals(fx, xx, FS, 0.0, "displacement", None)


def test_h1_is_unbiased_under_output_noise_and_its_error_band_is_calibrated():
    # H1 is free of output-noise bias (Bendat & Piersol 9.3); the scatter of H1 over independent
    # records must match the predicted random error
    errs, preds = [], []
    for seed in range(6):
        # 4096-sample segments (0.24 Hz) keep the resolution bias (Bendat & Piersol: -(B_e/B_r)^2/3 =
        # -1.5 % at the peaks) below the random error being tested
        model, sig = _mimo_records(seed, output_noise=2e-6, seconds=40.0)
        est = estimate_frf(sig, nperseg=4096)
        f = est.freq_hz
        sel = (f > 8) & (f < 40)
        g = model.receptance(f[sel])
        errs.append(est.receptance_m_N[:2, :2, sel] - g[:2, :2])
        preds.append(est.std_m_N[:2, :2, sel])
    errs, preds = np.array(errs), np.array(preds)
    ratio = np.sqrt(np.mean(np.abs(errs) ** 2) / np.mean(preds**2))
    # the ratio of empirical to predicted rms error; the first-order formula and ~8 averages
    # leave ~20 % uncertainty, a bias or a wrong dof would show as a factor
    assert 0.75 < ratio < 1.3
    bias = np.abs(np.mean(errs, axis=0)) / np.sqrt(np.mean(preds**2, axis=0) / errs.shape[0])
    assert np.median(bias) < 1.5  # the mean error is within the standard error of the mean


def test_few_averages_give_an_error_band_without_heavy_tails():
    # 14 s in 4.1 s segments: 4.8 averages, 2 inputs, so the noise spectrum at one line has 3.8
    # degrees of freedom. Used line by line, the predicted error is too small at the lines that
    # came out quiet by chance: rms z 1.34 and 10.3 % of the errors beyond 2 predicted sd (a complex
    # Gaussian has 1.8 %). Averaged over 7 lines (noise_lines), it is the error's own size.
    z = []
    for seed in range(6):
        model, sig = _mimo_records(seed, output_noise=2e-6, seconds=14.0)
        est = estimate_frf(sig, nperseg=4096)
        assert noise_lines(est.n_averages, 2) == 7
        f = est.freq_hz
        sel = (f > 8) & (f < 40)
        g = model.receptance(f[sel])
        z.append((np.abs(est.receptance_m_N[:2, :2, sel] - g[:2, :2]) / est.std_m_N[:2, :2, sel]).ravel())
    z = np.concatenate(z)
    assert 0.85 < np.sqrt(np.mean(z**2)) < 1.25
    assert np.mean(z > 2.0) < 0.06


def test_the_noise_average_rule_and_its_sums():
    # enough lines for 24 degrees of freedom, odd, and none once a line has them
    assert noise_lines(4.79, 3) == 9 and noise_lines(7.7, 3) == 5 and noise_lines(40.0, 3) == 1
    # values eight decades apart stay positive (a running sum's cancellation made them negative),
    # a constant stays itself to the ends, and a line that is not finite is not spread
    x = np.where(np.arange(200) % 2 == 0, 1e-12, 1e-20)[:, None] * np.ones((1, 2))
    x[50, 1] = np.nan
    y = _line_average(x, 9)
    assert np.all(y[np.isfinite(x)] > 0)
    assert np.isnan(y[50, 1]) and np.all(np.isfinite(np.delete(y[:, 1], 50)))
    np.testing.assert_allclose(_line_average(np.full((30, 1), 3.0), 9), 3.0, rtol=1e-14)
    np.testing.assert_allclose(y[100, 0], (5 * 1e-12 + 4 * 1e-20) / 9, rtol=1e-12)


def test_h1_biased_low_and_h2_unbiased_under_input_noise():
    # input (force) noise biases H1 by S_ff / (S_ff + S_nn) (Bendat & Piersol), H2 not;
    # Hv with the right noise ratio is consistent when both channels are noisy
    model, sig = _mimo_records(7, input_noise=10.0, output_noise=2e-7, seconds=60.0)
    f_noise_ratio = 20.0**2 / (20.0**2 + 10.0**2)  # = 0.8
    h1 = estimate_frf(sig, nperseg=4096, estimator="h1")
    h2 = estimate_frf(sig, nperseg=4096, estimator="h2")
    hv = estimate_frf(sig, nperseg=4096, estimator="hv", noise_psd_ratio=(2e-7 / 10.0) ** 2)
    f = h1.freq_hz
    sel = (f > 10) & (f < 14)
    g = model.receptance(f[sel])[0, 0]

    def ratio(e):
        return np.mean(np.abs(e.receptance_m_N[0, 0, sel]) / np.abs(g))

    # ~26 averages over 16 lines: the mean ratio scatters by ~2 %
    assert ratio(h1) == pytest.approx(f_noise_ratio, abs=0.05)
    assert ratio(h2) == pytest.approx(1.0, abs=0.05)
    assert ratio(hv) == pytest.approx(1.0, abs=0.05)
    with pytest.raises(ValueError, match="estimator must be one of"):
        frf_from_spectra(h1.spectra, estimator="h3")


def test_pooling_two_records_adds_their_averages():
    _, a = _mimo_records(10, output_noise=1e-6, seconds=8.0)
    _, b = _mimo_records(11, output_noise=1e-6, seconds=8.0)
    one = estimate_frf(a, nperseg=1024)
    two = estimate_frf([a, b], nperseg=1024)
    assert two.n_averages == pytest.approx(2 * one.n_averages)
    sp_a = welch_spectra(a.force_N[:2], a.displacement_m[:2], FS, nperseg=1024)
    pooled = pool_spectra([sp_a, sp_a])
    np.testing.assert_allclose(pooled.syu, sp_a.syu)


def test_frf_agreement_measures_a_relative_error():
    model = ModalModel([10.0, 25.0], [0.05, 0.04], [1.5e6, 3e6], np.eye(3)[:2])
    f = np.linspace(1, 60, 300)
    ref = FRFTable.from_model(model, f, entries=("XX", "YY"))
    est = FRFTable.from_entries(f, {"XX": 1.1 * ref.entry("XX"), "YY": ref.entry("YY")})
    out = frf_agreement(est, ref, (2.0, 50.0))
    assert out["X"] == pytest.approx(0.1, rel=1e-9) and out["Y"] == pytest.approx(0.0, abs=1e-12)
    assert "Z" not in out
    with pytest.raises(ValueError, match="increasing"):
        frf_agreement(est, ref, (50.0, 2.0))
