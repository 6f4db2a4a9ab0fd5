"""Pieces of the time-domain maximum-likelihood estimator (oma.timefit, oma.quantised)."""

from types import SimpleNamespace

import numpy as np
import pytest

from oma.identify import identify
from oma.quantised import input_noise_scale
from oma.signals import prepare_record
from oma.synthetic import paper_like_model, synthetic_record

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
    # X sees only the first mode, Z only the second, Y nothing; 1 %: the first-order hold and the
    # truncation of the impulse response after eight time constants
    np.testing.assert_allclose(got[[0, 2]], expected, rtol=0.01)
    assert got[1] == 0.0
    assert input_noise_scale(SimpleNamespace(records=[{"force_noise": 0.0}], fs=fs), fn, zeta, phi) is None


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
