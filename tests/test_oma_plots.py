"""Plots of the OMA results (Agg backend), and that importing oma pulls in no matplotlib."""

import subprocess
import sys

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

from oma.frf_table import FRFTable  # noqa: E402
from oma.identify import identify  # noqa: E402
from oma.synthetic import paper_like_model, synthetic_record  # noqa: E402


@pytest.fixture(scope="module")
def result():
    return identify([synthetic_record(duration_s=4.0, rng=7)], method="h1")


def test_frf_comparison_plot(result):
    import matplotlib.pyplot as plt

    ref = FRFTable.from_model(paper_like_model(), np.linspace(1, 100, 400))
    fig, axes = result.plot_frf(ref)
    assert axes.shape == (3, 3)
    mag = axes[0, 1]
    labels = [line.get_label() for line in mag.get_lines()]
    assert {"H1 estimate", "identified model", "reference"} <= set(labels)
    # the model line of Y peaks near 24.8 Hz
    model_line = [line for line in mag.get_lines() if line.get_label() == "identified model"][0]
    x, y = model_line.get_data()
    assert abs(x[np.argmax(y)] - 24.8) < 1.0
    plt.close(fig)


def test_force_spectrum_and_detectability_plots(result):
    import matplotlib.pyplot as plt

    fig, ax = result.plot_force_spectrum()
    assert len(ax.get_lines()) >= 6 + result.harmonics[0].freq_hz.size
    plt.close(fig)
    fig, ax = result.plot_detectability()
    res_lines = [line for line in ax.get_lines() if line.get_label().startswith("resolution")]
    assert res_lines and np.allclose(res_lines[0].get_ydata(), 15.0)
    plt.close(fig)
    fig, ax = result.modal_fit.diagram.plot()
    assert len(ax.get_lines()) > 0
    plt.close(fig)


def test_importing_oma_does_not_import_matplotlib():
    code = ("import sys, oma.identify, oma.fit, oma.timefit, oma.synthetic, oma.detectability;"
            "print('matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _lines(ax, label):
    return [line for line in ax.get_lines() if line.get_label() == label]


def test_reference_table_is_drawn_only_on_its_own_lines(result):
    import matplotlib.pyplot as plt

    # a hammer-like reference measured on 5-60 Hz only, plotted over 1-100 Hz
    ref_f = np.linspace(5.0, 60.0, 221)
    ref = FRFTable.from_model(paper_like_model(), ref_f)
    fig, axes = result.plot_frf(ref, freq_range_hz=(1.0, 100.0))
    for row in (0, 1):  # magnitude and phase
        for ax in axes[row]:
            (line,) = _lines(ax, "reference")
            x = np.asarray(line.get_xdata())
            # no extrapolation (the table's end values held) and no interpolation: its own lines
            assert x.min() >= ref_f[0] and x.max() <= ref_f[-1]
            np.testing.assert_array_equal(x, ref_f)
    plt.close(fig)


def test_phases_are_unwrapped_not_cut_at_180_degrees(result):
    import matplotlib.pyplot as plt

    # a reference with a pure delay of 15 ms: its phase falls steadily to about -540 degrees at
    # 100 Hz; a wrapped drawing jumps by 360 degrees three times
    f = np.linspace(1.0, 100.0, 991)
    delay_s = 0.015
    g = paper_like_model().receptance(f) * np.exp(-2j * np.pi * f * delay_s)
    ref = FRFTable.from_entries(f, {"XX": g[0, 0], "YY": g[1, 1], "ZZ": g[2, 2]})
    fig, axes = result.plot_frf(ref, freq_range_hz=(1.0, 100.0))
    for ax in axes[1]:
        (ref_line,) = _lines(ax, "reference")
        (model_line,) = _lines(ax, "identified model")
        (h1_points,) = _lines(ax, "H1 estimate")
        x, y = (np.asarray(v) for v in ref_line.get_data())
        # consecutive lines 0.1 Hz apart: the delay turns the phase by 0.54 degrees, a mode by a
        # few degrees; a +-360 degree cut would show as a jump of more than 180 degrees
        assert np.max(np.abs(np.diff(y))) < 90.0
        assert y[-1] - y[0] < -360.0  # the delay's full phase lag is drawn, not folded
        xm, ym = (np.asarray(v) for v in model_line.get_data())
        assert np.max(np.abs(np.diff(ym))) < 90.0
        # each H1 point lies on the branch of the model (within 180 degrees of it)
        xp, yp = (np.asarray(v) for v in h1_points.get_data())
        assert np.all(np.abs(yp - np.interp(xp, xm, ym)) <= 180.0 + 1e-9)
    plt.close(fig)
