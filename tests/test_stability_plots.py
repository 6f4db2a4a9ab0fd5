"""Plots of stability results (stability/plots.py), on the Agg backend, inspected not mocked."""

import subprocess
import sys

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from oma.cutting import Cut, CuttingCoefficients, Tool  # noqa: E402
from oma.modal import ModalModel  # noqa: E402
from stability.forced import forced_sweep  # noqa: E402
from stability.lobes import lobe_diagram, predict_point  # noqa: E402
from stability.plots import KIND_STYLE, plot_forced_sweep, plot_lobes  # noqa: E402

FN, ZETA, MASS = 922.0, 0.011, 0.03993
BENCH = ModalModel([FN], [ZETA], [MASS * (2 * np.pi * FN) ** 2], [[1, 0, 0]])
TOOL = Tool(2, 0.01)
COEF = CuttingCoefficients(6e8, 2e8)
LOW = Cut(1e-4, 0.0005, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])


@pytest.fixture(scope="module")
def diagrams():
    rpm = np.linspace(15000, 23000, 17)  # flip lobes below 18500 rpm, Hopf above (a/D = 0.05)
    z = lobe_diagram(BENCH, TOOL, LOW, COEF, rpm_range=(15000, 23000), n_rpm=200)
    s = lobe_diagram(BENCH, TOOL, LOW, COEF, rpm_range=(15000, 23000), rpm=rpm, method="sdm",
                     steps_per_mode_period=40, min_steps=80)
    return z, s


def test_importing_the_computations_does_not_import_matplotlib():
    code = ("import sys, stability.lobes, stability.sdm, stability.zoa, stability.forced, stability.oriented, "
            "stability.plots; sys.exit('matplotlib' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_lobe_plot_shows_zoa_and_sdm_with_flip_and_hopf_distinguished(diagrams):
    z, s = diagrams
    assert {"flip", "hopf"} <= set(s.kind)
    fig, ax = plot_lobes(z, s)
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    env = lines["ZOA envelope"]
    assert np.allclose(env.get_xdata(), z.rpm) and np.allclose(env.get_ydata(), z.depth_limit_m * 1e3)
    flip, hopf = lines[KIND_STYLE["flip"][3]], lines[KIND_STYLE["hopf"][3]]
    # each boundary line carries exactly the SDM points of its kind
    y_flip = np.asarray(flip.get_ydata(), dtype=float)
    assert np.array_equal(np.isfinite(y_flip), s.kind == "flip")
    assert np.allclose(y_flip[s.kind == "flip"], s.depth_limit_m[s.kind == "flip"] * 1e3)
    assert (flip.get_color(), flip.get_linestyle()) != (hopf.get_color(), hopf.get_linestyle())
    assert ax.get_xlabel() == "spindle speed (rpm)" and "mm" in ax.get_ylabel()
    assert ax.get_ylim()[1] >= np.nanmax(np.where(np.isfinite(s.depth_limit_m), s.depth_limit_m, np.nan)) * 1e3
    plt.close(fig)


def test_result_plot_methods_delegate_and_accept_axes(diagrams):
    z, _ = diagrams
    fig, ax = plt.subplots()
    fig2, ax2 = z.plot(ax=ax)
    assert fig2 is fig and ax2 is ax and len(ax.get_lines()) >= 2
    plt.close(fig)
    point = predict_point(BENCH, TOOL, LOW, COEF, spindle_rpm=20000, axial_depth_m=1e-3)
    fig, (a1, a2) = point.plot()
    assert len(a1.get_lines()) == 4  # FX, FY, FZ, |F|
    marker = [ln for ln in a2.get_lines() if ln.get_label().startswith("SLE")][0]
    assert np.allclose(marker.get_ydata(), [point.surface_location_error_m * 1e6])
    plt.close(fig)


def test_forced_sweep_plot():
    model = ModalModel([12.0, 25.0], [0.05, 0.04], [1.5e6, 3e6], [[1, 0.3, 0], [0, 1, 0.2]])
    tool = Tool(2, 0.0254, np.radians(30))
    cut = Cut(5e-4, 0.006, "down", feed_direction=[0, 1, 0], normal_direction=[-1, 0, 0])
    coef = CuttingCoefficients(1.2e8, 4.5e7, 2e7, 2e3, 3e3, 5e2)
    sweep = forced_sweep(model, tool, cut, coef, rpm=np.linspace(1000, 6000, 80), axial_depth_m=0.004)
    fig, (a1, a2) = sweep.plot()
    sle = a1.get_lines()[0]
    assert np.allclose(sle.get_ydata(), sweep.surface_location_error_m * 1e6)
    assert np.allclose(a2.get_lines()[0].get_ydata(), sweep.peak_force_N)
    assert a2.get_xlabel() == "spindle speed (rpm)"
    plt.close(fig)
    fig, ax = plt.subplots()
    with pytest.raises(ValueError, match="ax must hold 2 axes"):
        plot_forced_sweep(sweep, ax=ax)
    plt.close(fig)
