"""Plots of a diagnosis (Agg backend): what they show, and that the numerics do not import matplotlib."""

from __future__ import annotations

import subprocess
import sys

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from planner.diagnosis import detect_chatter, diagnose  # noqa: E402
from planner.diagnosis.cases import hidden_effect_case  # noqa: E402
from planner.diagnosis.plots import plot_chatter  # noqa: E402


def test_importing_the_diagnosis_does_not_import_matplotlib():
    code = ("import sys; import planner.diagnosis, planner.diagnosis.causes, planner.diagnosis.hurco, "
            "planner.diagnosis.shortcuts; print('matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("cause", ["unmodeled_mode", "runout"])
def test_diagnosis_plot_shows_residual_frf_and_evidence(cause):
    import matplotlib.pyplot as plt

    case = hidden_effect_case(cause, 0)
    d = diagnose(case.records, case.model)
    fig, axes = d.plot()
    try:
        assert len(axes) == 4
        res, mag, ph, ev = axes
        assert cause in fig._suptitle.get_text()
        # residual before/after: two series, the "after" one smaller overall
        data = d.plot_data["residual"]
        before, after = np.asarray(data["before"]), np.asarray(data["after"])
        assert np.sum(after**2) < 0.2 * np.sum(before**2)
        assert len(res.patches) + len(res.lines) >= 2
        # FRF: model and extended curves for the three axes, and the H1 estimate
        assert len(mag.lines) >= 6 and len(ph.lines) >= 6
        if cause == "unmodeled_mode":
            f = d.plot_data["frf"]["freq_hz"]
            # the extended model has a resonance near the fitted frequency that the model lacks
            fn = d.parameters["natural_frequency_hz"]
            k = np.argmin(np.abs(f - fn))
            gain = np.max(np.abs(d.plot_data["frf"]["after"][:, k]) / np.abs(d.plot_data["frf"]["before"][:, k]))
            assert gain > 2.0
        assert "evidence" in ev.get_title()
    finally:
        plt.close(fig)


def test_chatter_plot_marks_the_line_and_the_tooth_frequency():
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    fs = 1000.0
    t = np.arange(6000) / fs
    x = 10 * np.cos(2 * np.pi * 90 * t) + 5 * np.cos(2 * np.pi * 23.0 * t) + rng.normal(0, 0.5, t.size)
    res = detect_chatter(x[None, :], fs, 45.0, 2)
    assert res.chatter and res.frequency_hz == pytest.approx(23.0, abs=0.3)
    fig, ax = plot_chatter(res, title="synthetic")
    try:
        labels = [l.get_label() for l in ax.get_lines()]
        assert any(lab.startswith("chatter 23.") for lab in labels)
        assert any(lab.startswith("tooth 90.") for lab in labels)
    finally:
        plt.close(fig)
