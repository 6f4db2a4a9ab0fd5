"""Zero-order approximation (stability/zoa.py) and the ZOA path of stability/lobes.py.

Ground truth: the 1-DOF characteristic equation solved independently (scipy brentq on
``Im[(1 - e^{-i w T}) G] = 0``), the closed-form minimum of the real part of a 1-DOF receptance,
the published milling example of Altintas (Manufacturing Automation, 2nd ed.); for two-branch
(oblique, several-mode) structures, the characteristic equation solved at a fixed speed without
any eigenvalue ordering (:func:`reference_limit`), lobe points sampled densely from unordered
``numpy.linalg.eigvals``, and the semi-discretization (an independent time-domain method).
"""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from oma.cutting import Cut, CuttingCoefficients, Tool
from oma.frf_table import FRFTable
from oma.modal import ModalModel
from oma.modal_io import read_modal_model
from stability import zoa
from stability.lobes import lobe_diagram, predict_point
from stability.oriented import average_directional_matrix, oriented_receptance
from stability.setup_io import read_setup

# The accuracy for the 1-DOF closed form.
CLOSED_FORM_RTOL = 1e-9

# Insperger-Stepan / Ding 1-DOF benchmark structure, here flexible along the normal direction.
FN, ZETA, MASS = 922.0, 0.011, 0.03993
STIFF = MASS * (2 * np.pi * FN) ** 2
TEETH, KT, KR = 2, 6e8, 2e8


def one_dof(direction=(0, 1, 0)):
    return ModalModel([FN], [ZETA], [STIFF], [direction])


def slot_cut():
    return Cut(1e-4, 0.01, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])


TOOL = Tool(TEETH, 0.01)
COEF = CuttingCoefficients(KT, KR)
# slotting, mode along n: the mean directional factor is B_nn = (N / 2 pi) int_0^pi -Kr cos^2 = -N Kr / 4
B_NN = -TEETH * KR / 4


def g1(f, zeta=ZETA):
    r = np.asarray(f) / FN
    return 1 / (STIFF * (1 - r**2 + 2j * zeta * r))


def closed_form_limit(rpm, zeta=ZETA, *, resonance_lines: bool = False):
    """Smallest depth over all lobes at this speed, from 1 = a (1 - e^{-iwT}) B_nn G(w), searched on
    a grid 0.0092 Hz apart; ``resonance_lines`` adds lines 1/1000 of ``zeta fn`` apart near the
    resonance (where the lobes of a lightly damped mode turn: tests/test_zoa_onset.py)."""
    period = 60.0 / (TEETH * rpm)

    def im(f):
        return np.imag((1 - np.exp(-2j * np.pi * f * period)) * g1(f, zeta))

    f = np.linspace(FN, 3 * FN, 200_001)
    if resonance_lines:
        f = np.union1d(f, FN * (1 + zeta * np.linspace(0.0, 40.0, 40_001)))
    v = im(f)
    best = np.inf
    for i in np.flatnonzero(np.sign(v[:-1]) != np.sign(v[1:])):
        fr = brentq(im, f[i], f[i + 1], xtol=1e-13, rtol=1e-15)
        val = B_NN * np.real((1 - np.exp(-2j * np.pi * fr * period)) * g1(fr, zeta))
        if val > 0:
            best = min(best, 1 / val)
    return best


def test_one_dof_curve_satisfies_the_characteristic_equation():
    f = np.linspace(FN * 1.001, 2 * FN, 500)
    c = zoa.limit_curves(one_dof(), TOOL, slot_cut(), COEF, f)
    depth = c.depth_m[0]
    # closed form: a = 1 / (2 B_nn Re G) where Re G < 0
    assert np.allclose(depth, 1 / (2 * B_NN * g1(f).real), rtol=CLOSED_FORM_RTOL)
    for k in (0, 3, 40):
        rpm = c.rpm(k)[0]
        period = 60 / (TEETH * rpm)
        resid = 1 - depth * (1 - np.exp(-2j * np.pi * f * period)) * B_NN * g1(f)
        assert np.max(np.abs(resid)) < CLOSED_FORM_RTOL
    # the second eigenvalue of the rank-one problem is zero: no lobe
    assert np.all(np.isinf(c.depth_m[1]))


def test_one_dof_minimum_is_the_closed_form():
    # min Re G = -1 / (4 k zeta (1 + zeta)) at (f/fn)^2 = 1 + 2 zeta, so a_min = 2 k zeta (1+zeta) / (-B_nn)
    a_min = 2 * STIFF * ZETA * (1 + ZETA) / (-B_NN)
    c = zoa.limit_curves(one_dof(), TOOL, slot_cut(), COEF, [FN * np.sqrt(1 + 2 * ZETA)])
    assert c.depth_m[0, 0] == pytest.approx(a_min, rel=CLOSED_FORM_RTOL)
    # every lobe bottoms out at a_min: the envelope never goes below it and touches it on a fine grid
    env = zoa.envelope(one_dof(), TOOL, slot_cut(), COEF, np.linspace(5000, 20000, 3001))
    assert env.depth_limit_m.min() >= a_min * (1 - CLOSED_FORM_RTOL)
    assert env.depth_limit_m.min() <= a_min * (1 + 1e-4)  # grid spacing 5 rpm: the bottom is flat


@pytest.mark.parametrize("rpm_range", [(4000.0, 20000.0), (300.0, 900.0)])
def test_one_dof_envelope_is_exact_at_grid_and_intersections(rpm_range):
    """At high speed a few lobes; at 300-900 rpm lobes up to k = 93 overlap (all must be found)."""
    rpm = np.linspace(*rpm_range, 121)
    env = zoa.envelope(one_dof(), TOOL, slot_cut(), COEF, rpm)
    grid = ~env.is_intersection
    assert np.array_equal(env.rpm[grid], rpm)
    check = np.flatnonzero(grid)[::12]
    ref = np.array([closed_form_limit(r) for r in env.rpm[check]])
    assert np.allclose(env.depth_limit_m[check], ref, rtol=CLOSED_FORM_RTOL)
    cusps = np.flatnonzero(env.is_intersection)
    assert cusps.size > 3
    for i in cusps[:3]:
        r, d = env.rpm[i], env.depth_limit_m[i]
        assert d == pytest.approx(closed_form_limit(r), rel=CLOSED_FORM_RTOL)
        # a cusp is a local maximum of the true envelope: lower just left and right of it
        assert closed_form_limit(r * (1 - 1e-6)) < d and closed_form_limit(r * (1 + 1e-6)) < d
    if rpm_range[0] < 1000:
        # 300 rpm: tooth passing 10 Hz, chatter ~930 Hz, so the lowest lobe there is k = 93
        assert env.lobe.max() == 93


def altintas_frf(f):
    def modal(fns, zetas, residues):
        w = 2 * np.pi * f
        out = np.zeros(f.shape, dtype=complex)
        for fn, z, r in zip(fns, zetas, residues):
            wn = 2 * np.pi * fn
            s = -z * wn + 1j * wn * np.sqrt(1 - z * z)
            out += r / (1j * w - s) + np.conj(r) / (1j * w - np.conj(s))
        return out

    gx = modal([452.77, 1448.53], [0.123718, 0.01651], [9.202966e-5 - 1.862195e-4j, -4.181562e-5 - 3.043618e-4j])
    gy = modal([516.17, 1407.64], [0.0243, 0.0324], [-2.3929e-6 - 1.721539e-4j, 4.055052e-5 - 3.618808e-4j])
    return FRFTable.from_entries(f, {"XX": gx, "YY": gy})


def test_altintas_published_example():
    """Altintas, Manufacturing Automation (2nd ed.): half-immersion down milling, 2 teeth,
    Kt = 1319.4 MPa, Kr = 788.8 MPa; published minimum stable depth 1.0147 mm, chatter ~1441 Hz.

    The published depth has five significant digits, so the tolerance is half a unit of the last
    one (0.05 um); the chatter frequency is quoted as "near 1441 Hz": within 1 Hz. Altintas's x, y
    are the feed and normal directions of formats.md; a sign error in the directional factors
    moves the minimum by far more than this (it changes which modes can chatter).
    """
    f = np.arange(100.0, 3000.0, 0.05)
    table = altintas_frf(f)
    tool = Tool(2, 0.03175)
    cut = Cut(1e-4, 0.03175 / 2, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])
    coef = CuttingCoefficients(1319.4e6, 788.8e6)
    c = zoa.limit_curves(table, tool, cut, coef, f)
    i = np.argmin(c.depth_m[0])
    assert abs(c.depth_m[0, i] - 1.0147e-3) <= 0.5e-7
    assert abs(f[i] - 1441.0) <= 1.0
    diagram = lobe_diagram(table, tool, cut, coef, rpm_range=(5000, 20000), method="zoa", n_rpm=1500)
    # the envelope's lowest grid point sits on a lobe bottom within the grid's resolution
    assert diagram.min_depth_limit_m == pytest.approx(1.0147e-3, rel=2e-3)


def test_frf_table_gives_the_modal_model_lobes():
    model = ModalModel([420.0, 610.0], [0.03, 0.02], [3e7, 5e7], [[1, 0.2, 0], [0.3, 1, 0]])
    cut = Cut(1e-4, 0.004, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])
    f = np.linspace(0, 2000, 40_001)
    table = FRFTable.from_entries(f, {k: model.receptance(f)[i, j] for k, i, j in
                                      [("XX", 0, 0), ("XY", 0, 1), ("YX", 1, 0), ("YY", 1, 1)]})
    rpm = np.linspace(6000, 15000, 60)
    a = zoa.envelope(model, TOOL, cut, COEF, rpm)
    b = zoa.envelope(table, TOOL, cut, COEF, rpm)
    grid_a, grid_b = ~a.is_intersection, ~b.is_intersection
    # linear interpolation of a 0.05 Hz table: relative error ~ (df / half-power bandwidth)^2,
    # (0.05 / 24)^2 ~ 4e-6
    assert np.allclose(a.depth_limit_m[grid_a], b.depth_limit_m[grid_b], rtol=2e-5)


def test_cross_terms_of_an_oblique_mode_change_the_limit():
    """Mode coupling: the same oblique mode seen only through XX and YY (no cross terms) gives a
    different limit; the full oriented receptance must be used."""
    u = np.array([1.0, 1.0, 0.0])
    model = ModalModel([500.0], [0.02], [2e7], [u])
    cut = Cut(1e-4, 0.005, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])
    f = np.linspace(1, 1500, 60_001)
    g = model.receptance(f)
    diag = FRFTable.from_entries(f, {"XX": g[0, 0], "YY": g[1, 1]})
    full = FRFTable.from_entries(f, {"XX": g[0, 0], "XY": g[0, 1], "YX": g[1, 0], "YY": g[1, 1]})
    a_full = zoa.limit_curves(full, TOOL, cut, COEF, f).depth_m.min()
    a_diag = zoa.limit_curves(diag, TOOL, cut, COEF, f).depth_m.min()
    a_model = zoa.limit_curves(model, TOOL, cut, COEF, f).depth_m.min()
    assert a_full == pytest.approx(a_model, rel=1e-6)
    assert abs(a_diag / a_full - 1) > 0.2


def test_lobe_diagram_zoa_result_and_json():
    d = lobe_diagram(one_dof(), TOOL, slot_cut(), COEF, rpm_range=(8000, 12000), n_rpm=50)
    assert d.method == "zoa" and d.rpm.size == 50 + d.is_intersection.sum()
    assert np.all(np.diff(d.rpm) > 0) and not d.rpm.flags.writeable
    assert set(d.kind) == {"hopf"} and d.lobe_rpm.size > 0
    out = json.loads(json.dumps(d.to_dict(), allow_nan=False))
    assert out["method"] == "zoa" and len(out["rpm"]) == len(out["depth_limit_m"])


def test_predict_point_zoa_on_an_frf_table():
    f = np.linspace(0, 3000, 30_001)
    model = one_dof()
    table = FRFTable.from_entries(f, {"YY": model.receptance(f)[1, 1]})
    limit = zoa.envelope(model, TOOL, slot_cut(), COEF, [10_000.0]).depth_limit_m[0]
    below = predict_point(table, TOOL, slot_cut(), COEF, spindle_rpm=10_000, axial_depth_m=0.9 * limit)
    above = predict_point(table, TOOL, slot_cut(), COEF, spindle_rpm=10_000, axial_depth_m=1.1 * limit)
    assert below.stable and not above.stable
    assert below.depth_limit_m == pytest.approx(limit, rel=1e-4)
    d = json.loads(json.dumps(below.to_dict(), allow_nan=False))
    for key in ("stable", "depth_limit_m", "surface_location_error_m", "peak_force_N", "peak_torque_N_m",
                "power_W", "mrr_m3_s"):
        assert key in d


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="strictly increasing"):
        zoa.envelope(one_dof(), TOOL, slot_cut(), COEF, [9000.0, 8000.0])
    with pytest.raises(ValueError, match="method must be one of 'zoa', 'sdm'"):
        lobe_diagram(one_dof(), TOOL, slot_cut(), COEF, rpm_range=(1000, 2000), method="fdm")
    with pytest.raises(ValueError, match="rpm_range"):
        lobe_diagram(one_dof(), TOOL, slot_cut(), COEF, rpm_range=(2000, 1000))
    with pytest.raises(ValueError, match="process damping needs method 'sdm'"):
        lobe_diagram(one_dof(), TOOL, slot_cut(), COEF, rpm_range=(1000, 2000), process_damping_N_m=1e4)
    with pytest.raises(TypeError, match="ModalModel or an FRFTable"):
        zoa.default_chatter_frequencies(object())


# ------------------------------------------------------------- two eigenvalue branches: swaps, cusps
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "kr500_acetal"
# The planner engineer's reproduction: the example's 720/735 Hz tool, 3 flutes, 45 deg helix,
# ae/D = 0.1 down milling in aluminium (Altintas's coefficients).
ALU_TOOL = Tool(3, 0.016, np.deg2rad(45.0))
ALU_COEF = CuttingCoefficients(7.96e8, 1.68e8, 2.22e8, 2.77e4, 3.08e4, 1.8e3)
LOW_IMMERSION = Cut(1e-4, 0.0016, "down", feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])
# Three oblique modes (with axial components) whose eigenvalue order swaps under low lobes: the
# envelope that skipped the swap intervals was up to 2.2x too high at 15 of the speeds below.
OBLIQUE = ModalModel([624.0, 782.0, 713.0], [0.027, 0.018, 0.028], [1.3e7, 1.85e7, 1.2e7],
                     [[-0.98, 0.18, 0.09], [-0.04, 1.0, 0.15], [-1.0, 0.07, -0.45]])

# reference_limit and the envelope solve the same equation to ~1e-14 in frequency by different
# routes (bisection on a product of imaginary parts, Illinois on the phase): measured 1e-13.
REFERENCE_RTOL = 1e-9
# The ZOA against the SDM on this tool at ae/D = 0.1: measured 0.5 % at 9937 rpm (test_plan.py
# quotes up to ~20 % between the two methods on this tool elsewhere; 49.9 mm was 8x off).
ZOA_SDM_RTOL = 0.05


@pytest.fixture(scope="module")
def tool_mode():
    return read_modal_model(EXAMPLE / "models" / "tool_mode.yaml")


def _plane_eigenvalues(structure, tool, cut, coef, f):
    """Unordered eigenvalues of ``G_or(f) B0``, shape (n, 2), by LAPACK."""
    b0 = average_directional_matrix(tool, cut, coef)
    return np.linalg.eigvals(np.einsum("ijk,jl->kil", oriented_receptance(structure, cut, f), b0))


def reference_limit(structure, tool, cut, coef, rpm, *, n_freq=100_000):
    """ZOA limits at the speeds ``rpm`` without eigenvalues ordered or followed.

    ``det(I - a (1 - e^{-iwT}) G B0) = 0`` has the two roots ``a_j = 1 / ((1 - e^{-iwT}) lambda_j)``;
    a real root is a critical depth. ``Im(a_1) Im(a_2)`` does not depend on which eigenvalue is
    called 1, so its sign changes on a dense log grid (the default ZOA range, 10x denser) are
    bisected and the smallest positive real root is the limit.
    """
    fn = structure.natural_frequency_hz
    f = np.geomspace(fn.min() / 3, fn.max() * 3, n_freq)
    lam_grid = _plane_eigenvalues(structure, tool, cut, coef, f)
    out = []
    for n in np.atleast_1d(rpm):
        period = 60.0 / (tool.teeth * n)

        def roots(ff, lam):
            a = 1.0 / ((1.0 - np.exp(-2j * np.pi * ff * period))[:, None] * lam)
            return a.imag.prod(axis=1), a

        g, _ = roots(f, lam_grid)
        i = np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)
        lo, hi, g_lo = f[i], f[i + 1], g[i]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            g_mid, _ = roots(mid, _plane_eigenvalues(structure, tool, cut, coef, mid))
            same = np.sign(g_mid) == np.sign(g_lo)
            lo, g_lo, hi = np.where(same, mid, lo), np.where(same, g_mid, g_lo), np.where(same, hi, mid)
        mid = 0.5 * (lo + hi)
        _, a = roots(mid, _plane_eigenvalues(structure, tool, cut, coef, mid))
        a = a[np.arange(a.shape[0]), np.argmin(np.abs(a.imag) / np.abs(a), axis=1)]
        real = (np.abs(a.imag) <= 1e-6 * np.abs(a)) & (a.real > 0)  # not a pole of a (e^{-iwT} = 1)
        out.append(a.real[real].min())
    return np.array(out)


def test_continued_branches_are_smooth_where_the_sorted_ones_swap(tool_mode):
    c = zoa.limit_curves(tool_mode, ALU_TOOL, LOW_IMMERSION, ALU_COEF, zoa.default_chatter_frequencies(tool_mode))
    finite = np.isfinite(c.depth_m[:, :-1]) & np.isfinite(c.depth_m[:, 1:])
    # premise: the sorted branches swap (a phase step of ~pi) where both depths are finite
    assert np.any(finite & (np.abs(np.diff(c.phase_rad, axis=1)) >= np.pi / 2))
    depth, phase = c.continued()
    finite = np.isfinite(depth[:, :-1]) & np.isfinite(depth[:, 1:])
    # the continued ones change by little between grid frequencies (the largest step of the phase
    # on this 10^4-point grid, at the steepest point of a 2 % damped mode, is ~0.02 rad)
    assert np.max(np.abs(np.diff(phase, axis=1))[finite]) < 0.1
    # and are the same two eigenvalues, which are those of LAPACK
    assert np.array_equal(np.sort(depth, axis=0), np.sort(c.depth_m, axis=0))
    lapack = _plane_eigenvalues(tool_mode, ALU_TOOL, LOW_IMMERSION, ALU_COEF, c.freq_hz).T
    lapack = np.where(np.abs(lapack[0] - c.eigenvalue[0]) < np.abs(lapack[1] - c.eigenvalue[0]), lapack,
                      lapack[::-1])
    assert np.allclose(lapack, c.eigenvalue, rtol=1e-10, atol=1e-12 * np.abs(c.eigenvalue).max())
    assert np.all(np.diff(c.eigenvalue.real, axis=0) <= 0)  # rows stay sorted: row 0 the larger Re


def test_lowest_lobe_survives_an_eigenvalue_order_swap(tool_mode):
    """The reproduction: at 9934-9941 rpm the envelope gave 49.9 mm (a higher lobe) and called a
    20 mm cut stable; lobe 1 at 749 Hz gives 6.0 mm, and the SDM agrees (spectral radius 2.2)."""
    args = (tool_mode, ALU_TOOL, LOW_IMMERSION, ALU_COEF)
    z = predict_point(*args, spindle_rpm=9937.0, axial_depth_m=0.02, method="zoa")
    s = predict_point(*args, spindle_rpm=9937.0, axial_depth_m=0.02, method="sdm")
    assert not s.stable and s.spectral_radius > 1.5
    assert not z.stable
    assert z.depth_limit_m == pytest.approx(s.depth_limit_m, rel=ZOA_SDM_RTOL)
    assert z.depth_limit_m == pytest.approx(reference_limit(*args, 9937.0)[0], rel=REFERENCE_RTOL)
    assert abs(z.chatter_frequency_hz - 749.0) < 1.0
    # across the old gap the limit follows lobe 1 smoothly: 0.1 rpm steps change it by < 1e-3
    env = zoa.envelope(*args, np.arange(9925.0, 9950.0, 0.1))
    assert np.all(env.lobe == 1) and not env.is_intersection.any()
    assert np.max(np.abs(np.diff(np.log(env.depth_limit_m)))) < 1e-3
    # the plotted lobes run through the gap too
    r, d = zoa.lobe_segments(zoa.limit_curves(*args, zoa.default_chatter_frequencies(tool_mode)), 9900.0, 9980.0)
    across = (r[:-1] <= 9937.0) & (r[1:] >= 9937.0) & (np.abs(d[:-1] / z.depth_limit_m - 1) < 0.01)
    assert across.any()


@pytest.mark.parametrize("name, rpm_range", [("tool_mode", (8000.0, 12000.0)), ("oblique", (6000.0, 20000.0))])
def test_envelope_is_never_above_a_densely_sampled_lobe_point(name, rpm_range, tool_mode):
    """Every lobe point ``(60 f / (N (eps / 2 pi + k)), 1 / (2 Re lambda))`` of either eigenvalue
    (LAPACK, unordered) at 5x the grid density is a critical point, so the envelope at its speed
    (evaluated there exactly) is at most its depth. Points more than 5 % above the envelope at the
    neighbouring grid speeds cannot be the lowest there and are not evaluated."""
    model = tool_mode if name == "tool_mode" else OBLIQUE
    lo, hi = rpm_range
    fn = model.natural_frequency_hz
    f = np.geomspace(fn.min() / 3, fn.max() * 3, 50_000)
    lam = _plane_eigenvalues(model, ALU_TOOL, LOW_IMMERSION, ALU_COEF, f).T.ravel()
    ff = np.tile(f, 2)[lam.real > 0]
    lam = lam[lam.real > 0]
    eps_turns = (np.pi + 2 * np.arctan2(lam.imag, lam.real)) / (2 * np.pi)
    k = np.arange(int(np.ceil(60 * ff.max() / (ALU_TOOL.teeth * lo))) + 1)
    r = 60 * ff[:, None] / (ALU_TOOL.teeth * (eps_turns[:, None] + k))
    d = np.broadcast_to(0.5 / lam.real[:, None], r.shape)
    inside = (r >= lo) & (r <= hi)
    r, d = r[inside], d[inside]
    grid = np.linspace(lo, hi, 2000)
    env = zoa.envelope(model, ALU_TOOL, LOW_IMMERSION, ALU_COEF, grid)
    on_grid = env.depth_limit_m[~env.is_intersection]
    j = np.clip(np.searchsorted(grid, r), 1, grid.size - 1)
    near = d <= 1.05 * np.maximum(on_grid[j - 1], on_grid[j])
    speeds, inv = np.unique(r[near], return_inverse=True)
    assert speeds.size > 2000
    at = zoa.envelope(model, ALU_TOOL, LOW_IMMERSION, ALU_COEF, speeds)
    assert np.all(at.depth_limit_m[~at.is_intersection][inv] <= d[near] * (1 + REFERENCE_RTOL))


def test_lobes_with_the_same_number_from_two_modes_meet_in_a_cusp():
    """The example cell: the robot's 24.8 Hz mode and the 715 Hz tool mode both have a lobe 0
    near 21.7 krpm. Where the lowest lobe changes from one to the other the envelope marks the
    crossing, a local maximum of the exact limit; no change of lobe goes unmarked."""
    model = read_modal_model(EXAMPLE / "models" / "planning_model.yaml")
    setup = read_setup(EXAMPLE / "setup.yaml")
    args = (model, setup.tool, setup.cut, setup.material.cutting_coefficients)
    env = zoa.envelope(*args, np.linspace(500.0, 24000.0, 2000))
    grid = np.flatnonzero(~env.is_intersection)
    f = env.chatter_frequency_hz
    # along one lobe the chatter frequency changes by < 1 % between these grid speeds
    change = grid[:-1][np.abs(np.log(f[grid[1:]] / f[grid[:-1]])) > np.log(1.05)]
    nxt = grid[np.searchsorted(grid, change) + 1]
    marked = np.array([env.is_intersection[a:b].any() for a, b in zip(change, nxt)])
    assert change.size >= 5 and marked.all()
    robot_tool = [(a, b) for a, b in zip(change, nxt) if env.rpm[a] > 21_000 and min(f[a], f[b]) < 30 < max(f[a], f[b])]
    assert len(robot_tool) == 1
    a, b = robot_tool[0]
    assert env.lobe[a] == env.lobe[b] == 0
    c = a + np.flatnonzero(env.is_intersection[a:b])[0]
    rpm_c, depth_c = env.rpm[c], env.depth_limit_m[c]
    assert 21_700 < rpm_c < 21_730
    left, at, right = reference_limit(*args, rpm_c * np.array([1 - 1e-6, 1.0, 1 + 1e-6]))
    assert at == pytest.approx(depth_c, rel=REFERENCE_RTOL)
    assert left < depth_c and right < depth_c
