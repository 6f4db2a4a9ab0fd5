"""Cross-checks between independent methods: the time-domain simulator against the
semi-discretization limit and against the harmonic-balance forced response.

The simulator integrates the regenerative delay equation step by step (exact per-mode
discretisation, chip from the delayed surface); SDM builds the monodromy of the linearised
periodic system; the forced response sums harmonics of the rigid-tool force through the
receptance. They share only the force model of formats.md.
"""

from __future__ import annotations

import numpy as np
import pytest

from oma.cutting import Cut, CuttingCoefficients, Tool
from oma.modal import ModalModel
from stability.forced import forced_response
from stability.lobes import lobe_diagram
from stability.simulate import simulate

# Insperger & Stepan / Ding et al. benchmark: one mode along the feed, 2 straight teeth, slotting.
BENCH_MODEL = ModalModel(
    natural_frequency_hz=[922.0],
    damping_ratio=[0.011],
    stiffness_N_m=[0.03993 * (2 * np.pi * 922.0) ** 2],
    directions=[[1.0, 0.0, 0.0]],
)
BENCH_TOOL = Tool(teeth=2, diameter_m=0.02, helix_rad=0.0)
BENCH_COEF = CuttingCoefficients(Ktc_N_m2=6e8, Krc_N_m2=2e8)
BENCH_CUT = Cut(feed_per_tooth_m=1e-4, radial_depth_m=0.02, milling="down",
                feed_direction=[1, 0, 0], normal_direction=[0, -1, 0])

# SDM is converged to 1 % (rtol below); the simulator's default step rule leaves its onset ~1.3 %
# high on this 922 Hz mode (measured in benchmarks/bench_simulate.py). The issue asks for 3 %.
AGREEMENT = 0.03
SPEEDS_RPM = [6000.0, 9000.0, 12500.0, 17000.0, 22000.0]


@pytest.fixture(scope="module")
def sdm_limits():
    diagram = lobe_diagram(BENCH_MODEL, BENCH_TOOL, BENCH_CUT, BENCH_COEF, rpm_range=(5000, 25000),
                           method="sdm", rpm=SPEEDS_RPM, rtol=0.01)
    return np.asarray(diagram.depth_limit_m)


def _decay_ratio(rpm: float, depth: float) -> float:
    """How much of the non-periodic vibration is left at the end of ~500 tooth periods.

    The cut starts at rest and fully engaged, so the start-up transient excites every mode. The
    non-periodic part is ``d_k = q(t + T) - q(t)`` (forced vibration repeats with the tooth period
    T). Returned: RMS of ``|d|`` over the last fifth divided by its RMS over the first fifth. A
    stable cut decays by orders of magnitude; a chattering one grows until the teeth leave the cut
    and then holds a limit cycle, so the ratio stays of order one (which is why a growth *rate*
    measured late in the record reads about zero for chatter).
    """
    tooth_period = 60.0 / (rpm * BENCH_TOOL.teeth)
    result = simulate(BENCH_MODEL, BENCH_TOOL, BENCH_CUT, BENCH_COEF, spindle_rpm=rpm,
                      axial_depth_m=depth, duration_s=max(1.5, 500 * tooth_period))
    x = result.displacement_m[0]
    lag = int(round(tooth_period / (result.time_s[1] - result.time_s[0])))
    d = x[lag:] - x[:-lag]
    fifth = d.size // 5
    return float(np.sqrt(np.mean(d[-fifth:] ** 2)) / np.sqrt(np.mean(d[:fifth] ** 2)))


@pytest.mark.parametrize("index", range(len(SPEEDS_RPM)))
def test_simulator_onset_brackets_the_sdm_limit(sdm_limits, index):
    """Below the SDM limit by 3 % the simulated cut settles; above it by 3 % it chatters.

    Threshold: 3 % inside the boundary the dominant root decays at about zeta w_n * 0.03 = 1.9 /s
    (linearised), so over the 1.2 s between the first and last fifths of a 1.5 s record at most
    e^-2.3 = 0.10 of the vibration is left; a chattering cut keeps a limit cycle (ratio ~1) or grows.
    0.5 separates the two with a factor of 2 either side."""
    rpm, limit = SPEEDS_RPM[index], sdm_limits[index]
    assert np.isfinite(limit)
    assert _decay_ratio(rpm, (1.0 - AGREEMENT) * limit) < 0.5
    assert _decay_ratio(rpm, (1.0 + AGREEMENT) * limit) > 0.5


def test_forced_response_matches_the_simulated_steady_state():
    """A stable helical cut on an oblique robot mode plus a tool mode: the simulator's steady
    tooth-period motion equals the harmonic-balance forced response within 5 % of its range, and
    the surface location errors agree."""
    model = ModalModel(
        natural_frequency_hz=[40.0, 55.0, 700.0],
        damping_ratio=[0.05, 0.05, 0.03],
        stiffness_N_m=[2.0e6, 3.0e6, 2.0e7],
        directions=[[0.8, 0.6, 0.0], [-0.6, 0.8, 0.2], [1.0, 0.0, 0.0]],
    )
    tool = Tool(teeth=3, diameter_m=0.016, helix_rad=np.deg2rad(30.0))
    cut = Cut(feed_per_tooth_m=1e-4, radial_depth_m=0.004, milling="down",
              feed_direction=[0, 1, 0], normal_direction=[-1, 0, 0])
    coef = CuttingCoefficients(Ktc_N_m2=7e8, Krc_N_m2=2.1e8, Kac_N_m2=1e8, Kte_N_m=2e4, Kre_N_m=3e4)
    rpm, depth = 6000.0, 0.001
    forced = forced_response(model, tool, cut, coef, spindle_rpm=rpm, axial_depth_m=depth)

    # slowest decay time 1/(zeta w) = 80 ms: 1.5 s leaves e^-18 of the start-up transient
    sim = simulate(model, tool, cut, coef, spindle_rpm=rpm, axial_depth_m=depth, duration_s=1.5,
                   axial_slices=48)
    assert sim.chatter_growth(start_fraction=0.5) < 0.0  # the cut is stable
    period = 60.0 / (rpm * tool.teeth)
    last = sim.time_s >= sim.time_s[-1] - period
    x_sim = sim.displacement_m[:, last]
    x_hb = forced.displacement_at(sim.time_s[last])
    scale = np.max(np.abs(x_hb))
    assert np.max(np.abs(x_sim - x_hb)) < 0.05 * scale
    # static (mean-force) deflection and the finished wall
    np.testing.assert_allclose(x_sim.mean(axis=1), forced.static_displacement_m, atol=0.05 * scale)
    wall = -cut.normal_direction  # down milling: the wall is on the -n side of the tool
    t_fin = sim.time_s[last][0] + ((forced.finishing_time_s - sim.time_s[last][0]) % period)
    sle_sim = float(np.interp(t_fin, sim.time_s, sim.displacement_m.T @ -wall))
    assert sle_sim == pytest.approx(forced.surface_location_error_m, rel=0.05)
