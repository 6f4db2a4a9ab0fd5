"""Records sampled far above what the output-only analysis reads are decimated first
(:mod:`oma.decimation`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from oma.output_only.identify import identify_output_only
from oma.decimation import MIN_ANALYSIS_RATE_HZ, analysis_factor, decimate_rows, decimated, white_power
from oma.record import Channel, Record
from oma.synthetic import paper_like_cut, paper_like_model, paper_like_tool, synthetic_record


def _record(fs, data, rpm=2700.0, teeth=2, time_s=None):
    channels = tuple(Channel(a, "acceleration", a, "m/s2") for a in "xyz")
    return Record(fs, channels, data, replace(paper_like_tool(), teeth=teeth),
                  replace(paper_like_cut(), spindle_rpm=rpm), time_s=time_s)


def test_the_factor_keeps_the_rate_over_what_the_analysis_reads():
    n = 1000
    data = np.ones((3, n)) * np.arange(n)
    assert analysis_factor([_record(25600.0, data)], (4.0, 100.0)) == int(25600 // MIN_ANALYSIS_RATE_HZ) == 6
    assert analysis_factor([_record(5000.0, data)], (4.0, 100.0)) == 1          # under twice the floor
    assert analysis_factor([_record(25600.0, data)], (4.0, 1000.0)) == 2         # ten times the band's top
    # a 4-tooth tool at 30 000 rpm passes at 2 kHz: the rate stays at 2.5 times that or more
    assert analysis_factor([_record(25600.0, data, rpm=30000.0, teeth=4)], (4.0, 100.0)) == 5
    assert analysis_factor([_record(25600.0, data)], (4.0, 100.0), max_line_hz=2500.0) == 4
    # folds placed from the recorded rate, a gap inside a channel, or two rates: as recorded
    assert analysis_factor([_record(25600.0, data)], (4.0, 100.0), alias_up_to=4.0) == 1
    gap = data.copy()
    gap[1, 10] = np.nan
    assert analysis_factor([_record(25600.0, gap)], (4.0, 100.0)) == 1
    assert analysis_factor([_record(25600.0, data), _record(12800.0, data)], (4.0, 100.0)) == 1
    missing = data.copy()
    missing[2] = np.nan                                                           # an axis not recorded
    assert analysis_factor([_record(25600.0, missing)], (4.0, 100.0)) == 6


def test_decimation_keeps_the_band_and_removes_what_would_fold():
    fs, q, n = 24000.0, 6, 48000
    t = np.arange(n) / fs
    keep, fold = 0.3 * fs / q, 0.65 * fs / q         # 1.2 kHz kept; 2.6 kHz, over the new Nyquist (2 kHz)
    x = np.cos(2 * np.pi * keep * t + 0.4) + np.cos(2 * np.pi * fold * t) + 3.0 * t
    data = np.vstack([x, np.full(n, 0.25), np.full(n, np.nan)])   # a dead sensor, an axis not recorded
    rec = decimated(_record(fs, data, time_s=t + 5.0), q)
    assert rec.sample_rate_hz == fs / q and rec.n_samples == n // q
    np.testing.assert_array_equal(rec.time_s, t[::q] + 5.0)
    assert np.all(rec.data[1] == 0.25) and np.all(np.isnan(rec.data[2]))
    # away from the ends: the kept line's amplitude and phase, the trend, and nothing of the folded line
    y = rec.data[0] - 3.0 * rec.time
    mid = slice(200, -200)
    tt = rec.time[mid]
    basis = np.column_stack([np.cos(2 * np.pi * keep * tt), np.sin(2 * np.pi * keep * tt),
                             np.cos(2 * np.pi * (fs / q - fold) * tt), np.sin(2 * np.pi * (fs / q - fold) * tt)])
    coef = np.linalg.lstsq(basis, y[mid], rcond=None)[0]
    assert abs(coef[0] - 1j * coef[1]) == pytest.approx(1.0, abs=1e-3)
    assert np.angle(coef[0] - 1j * coef[1]) == pytest.approx(0.4, abs=1e-3)
    assert abs(coef[2] - 1j * coef[3]) < 0.01          # where the 2.6 kHz line would fold: 1.4 kHz
    assert decimated(rec, 1) is rec


def test_a_record_at_a_shop_rate_gives_the_modes_it_gives_undecimated():
    # 12 s of the paper cell's accelerations at 8 kHz: analysed at 4 kHz, the same modes within a
    # fraction of their standard errors, the same trust, at about half the CPU (not asserted)
    rec = synthetic_record(paper_like_model(), duration_s=12.0, sample_rate_hz=8000.0, output="acceleration", rng=5,
                           spindle_rpm=2700.0)
    fast = identify_output_only([rec])
    full = identify_output_only([rec], decimate=False)
    assert fast.analysis_rate_hz == 4000.0 and full.analysis_rate_hz == 8000.0
    assert fast.sample_rate_hz == full.sample_rate_hz == 8000.0
    assert fast.to_dict()["analysis_rate_hz"] == 4000.0
    assert fast.modes.n_modes == full.modes.n_modes == 3 and fast.trusted == full.trusted
    gap = np.abs(fast.modes.freq_hz - full.modes.freq_hz) / full.modes.freq_se_hz
    assert np.all(gap < 0.5), gap
    true = np.sort(paper_like_model().natural_frequency_hz)
    assert np.all(np.abs(fast.modes.freq_hz / true - 1) < 0.02)


def test_the_filter_is_scipys_own_and_its_white_power_is_what_noise_keeps():
    # the FIR spelt out is resample_poly's default bit for bit, and white noise decimated keeps
    # white_power(q) / q of its variance (200 000 samples: the variance is good to about 0.5 %)
    from scipy import signal as sps

    x = np.random.default_rng(0).standard_normal((2, 200_000))
    for q in (2, 5):
        y = decimate_rows(x, q)
        np.testing.assert_array_equal(y, sps.resample_poly(x, 1, q, axis=1, padtype="line")[:, :y.shape[1]])
        assert q * np.var(y[:, 100:-100]) == pytest.approx(white_power(q), rel=0.01)
    assert 0.95 < white_power(5) < 0.97 and white_power(1) == 1.0


def test_the_force_based_identify_decimates_a_shop_rate_record_and_not_a_rounded_one():
    # 8 s of force and acceleration at 8 kHz, the background at the benchmark's spectral level:
    # analysed at 4 kHz, the same modes as undecimated (0.001 Hz, 0.1 % in stiffness measured) at a
    # quarter of the CPU (3.0 against 11.4 s, not asserted), and the background variance reported
    # at the recorded rate as a white level (1826 / 2227 / 2007 against 1835 / 2228 / 2006 N^2
    # undecimated; the truth 1856 / 2224 / 2008)
    from oma.identify import _analysis_records, identify
    from oma.signals import prepare_record
    from oma.synthetic import PAPER_BACKGROUND_VARIANCE_N2

    fs = 8000.0
    background = tuple(np.array(PAPER_BACKGROUND_VARIANCE_N2) * fs / 1000.0)
    rec = synthetic_record(paper_like_model(), duration_s=8.0, sample_rate_hz=fs, rng=5, output="acceleration",
                           background_variance_N2=background)
    fast = identify([rec])
    full = identify([rec], decimate=False)
    assert fast.analysis_rate_hz == 4000.0 and full.analysis_rate_hz == fs
    assert fast.to_dict()["analysis_rate_hz"] == 4000.0
    assert fast.model.n_modes == full.model.n_modes == 3 and fast.trusted and full.trusted
    order_f, order_u = np.argsort(fast.model.natural_frequency_hz), np.argsort(full.model.natural_frequency_hz)
    np.testing.assert_allclose(fast.model.natural_frequency_hz[order_f], full.model.natural_frequency_hz[order_u],
                               atol=0.01)
    np.testing.assert_allclose(fast.model.stiffness_N_m[order_f], full.model.stiffness_N_m[order_u], rtol=0.01)
    np.testing.assert_allclose(fast.noise_variance_N2, full.noise_variance_N2, rtol=0.02)
    np.testing.assert_allclose(fast.noise_variance_N2, background, rtol=0.05)
    # a rounded displacement keeps its rate: the likelihood uses its grid
    rounded = synthetic_record(paper_like_model(), duration_s=2.0, sample_rate_hz=fs, rng=5)
    assert _analysis_records([rounded], [prepare_record(rounded)], None)[2] == 1
    assert _analysis_records([rec], [prepare_record(rec)], None)[2] == 2
