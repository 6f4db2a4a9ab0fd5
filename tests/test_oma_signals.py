"""Signal preparation: cut window, detrending, frequency-domain integration, quantisation grid."""

import numpy as np
import pytest
from dataclasses import replace

from oma.errors import RecordError
from oma.signals import detrend, integrate_frequency_domain, prepare_record, window_slice
from oma.synthetic import synthetic_record
from oma.cutting import Sensors

FS = 1000.0


def test_integration_of_whole_cycle_tones_is_exact():
    # tones with a whole number of cycles in the record are periodic: dividing the spectrum by
    # (i w)^n is then the exact integral (up to float rounding)
    n = 2000
    t = np.arange(n) / FS
    amps, freqs = [3e-6, 1e-6], [10.5, 40.0]  # 21 and 80 cycles in 2 s
    x = sum(a * np.sin(2 * np.pi * f * t) for a, f in zip(amps, freqs))
    v = sum(a * 2 * np.pi * f * np.cos(2 * np.pi * f * t) for a, f in zip(amps, freqs))
    acc = sum(-a * (2 * np.pi * f) ** 2 * np.sin(2 * np.pi * f * t) for a, f in zip(amps, freqs))
    tol = 1e-9 * np.max(np.abs(x))  # float rounding of an FFT of 2000 points
    np.testing.assert_allclose(integrate_frequency_domain(v, FS, order=1, detrend_kind="constant"), x, atol=tol)
    np.testing.assert_allclose(integrate_frequency_domain(acc, FS, order=2, detrend_kind="constant"), x, atol=tol)


def test_integration_highpass_removes_slow_content_and_bad_order_raises():
    n = 1000
    t = np.arange(n) / FS
    slow = np.sin(2 * np.pi * 2.0 * t)
    fast = np.sin(2 * np.pi * 50.0 * t)
    out = integrate_frequency_domain(slow + fast, FS, order=1, highpass_hz=5.0, detrend_kind="constant")
    expected = -np.cos(2 * np.pi * 50.0 * t) / (2 * np.pi * 50.0)
    np.testing.assert_allclose(out, expected, atol=1e-9 * np.max(np.abs(expected)))
    with pytest.raises(ValueError, match="order must be 1 or 2"):
        integrate_frequency_domain(fast, FS, order=3)


def test_detrend_keeps_missing_axes_nan():
    x = np.vstack([np.arange(10.0), np.full(10, np.nan), 2 + np.arange(10.0) * 3])
    out = detrend(x)
    np.testing.assert_allclose(out[[0, 2]], 0.0, atol=1e-12)
    assert np.all(np.isnan(out[1]))
    with pytest.raises(ValueError, match="kind must be"):
        detrend(x, kind="cubic")


def test_window_selects_the_engaged_span_and_rejects_a_window_outside():
    rec = synthetic_record(duration_s=2.0, rng=1)
    rec_w = replace(rec, cut=replace(rec.cut, window_s=(0.5, 1.5)))
    sl = window_slice(rec_w)
    assert (sl.start, sl.stop) == (500, 1501)
    prepared = prepare_record(rec_w)
    assert prepared.n_samples == 1001 and prepared.start_s == pytest.approx(0.5)
    bad = replace(rec, cut=replace(rec.cut, window_s=(5.0, 6.0)))
    with pytest.raises(RecordError, match="cut.window_s"):
        window_slice(bad)
    reversed_window = replace(rec, cut=replace(rec.cut, window_s=(1.5, 0.5)))
    with pytest.raises(RecordError, match="increasing pair"):
        window_slice(reversed_window)


def test_quantisation_grid_is_detected_only_when_present():
    quantised = prepare_record(synthetic_record(duration_s=1.0, rng=2))
    assert quantised.quantisation_step_m == pytest.approx(1.5e-5)
    continuous = prepare_record(synthetic_record(duration_s=1.0, rng=2, sensors=Sensors(0.56, 0.75, None)))
    assert continuous.quantisation_step_m is None


def test_velocity_record_integrates_to_the_displacement():
    # same seed, same force: the velocity record integrated in the frequency domain must match the
    # (unquantised) displacement record above the high-pass, away from the record's ends
    sensors = Sensors(0.56, 0.75, None)
    disp = prepare_record(synthetic_record(duration_s=8.0, rng=3, sensors=sensors))
    vel = prepare_record(synthetic_record(duration_s=8.0, rng=3, sensors=sensors, output="velocity"), highpass_hz=3.0)
    assert vel.motion_quantity == "velocity" and vel.quantisation_step_m is None
    x_ref = integrate_frequency_domain(np.gradient(disp.displacement_m, 1 / FS, axis=1), FS, order=1, highpass_hz=3.0)
    mid = slice(1000, 7000)
    err = np.linalg.norm(vel.displacement_m[:, mid] - x_ref[:, mid]) / np.linalg.norm(x_ref[:, mid])
    # np.gradient's central difference costs (w T)^2 / 6 ~ 0.1 % at 25 Hz; 2 % leaves room for
    # the harmonic content at 90-450 Hz where its error grows
    assert err < 0.02


def test_record_without_motion_is_refused():
    rec = synthetic_record(duration_s=0.5, rng=4)
    keep = [i for i, c in enumerate(rec.channels) if c.quantity == "force"]
    no_motion = replace(rec, channels=tuple(rec.channels[i] for i in keep), data=rec.data[keep])
    with pytest.raises(RecordError, match="displacement, velocity or acceleration"):
        prepare_record(no_motion)
