"""The background-level scaling under a coloured background force (issue 14; docs/output_only.md,
session 16, "the background's colour").

Ground truth: a background force whose power spectral density is a known power law in frequency,
``S(f) = S_ref (f / F_REF_HZ)^b`` on every axis (``b = -1`` pink). Two things are checked: what
the white carry of :mod:`oma.output_only.background` does with such a background (it moves the
level of the scaled modes' precision-weighted geometric-mean frequency to the target's; the
documented transfer error ``(f_t / f_c)^(b / 2)`` in stiffness, exactly), and, on a record, that
the refined input levels are the force's PSD at each mode's own frequency and that the interval
of the mode scaled by the background still holds its truth. A correction for the colour was
measured and not adopted (docs): these tests pin what the white carry does and promises.
"""

from __future__ import annotations

import numpy as np
import pytest

from oma.output_only.background import ANISOTROPY_LOG_SD, background_level, scale_by_background
from oma.output_only.identify import identify_output_only
from oma.output_only.scaling import StiffnessScaling
from oma.record import Channel, Record
from oma.synthetic import (PAPER_BACKGROUND_VARIANCE_N2, band_limited_milling_force, band_limited_response,
                           paper_like_cut, paper_like_material, paper_like_model, paper_like_tool)

TRUTH = paper_like_model()
FS = 1000.0
#: Frequency at which the coloured background's PSD equals the white one of the same variance, Hz.
F_REF_HZ = 15.0


def _scaling(k, stat, too_far, coef_sd=0.15):
    k = np.asarray(k, float)
    stat = np.asarray(stat, float)
    return StiffnessScaling(stiffness_N_m=k, statistical_relative_sd=stat, coefficient_relative_sd=coef_sd,
                            relative_sd=np.hypot(stat, coef_sd), interval_N_m=np.column_stack([k, k]),
                            theta_rad=np.zeros(1), lines_hz=np.array([90.0]), too_far=np.asarray(too_far, bool))


def test_the_white_carry_moves_the_level_of_the_references_geometric_mean_frequency():
    """Four scaled modes at 8-30 Hz whose levels follow ``S(f) ~ f^-1`` exactly, with equal
    errors: the common level is the power law at their geometric-mean frequency ``f_c`` (the
    mean of ``log S`` is ``log S(f_c)`` for a law linear in ``log f``), so a mode at 10 Hz gets the
    stiffness ``k (f_c / f_t)^(b / 2)``: 22 % stiff here, the documented transfer error. The
    colour does not go unseen: the levels' spread beyond their errors is taken up by the allowed
    spread between directions (DerSimonian-Laird), which widens the interval over that error."""
    slope, s_ref = -1.0, 0.25
    f = np.array([8.0, 12.0, 20.0, 30.0, 10.0])
    k = np.array([1.0e6, 2.0e6, 1.5e6, 3.0e6, 2.0e6])
    se = np.full(5, 0.05)
    psd = s_ref * (f / F_REF_HZ) ** slope
    sc = _scaling([*k[:4], np.nan], [0.02] * 4 + [np.inf], [False] * 4 + [True])
    bg = background_level(sc, psd / k ** 2, se)
    f_c = np.exp(np.mean(np.log(f[:4])))
    assert bg.psd_N2_Hz == pytest.approx(s_ref * (f_c / F_REF_HZ) ** slope, rel=1e-12)
    out, by = scale_by_background(sc, bg, psd / k ** 2, se)
    assert by.tolist() == [False] * 4 + [True]
    error = out.stiffness_N_m[4] / k[4]
    assert error == pytest.approx((f_c / f[4]) ** (slope / 2), rel=1e-12)
    assert bg.anisotropy_log_sd > ANISOTROPY_LOG_SD
    lo, hi = out.interval_N_m[4]
    assert lo <= k[4] <= hi


def coloured_record(seed: int, exponent: float = 1.0, output: str = "displacement") -> Record:
    """20 s of the paper-like cell at 2700 rpm (milling lines, no runout) under a coloured
    background force: the paper's variances per axis, each shaped in the frequency domain to the
    PSD ``sigma^2 / fs * (F_REF_HZ / f)^exponent`` (f floored at 0.5 Hz; 1 pink, 2 red, -1 blue),
    from rest after a 3 s preroll; ``output`` displacement or acceleration
    (:func:`oma.synthetic.band_limited_response`)."""
    rng = np.random.default_rng(seed)
    tool, material = paper_like_tool(), paper_like_material()
    cut = paper_like_cut(2700.0)
    n_pre, n = 3000, 20000
    t = (np.arange(n_pre + n) - n_pre) / FS
    force = band_limited_milling_force(tool, cut, material.cutting_coefficients, t, 0.5 * FS, runout_m=None)
    freq = np.fft.rfftfreq(t.size, 1.0 / FS)
    shape = (F_REF_HZ / np.maximum(freq, 0.5)) ** (exponent / 2)
    noise = np.fft.irfft(np.fft.rfft(rng.standard_normal((3, t.size)), axis=1) * shape, n=t.size, axis=1)
    force += np.sqrt(np.asarray(PAPER_BACKGROUND_VARIANCE_N2))[:, None] * noise
    unit = {"displacement": "m", "acceleration": "m/s2"}[output]
    motion = band_limited_response(TRUTH, force, FS, derivative=2 if output == "acceleration" else 0)[:, n_pre:]
    channels = tuple(Channel(a.lower(), output, a, unit) for a in ("X", "Y", "Z"))
    return Record(sample_rate_hz=FS, channels=channels, data=motion, tool=tool, cut=cut, material=material,
                  name=f"coloured-{exponent}-{seed}")


def _pink_record(seed: int):
    """20 s of displacement under a pink background (:func:`coloured_record`)."""
    return coloured_record(seed, 1.0, "displacement")


def _match(model, k):
    d = np.abs(model.natural_frequency_hz / TRUTH.natural_frequency_hz[k] - 1) + \
        (1 - np.abs(model.directions @ TRUTH.directions[k]))
    return int(np.argmin(d))


def test_pink_background_levels_at_each_modes_frequency_and_the_carry_stays_inside_its_interval():
    """Under a pink background the refined level ``P_r k_r^2`` (true stiffness) is the force's
    PSD along the mode at the mode's OWN frequency (session 15's sloped input level), within 3
    of its stated standard errors, for X (10.5 Hz), Y (24.8 Hz) and Z (10.0 Hz): the levels a
    colour correction would regress on are right. Z, scaled by the background's white carry from
    X and Y, comes out soft (the pooled level is that of about 16 Hz, below Z's by ``(16 / 10)``:
    about -20 %) but inside its 95 % interval. On seeds 0-9 of this generator: levels within 1.8
    standard errors (30 modes), Z -17 to -31 % with every interval covering (9 records; in the
    10th, seed 3, Z's refinement failed and the lines scaled it, flagged)."""
    res = identify_output_only([_pink_record(0)])
    modes = res.modes
    var = np.diag(PAPER_BACKGROUND_VARIANCE_N2)
    for k in range(3):
        j = _match(res.model, k)
        u = modes.directions[j]
        psd_true = u @ var @ u / FS * F_REF_HZ / TRUTH.natural_frequency_hz[k]
        se = modes.input_level_log_se[j]
        assert 0 < se < 0.5
        assert abs(np.log(modes.input_level[j] * TRUTH.stiffness_N_m[k] ** 2 / psd_true)) < 3 * se
    jz = _match(res.model, 2)
    assert res.scaled_by[jz] == "background"
    lo, hi = res.stiffness.interval_N_m[jz]
    assert lo <= TRUTH.stiffness_N_m[2] <= hi
    assert res.model.stiffness_N_m[jz] < TRUTH.stiffness_N_m[2]
