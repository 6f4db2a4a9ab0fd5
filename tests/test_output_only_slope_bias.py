"""The input slope ``beta`` of the output-only refinement on records without a noise floor
(session 16): its cause, and the slope the refinement reports (``refine_modes_ml(slopes=...)``).

Ground truth: the paper's cell (X 10.5 Hz / 5 %, Y 24.8 Hz / 4 %, Z 10.0 Hz / 5 %, unit directions
along the axes, one independent background force per axis) and no sensor noise, so the true
constant background ``N`` of the Whittle model is 0. Two generators: a circular one (the modal
filter applied in the frequency domain over the whole record: an exactly stationary periodic
process, its DFT bins independent, so what biases the fit is the estimator, not leakage), with a
background force whose spectral density is ``S0 (f / 15 Hz)^b``; and :func:`oma.synthetic.synthetic_record`
(time domain, white force: leakage and all, as the benchmark's records).

Every check is a mean over seeded records against a known value within :data:`K_SE` standard
errors of that mean (the records' own scatter over ``sqrt(n)``): at 3 the check of an unbiased
estimator fails by chance in 0.3 % of seed sets, and the seeds are fixed.
"""

from __future__ import annotations

import numpy as np
import pytest

from oma.modal import ModalModel
from oma.output_only._ml_fit import _fit_group, _known_tails, _signed
from oma.output_only._ml_inference import _input_slope
from oma.output_only.ml import refine_modes_ml
from oma.output_only.whittle import SLOPE_PRIOR_SD, _Model, _fisher, _nll, _spectrum, _unpack
from oma.synthetic import synthetic_record

FREQ_HZ = np.array([10.5, 24.8, 10.0])
DAMPING = np.array([0.05, 0.04, 0.05])
STIFFNESS = np.array([1.5e6, 3.0e6, 2.0e6])
DIRECTIONS = np.eye(3)                       # (mode, axis)
FS = 1000.0
DURATION_S = 20.0
#: Two-sided background force PSD at 15 Hz, N^2/Hz (the paper's ~250 N^2 per sample at 1 kHz).
FORCE_PSD = 0.25
#: A mean more than this many of its standard errors from the truth is taken as biased.
K_SE = 3.0


def _circular(seed, derivative, slope=0.0, duration_s=DURATION_S):
    """Motion (3, n) of the cell under a force of PSD ``S0 (f / 15)^slope`` per axis, circular."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * FS)
    f = np.fft.rfftfreq(n, 1.0 / FS)
    w = 2 * np.pi * f
    force = np.fft.rfft(rng.standard_normal((3, n)), axis=1) \
        * np.sqrt(FORCE_PSD * (np.maximum(f, 0.5) / 15.0) ** slope * FS)[None, :]
    x = np.zeros_like(force)
    for fr, zr, kr, ur in zip(FREQ_HZ, DAMPING, STIFFNESS, DIRECTIONS):
        wr = 2 * np.pi * fr
        x += np.outer(ur, (1j * w) ** derivative * wr ** 2 / (wr ** 2 - w ** 2 + 2j * zr * wr * w) / kr * (ur @ force))
    return np.fft.irfft(x, n=n, axis=1)


def _refine(x, derivative, slopes):
    """:func:`refine_modes_ml` as :mod:`oma.output_only.modes` calls it (unit-variance channels),
    started from the truth moved as SSI would (+1 % frequency, +15 % damping, directions a few
    degrees off); ``slopes`` is filled."""
    x = x - x.mean(axis=1, keepdims=True)
    ch = np.sqrt(np.mean(x ** 2, axis=1))
    u0 = (DIRECTIONS + np.array([[0.0, 0.05, -0.03], [0.04, 0.0, 0.03], [-0.03, 0.04, 0.0]])) / ch[None, :]
    u0 = (u0 / np.linalg.norm(u0, axis=1, keepdims=True)).T
    return refine_modes_ml([x / ch[:, None]], FS, FREQ_HZ * 1.01, DAMPING * 1.15, u0, derivative=derivative,
                           direction_scale=ch, add_missing=None, slopes=slopes)


def _mean_and_se(values):
    v = np.asarray(values, dtype=float)
    assert np.all(np.isfinite(v))
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size))


def test_signed_background_gradient_and_fisher_match_finite_differences():
    """With the background's entries as parameters (``signed_background``, here indefinite, the
    spectrum still positive definite) and the input's slope: the analytic gradient against central
    differences of the likelihood, the information against ``Re sum tr(S^-1 dS_i S^-1 dS_j)`` with
    ``dS`` by central differences, and :func:`_signed`'s map keeps the spectrum exactly."""
    rng = np.random.default_rng(5)
    m, l, k = 2, 3, 40
    w = 2 * np.pi * np.linspace(8.0, 12.5, k)
    tails = _known_tails(w, (np.array([24.8]), np.array([0.04]), np.array([[0.1], [1.0], [0.2]])), np.ones(l))
    mod = _Model(m, l, w, (w / w.mean()) ** 4, tails, True, (np.array([10.0, 10.5]), np.array([0.05, 0.05])),
                 slope=True)
    x = rng.normal(size=(k, l)) + 1j * rng.normal(size=(k, l))
    p = 0.3 * rng.normal(size=2 * m + m * l + 6 + 6 + 1)
    p[2 * m + m * l:2 * m + m * l + 6] += np.eye(3)[np.tril_indices(3)] * 3.0
    p[-7:-1] += [0.5, 0.0, 0.5, 0.0, 0.0, 0.5]
    signed, ps = _signed(p, mod)
    np.testing.assert_allclose(_spectrum(ps, signed)[-1], _spectrum(p, mod)[-1], rtol=1e-12, atol=1e-14)
    ps[-7:-1] = [0.2, 0.05, -0.005, 0.0, 0.01, 0.2]     # N's lower triangle: indefinite
    assert np.min(np.linalg.eigvalsh(_unpack(ps, signed).n)) < 0 < _nll(ps, signed, x)[0] < 1e30
    h = 1e-6
    steps = np.eye(ps.size) * h
    _, grad = _nll(ps, signed, x)
    num = np.array([(_nll(ps + e, signed, x)[0] - _nll(ps - e, signed, x)[0]) / (2 * h) for e in steps])
    np.testing.assert_allclose(grad, num, rtol=1e-5, atol=1e-6 * np.max(np.abs(num)))
    sinv = np.linalg.inv(_spectrum(ps, signed)[-1])
    ds = [(_spectrum(ps + e, signed)[-1] - _spectrum(ps - e, signed)[-1]) / (2 * h) for e in steps]
    ref = np.array([[np.real(np.einsum("kab,kbc,kcd,kda->", sinv, a, sinv, b)) for b in ds] for a in ds])
    ref[-1, -1] += 1.0 / SLOPE_PRIOR_SD ** 2     # the slope's prior, in the information too
    np.testing.assert_allclose(_fisher(ps, signed), ref, rtol=1e-6, atol=1e-7 * np.max(np.abs(ref)))


#: The noise floor of the control, as a share of each channel's mean power in the band (the Y
#: channel, the tail of the 24.8 Hz mode only, rises 20-fold across the band: 0.1 is about the
#: level of its low edge).
FLOOR = 0.1


@pytest.fixture(scope="module")
def close_pair_fits():
    """The close pair's group (X and Z modes, Y's tail known) fitted on 30 circular acceleration
    records under a white force: per record the fit's own slope and the reported one
    (:func:`_input_slope`), without a noise floor and with one (white noise of :data:`FLOOR` of
    each channel's power in the band: ``N`` well inside its cone)."""
    out = {"none": ([], []), "floor": ([], [])}
    for seed in range(30):
        x = _circular(100 + seed, 2)
        n = x.shape[1]
        spec = np.fft.rfft(x, axis=1) / np.sqrt(FS * n)
        f = np.fft.rfftfreq(n, 1.0 / FS)
        sel = (f >= 10.0 - 3.0) & (f <= 10.5 + 3.15)
        w = 2 * np.pi * f[sel]
        scale = np.sqrt(np.mean(np.abs(spec[:, sel]) ** 2, axis=1))
        tails = _known_tails(w, (FREQ_HZ[1:2], DAMPING[1:2], DIRECTIONS[1:2].T), scale)
        rng = np.random.default_rng(900 + seed)
        noise = np.sqrt(FLOOR / 2) * (rng.standard_normal((3, w.size)) + 1j * rng.standard_normal((3, w.size)))
        clean = spec[:, sel] / scale[:, None]
        for key, xb in (("none", clean.T), ("floor", (clean + noise).T)):
            u0 = np.array([[1.0, 0.05, 0.0], [0.0, 0.05, 1.0]]).T
            fit = _fit_group(w, xb, FREQ_HZ[[0, 2]], DAMPING[[0, 2]], u0 / np.linalg.norm(u0, axis=0), 2,
                             residuals="known", tails=tails, slope=True)
            assert fit is not None
            out[key][0].append(_unpack(fit[4], fit[5]).beta)
            out[key][1].append(_input_slope(fit[4], fit[5], xb)[0])
    return out


def test_without_a_noise_floor_the_fits_slope_is_biased_and_the_reported_one_is_not(close_pair_fits):
    """The cause: on noise-free accelerations under a white force the fit's own ``beta`` of the
    close pair comes out positive, more than :data:`K_SE` standard errors of its mean (here
    +0.16 +- 0.04: ``N`` on its boundary, positive, lifts the band's low edge, where the spectra
    rise as ``w^4``, and the slope tilts against it); the fit with ``N``'s sign free (the slope
    reported) is within :data:`K_SE` of 0 (here -0.00 +- 0.05)."""
    own, reported = close_pair_fits["none"]
    mean, se = _mean_and_se(own)
    assert mean > K_SE * se
    mean, se = _mean_and_se(reported)
    assert abs(mean) < K_SE * se


def test_with_a_noise_floor_the_fits_slope_is_unbiased(close_pair_fits):
    """The control: the same records with a white noise floor in every channel (``N`` inside its
    cone, no boundary): the fit's own slope and the reported one are both within :data:`K_SE`
    standard errors of 0 (here +0.01 +- 0.05 each), and within 0.05 of each other on average (one
    model, one optimum)."""
    own, reported = close_pair_fits["floor"]
    for values in (own, reported):
        mean, se = _mean_and_se(values)
        assert abs(mean) < K_SE * se
    assert abs(np.mean(own) - np.mean(reported)) < 0.05


def test_reported_slopes_of_white_accelerations_are_unbiased():
    """The benchmark's kind of record (:func:`oma.synthetic.synthetic_record`, 20 s of
    accelerations, white force, no harmonics) through :func:`refine_modes_ml`: over 16 records
    the mean reported slope of the close pair's group and of Y's are within :data:`K_SE` standard
    errors of 0 (here +0.03 +- 0.06 each; the fit's own, on 60 such records started from the
    truth: +0.24 +- 0.03 and +0.08 +- 0.03). Modes refined together report one slope."""
    model = ModalModel(FREQ_HZ, DAMPING, STIFFNESS, DIRECTIONS)
    pair, single = [], []
    for seed in range(16):
        rec = synthetic_record(model, duration_s=DURATION_S, rng=700 + seed, output="acceleration",
                               harmonics=False, runout_m=None)
        slopes = {}
        res = _refine(rec.data[3:], 2, slopes)
        assert np.all(res.fitted) and slopes["beta"].shape == (3,)
        assert slopes["beta"][0] == slopes["beta"][2] and np.all(slopes["beta_se"] > 0)
        pair.append(slopes["beta"][0])
        single.append(slopes["beta"][1])
    for values in (pair, single):
        mean, se = _mean_and_se(values)
        assert abs(mean) < K_SE * se


@pytest.mark.parametrize("slope", [-1.0, 1.0], ids=["pink", "blue"])
def test_reported_slopes_follow_a_power_law_background(slope):
    """Under a force whose PSD is ``~ f^b`` (circular displacement records, no noise floor), the
    reported slopes with the refinement's prior taken out (``beta / se^2`` over the data's own
    precision, ``1 / se^2 - 1 / SLOPE_PRIOR_SD^2``) average, precision-weighted over the two
    groups of 8 records, within :data:`K_SE` of their standard error of ``b`` (here -1.08 +- 0.11
    and +0.88 +- 0.10), and their z-scores have an rms under 2 (0.8 and 1.0: the stated errors
    are not optimistic)."""
    values, weights = [], []
    for seed in range(8):
        slopes = {}
        res = _refine(_circular(300 + seed, 0, slope), 0, slopes)
        assert np.all(res.fitted)
        for k in (0, 1):                      # the close pair's group, Y's group
            b, se = slopes["beta"][k], slopes["beta_se"][k]
            precision = 1.0 / se ** 2 - 1.0 / SLOPE_PRIOR_SD ** 2
            assert precision > 0
            values.append(b / se ** 2 / precision)
            weights.append(precision)
    values, weights = np.array(values), np.array(weights)
    mean = np.sum(weights * values) / np.sum(weights)
    assert abs(mean - slope) < K_SE / np.sqrt(np.sum(weights))
    assert np.sqrt(np.mean(weights * (values - slope) ** 2)) < 2.0
