"""A cut during which the arm's modes drift (DOMAIN.md's ``pose_drift``): ``identify --output-only``
names the drifting modes from their frequencies refitted on the records' halves (session 26).

The records come from ``tests/drifting_records.py`` (each modal equation integrated exactly per
sample with that sample's frequency; nothing of robomill's simulator)."""

from __future__ import annotations

import numpy as np
import pytest
from drifting_records import drifting_record

from oma.output_only.identify import DRIFT_Z, _half_record_shift, identify_output_only
from oma.synthetic import paper_like_model


@pytest.fixture(scope="module")
def identified():
    return {c: identify_output_only([drifting_record(c, 0)[0]]) for c in (0.0, -0.15)}


def test_modes_drifting_by_15_percent_are_named_with_their_halves(identified):
    """Every frequency falling by 15 % over the 20 s record: at least one mode is named, the model
    is not trusted, and each named mode's halves bracket its drift: the second half lower, each
    within 3 % of the truth's mean over that half (the frequencies there are 0.9625 and 0.8875 of
    the start's; the halves differ by 8 %)."""
    res = identified[-0.15]
    assert res.drifting_modes and not res.trusted
    assert any("drifted during the cut" in w for w in res.warnings)
    truth = paper_like_model()
    for k in res.drifting_modes:
        f1, f2 = res.modes.half_freq_hz[k]
        assert f2 < f1 and abs(_half_record_shift(res.modes)[1][k]) > DRIFT_Z
        r = int(np.argmin(np.abs(truth.natural_frequency_hz * 0.925 / res.modes.freq_hz[k] - 1)))
        f0 = truth.natural_frequency_hz[r]
        assert abs(f1 / (0.9625 * f0) - 1) < 0.03 and abs(f2 / (0.8875 * f0) - 1) < 0.03
    entries = res.to_dict()["drifting_modes"]
    assert [e["freq_hz"] for e in entries] == [res.modes.freq_hz[k] for k in res.drifting_modes]


def test_a_steady_record_names_no_drift_and_its_halves_agree_within_their_noise(identified):
    """The same record with no drift: nothing named, and every mode's halves within 3 standard
    errors of their difference."""
    res = identified[0.0]
    assert res.drifting_modes == () and res.to_dict()["drifting_modes"] == []
    assert not any("drifted" in w for w in res.warnings)
    z = _half_record_shift(res.modes)[1]
    assert np.all(np.isfinite(z)) and np.all(np.abs(z) < 3.0)
