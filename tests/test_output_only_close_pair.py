"""Two modes taken for one (issue 14, session 17; :mod:`oma.output_only.resolution`): over a mode's
band the vibration channels' spectral matrix is rank one for one mode, rank two for a merged pair.
Ground truth: the paper-like cell (X 10.5 Hz / 5 %, Y 24.8 Hz / 4 %, Z 10.0 Hz / 5 %: the X and Z
half-power bands overlap), white background force on all three axes, milling harmonics."""

from __future__ import annotations

import numpy as np
import pytest

from oma.modal import ModalModel
from oma.output_only.identify import identify_output_only
from oma.output_only.resolution import SHARE, band_shapes, unresolved_modes
from oma.synthetic import paper_like_model, synthetic_record

TRUTH = paper_like_model()
#: The paper's cell with Z moved to 40 Hz: every mode alone in its band, the same background.
APART = ModalModel([10.5, 24.8, 40.0], [0.05, 0.04, 0.05], [1.5e6, 3.0e6, 2.0e6], np.eye(3))
ACCELERATION = 2


def _record(seed, *, duration_s=20.0, rpm=2700.0, model=TRUTH):
    return synthetic_record(model, duration_s=duration_s, rng=seed, spindle_rpm=rpm, output="acceleration",
                            runout_m=None)


def _residual(record):
    """The motion channels with the milling lines regressed out, as identify checks them."""
    h = identify_output_only([record]).modes.harmonics[0]
    return h.residual, h.freq_hz


@pytest.mark.parametrize("duration_s", [20.0, 5.0])
def test_a_merged_pair_is_flagged_and_the_pair_is_not(duration_s):
    """The true modes leave nothing; the X and Z modes given as one mode between them (10.25 Hz,
    5 %) are flagged, with a second shape holding far more than ``SHARE`` of the band."""
    rec = _record(21, duration_s=duration_s)
    res, lines = _residual(rec)
    f, z = TRUTH.natural_frequency_hz, TRUTH.damping_ratio
    fs = rec.sample_rate_hz
    assert unresolved_modes([res], fs, (4.0, 100.0), f, z, lines, derivative=ACCELERATION) == []
    merged = unresolved_modes([res], fs, (4.0, 100.0), [10.25, 24.8], [0.05, 0.04], lines,
                              derivative=ACCELERATION)
    assert [u.index for u in merged] == [0]
    assert merged[0].share > merged[0].expected_share + 2 * SHARE
    assert "two or more modes taken for one" in merged[0].describe()


def test_clean_single_modes_are_not_flagged():
    """Every mode alone in its band (Z moved to 40 Hz), the same white background, 5 s records
    (the fewest bins per band), five seeds: identified or true modes, nothing flagged."""
    for seed in range(5):
        rec = _record(30 + seed, duration_s=5.0, model=APART)
        out = identify_output_only([rec])
        assert out.unresolved_modes == ()
        assert out.to_dict()["unresolved_modes"] == []
        h = out.modes.harmonics[0]
        stats = band_shapes([h.residual], rec.sample_rate_hz, (4.0, 100.0), APART.natural_frequency_hz,
                            APART.damping_ratio, h.freq_hz, derivative=ACCELERATION)
        assert all(s is not None and s.share < s.expected_share + SHARE for s in stats)


def test_a_milling_line_inside_a_band_is_not_a_second_mode():
    """720 rpm: the 24.0 Hz tooth line inside the 24.8 Hz / 4 % mode's band. Identified end to end,
    nothing flagged; a line left along X and Z at 24.0 Hz (not the Y mode's direction), about as
    strong as the mode over its band, is not flagged when it is a known line, and is when it is
    not (so the check does see such a line)."""
    rec = _record(5, rpm=720.0)
    out = identify_output_only([rec])
    assert out.unresolved_modes == ()
    h = out.modes.harmonics[0]
    res, lines = h.residual, h.freq_hz
    assert np.any(np.abs(lines - 24.0) < 0.01)
    t = np.arange(res.shape[1]) / rec.sample_rate_hz
    amp = 0.6 * np.std(res[1])  # its one bin's power about the Y mode's over its band
    left = res + amp * np.outer([1.0, 0.0, 1.0], np.sin(2 * np.pi * 24.0 * t))
    f, z = TRUTH.natural_frequency_hz, TRUTH.damping_ratio
    known = unresolved_modes([left], rec.sample_rate_hz, (4.0, 100.0), f, z, lines, derivative=ACCELERATION)
    assert known == []
    unknown = unresolved_modes([left], rec.sample_rate_hz, (4.0, 100.0), f, z, lines[np.abs(lines - 24.0) > 0.5],
                               derivative=ACCELERATION)
    assert [u.freq_hz for u in unknown] == [24.8] and unknown[0].share > 0.5


def test_a_merged_pair_in_a_short_record_is_not_trusted():
    """A 5 s record whose SSI took the X and Z modes for one (before session 17: trusted, one mode
    at 10.2 Hz): either both are found, or the one is named and the model is not trusted."""
    out = identify_output_only([_record(10_006, duration_s=5.0)])
    near = np.flatnonzero((out.modes.freq_hz > 9.3) & (out.modes.freq_hz < 11.2))
    assert near.size in (1, 2)
    if near.size == 1:
        assert [u.index for u in out.unresolved_modes] == list(near)
        assert not out.trusted
        assert out.to_dict()["unresolved_modes"][0]["freq_hz"] == pytest.approx(out.modes.freq_hz[near[0]])
        assert any("two or more modes taken for one" in w for w in out.warnings)
