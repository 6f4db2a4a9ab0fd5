"""What the paper's shortcuts do to the identification, on the example cell (method 'h1', fast).

Physics checked: (1) leaving the harmonics in adds exactly their power to the background variance
estimate (Parseval); removing them recovers the simulated background; (2) a force sensor's
resonance multiplies the background variance estimate by the variance gain of the resonance on the
background spectrum, and inverse filtering undoes it.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal as sps

from planner.diagnosis.forcemodel import anti_alias_gain, sensor_gain
from planner.diagnosis.shortcuts import EXAMPLE_DIRECTORY, inverse_filter_sensor, paper_shortcuts

pytestmark = pytest.mark.skipif(not (EXAMPLE_DIRECTORY / "records" / "cut_short").exists(),
                                reason="example cell not generated")


@pytest.fixture(scope="module")
def report():
    return paper_shortcuts(method="h1", sensor_duration_s=4.0, seed=1)


def test_harmonics_left_in_add_their_power_to_the_background(report):
    h = report.harmonics
    excess = np.asarray(h.noise_variance_with_N2) - np.asarray(h.noise_variance_without_N2)
    power = np.asarray(h.extra["harmonic_power_N2"])
    # X and Y carry most of the harmonic power: the excess is that power within 5 %
    np.testing.assert_allclose(excess[:2], power[:2], rtol=0.05)
    # with the harmonics removed, the estimate is the simulated background within 20 % (1.1 s)
    np.testing.assert_allclose(h.noise_variance_without_N2, h.truth_noise_variance_N2, rtol=0.2)
    assert h.noise_variance_with_N2[0] > 10 * h.truth_noise_variance_N2[0]


def test_sensor_resonance_inflates_the_background_by_its_variance_gain(report):
    s = report.sensor
    fs = 1000.0
    f = np.linspace(0.0, fs / 2, 20001)
    _, bw = sps.freqz(*sps.butter(4, 400.0, fs=16 * fs), worN=f, fs=16 * fs)  # the simulated background shape
    shape = np.abs(bw) ** 2 * anti_alias_gain(f, fs) ** 2
    gain = np.trapezoid(shape * np.abs(sensor_gain(f, 200.0, 0.05)) ** 2, f) / np.trapezoid(shape, f)
    ratio = np.asarray(s.noise_variance_with_N2) / np.asarray(s.noise_variance_without_N2)
    np.testing.assert_allclose(ratio, gain, rtol=0.2)
    np.testing.assert_allclose(s.noise_variance_without_N2, s.truth_noise_variance_N2, rtol=0.25)


def test_inverse_filter_undoes_the_resonance():
    rng = np.random.default_rng(0)
    fs = 1000.0
    n = 4095  # odd: no Nyquist line, whose phase a real signal cannot carry
    x = rng.standard_normal((1, n))
    spec = np.fft.rfft(x)
    h = sensor_gain(np.fft.rfftfreq(n, 1 / fs), 200.0, 0.05)
    measured = np.fft.irfft(spec * h, n=n)
    np.testing.assert_allclose(inverse_filter_sensor(measured, fs, 200.0, 0.05), x, atol=1e-10)


def test_report_rows_for_the_demo(report):
    rows = report.rows()
    assert {r["shortcut"] for r in rows} == {"harmonics left in", "force-sensor dynamics ignored"}
    assert all({"quantity", "with_shortcut", "without_shortcut"} <= set(r) for r in rows)
    assert report.to_dict()["method"] == "h1"
