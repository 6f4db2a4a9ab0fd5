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
