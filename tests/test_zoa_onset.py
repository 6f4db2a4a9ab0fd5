"""The ZOA where a lobe starts: lightly damped modes (stability/zoa.py, stability/zoa_batch.py).

A lobe starts where its eigenvalue branch's real part crosses 0 (critical depth -> infinity). The
grid interval holding that crossing has one infinite end; it used to be no lobe candidate, and on
the default grid a lightly damped mode's whole lobe flank can lie in it: the envelope, predict,
plan and check then took the next lobe up (the example's tool at 0.5 % damping: 0.119 m at
21 990 rpm where the limit is 14.9 mm).

Ground truth: the 1-DOF characteristic equation in closed form (lobe points ``(60 f / (N (eps / 2
pi + k)), 1 / (2 B_nn Re G))`` and the limit at a speed by brentq on ``Im[(1 - e^{-iwT}) G] = 0``,
as in test_zoa.py, here for any damping); for the example's several-mode structure, the
characteristic equation solved at a fixed speed without any eigenvalue ordering on 200 000 lines
(test_zoa.reference_limit) and the same ZOA on 200 000 lines.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from oma.modal import ModalModel
from oma.modal_io import read_modal_model
from stability import zoa, zoa_batch
from stability.lobes import predict_point
from stability.oriented import average_directional_matrix
from stability.setup_io import read_setup

sys.path.insert(0, str(Path(__file__).parent))
import test_zoa  # noqa: E402
from test_zoa import (  # noqa: E402
    B_NN, COEF, EXAMPLE, FN, REFERENCE_RTOL, STIFF, TEETH, TOOL, reference_limit, slot_cut)

# The closed form and the envelope solve the same equation to ~1e-13 by different routes (brentq on
# the characteristic equation, Illinois on the eigenvalue phase), as in test_zoa.py.
CLOSED_FORM_RTOL = 1e-9
# Limits of the compiled batch kernel (robomill check) against the envelope: the same solve on the
# same grid, measured 1e-10 (tests/test_check.py holds it to 1e-9 against predict_point).
BATCH_RTOL = 1e-9


def one_dof(zeta):
    return ModalModel([FN], [zeta], [STIFF], [(0, 1, 0)])


def closed_form_limit(rpm, zeta):
    """test_zoa's closed form at this damping, with lines near the resonance (the lobes turn there)."""
    return test_zoa.closed_form_limit(rpm, zeta, resonance_lines=True)


def onset_flank(zeta, k_max=12, rpm_range=(2000.0, 60000.0)):
    """Closed-form points of lobes 0..k_max on the flank from the onset (f = fn, depth infinite) to
    the lobe's bottom: speeds (rpm) and depths (m)."""
    x = zeta * np.geomspace(0.01, 1.0, 25)  # f / fn - 1 up to the bottom (r^2 = 1 + 2 zeta)
    f = FN * (1 + x)
    r = f / FN
    lam = B_NN / (STIFF * (1 - r**2 + 2j * zeta * r))  # the one eigenvalue of G_or B0
    depth = 0.5 / lam.real
    eps_turns = (np.pi + 2 * np.arctan2(lam.imag, lam.real)) / (2 * np.pi)
    rpm = 60 * f[:, None] / (TEETH * (eps_turns[:, None] + np.arange(k_max + 1)))
    depth = np.broadcast_to(depth[:, None], rpm.shape)
    inside = (rpm >= rpm_range[0]) & (rpm <= rpm_range[1])
    return rpm[inside], depth[inside]


@pytest.mark.parametrize("zeta", [1e-3, 1e-4])
def test_one_dof_lobe_flank_from_its_onset_bounds_the_envelope(zeta):
    """Every closed-form point of a lobe's flank from its onset is a critical point, so the limit at
    its speed is at most its depth. 0.1 % damping: the default log grid (no lines added) has the
    flank down to 5 times the lobe's minimum in its onset interval; the envelope gave the next lobe
    up (142 of these 325 points above it, by up to 69 x). 0.01 %: the whole resonance (0.18 Hz)
    lies within two log lines (0.2 Hz apart; all 325 above it, up to 7500 x), and lines are added
    around it."""
    model = one_dof(zeta)
    grid = zoa.default_chatter_frequencies(model)
    a_min = 2 * STIFF * zeta * (1 + zeta) / (-B_NN)  # min Re G = -1 / (4 k zeta (1 + zeta))
    if zeta == 1e-3:
        # premise: no line added, the onset interval is the log grid's, and a lobe's flank in it
        # reaches down to a few times the lobe's minimum
        assert grid.size == 10_000
        above = grid[np.searchsorted(grid, FN)]
        x = above / FN - 1
        assert (x**2 + zeta**2) / (2 * x * zeta) < 10
    else:
        # lines around the mode, 4 per zeta fn at the peak (fn (1 + zeta sinh(j / 4)), |j| <= 3 within zeta fn)
        near = grid[np.abs(grid / FN - 1) < zeta]
        assert near.size >= 7 and np.max(np.diff(near)) <= 0.31 * zeta * FN
    rpm, depth = onset_flank(zeta)
    speeds, inv = np.unique(rpm, return_inverse=True)
    env = zoa.envelope(model, TOOL, slot_cut(), COEF, speeds)
    limit = env.depth_limit_m[~env.is_intersection]
    assert np.all(limit[inv] <= depth * (1 + CLOSED_FORM_RTOL))
    assert np.all(limit >= a_min * (1 - CLOSED_FORM_RTOL))
    # the limit itself at a few of these speeds (the closed form's search over all lobes)
    check = np.linspace(0, speeds.size - 1, 6).astype(int)
    ref = np.array([closed_form_limit(r, zeta) for r in speeds[check]])
    assert np.allclose(limit[check], ref, rtol=CLOSED_FORM_RTOL)


@pytest.mark.parametrize("zeta", [1e-3, 1e-4])
def test_one_dof_lobe_bottoms_are_the_closed_form_minimum(zeta):
    """At the speed of each lobe's bottom (r^2 = 1 + 2 zeta) the limit is the smallest of all,
    ``a_min = 2 k zeta (1 + zeta) / (-B_nn)``."""
    f = FN * np.sqrt(1 + 2 * zeta)
    lam = B_NN / (STIFF * (1 - (f / FN) ** 2 + 2j * zeta * f / FN))
    eps_turns = (np.pi + 2 * np.arctan2(lam.imag, lam.real)) / (2 * np.pi)
    rpm = np.sort(60 * f / (TEETH * (eps_turns + np.arange(1, 12))))
    env = zoa.envelope(one_dof(zeta), TOOL, slot_cut(), COEF, rpm)
    a_min = 2 * STIFF * zeta * (1 + zeta) / (-B_NN)
    assert np.allclose(env.depth_limit_m[~env.is_intersection], a_min, rtol=CLOSED_FORM_RTOL)


# ------------------------------------------------------------------ the example's tool at 0.5 %
# Speeds where the default grid lost the 720 Hz tool lobe (measured on 2000 speeds 500-24 000 rpm:
# 40 of them, up to 7.9 x): 7 224-7 236, 10 822-10 892 and 21 637-22 001 rpm.
WINDOWS = np.concatenate([np.linspace(7220.0, 7240.0, 5), np.linspace(10815.0, 10895.0, 9),
                          np.linspace(21630.0, 22010.0, 20)])


@pytest.fixture(scope="module")
def light_tool():
    """The example's planning model with its 720/735 Hz tool modes at 0.5 % damping, and its setup."""
    model = read_modal_model(EXAMPLE / "models" / "planning_model.yaml")
    zeta = np.where(np.isin(model.natural_frequency_hz, [720.0, 735.0]), 0.005, model.damping_ratio)
    model = ModalModel(model.natural_frequency_hz, zeta, model.stiffness_N_m, model.directions,
                       model.residual_compliance_m_N)
    setup = read_setup(EXAMPLE / "setup.yaml")
    return model, setup.tool, setup.cut, setup.material.cutting_coefficients


def test_predict_finds_the_tool_lobe_at_its_onset(light_tool):
    """At 21 990 rpm predict said 0.119 m (the robot's 24.7 Hz lobe) and called a 20 mm cut stable;
    the tool's lobe 0 at 719.7 Hz, inside the onset interval of the default grid, gives 14.9 mm."""
    op = predict_point(*light_tool, spindle_rpm=21990.0, axial_depth_m=0.02)
    assert not op.stable
    assert op.depth_limit_m == pytest.approx(reference_limit(*light_tool, [21990.0], n_freq=200_000)[0],
                                             rel=REFERENCE_RTOL)
    assert abs(op.chatter_frequency_hz - 719.7) < 1.0


def test_envelope_equals_the_reference_where_the_tool_lobe_starts(light_tool):
    env = zoa.envelope(*light_tool, WINDOWS)
    ref = reference_limit(*light_tool, WINDOWS, n_freq=200_000)
    assert np.allclose(env.depth_limit_m[~env.is_intersection], ref, rtol=REFERENCE_RTOL)


def test_envelope_equals_the_zoa_on_200_000_lines(light_tool):
    """The default grid (10 000 lines) against 200 000 lines over the setup's speed range."""
    rpm = np.linspace(500.0, 24000.0, 2000)
    model = light_tool[0]
    fn = model.natural_frequency_hz
    a = zoa.envelope(*light_tool, rpm)
    b = zoa.envelope(*light_tool, rpm, freq_hz=np.geomspace(fn.min() / 3, fn.max() * 3, 200_000))
    assert np.allclose(a.depth_limit_m[~a.is_intersection], b.depth_limit_m[~b.is_intersection],
                       rtol=REFERENCE_RTOL)


def batch_scan(model, tool, cut, coef, rpm, *, thr=None, lo=0.0, hi=0.0):
    """``zoa_batch``'s compiled scan (robomill check) for one structure group: limit, chatter
    frequency and, where ``thr`` is given and the limit is below it, the nearest speed in
    ``[lo, hi]`` whose limit is at least ``thr``. ``G_or B0 = sum_r W_r / (k_r (1 - rho^2 + 2 i
    zeta_r rho))`` with ``W_r = v_r[:2] (B0^T v_r)^T``, ``v_r`` the mode direction in the cut frame."""
    b0 = average_directional_matrix(tool, cut, coef)
    v = model.directions @ cut.frame.T
    w = np.einsum("mi,jl,mj->mil", v[:, :2], b0, v)
    wres = (cut.frame @ model.residual_compliance_m_N @ cut.frame.T)[:2] @ b0
    fn = np.asarray(model.natural_frequency_hz)[None]
    rpm = np.ascontiguousarray(rpm, dtype=float)
    n = rpm.size
    out = [np.empty(n) for _ in range(3)]
    zoa_batch.scan_kernel()(
        fn.copy(), np.asarray(model.damping_ratio)[None].copy(), np.asarray(model.stiffness_N_m)[None].copy(),
        w[None].copy(), wres[None].copy(), fn.min(axis=1) / 3, fn.max(axis=1) * 3, float(tool.teeth), 10_000,
        np.array([0, n], dtype=np.int64), rpm, np.full(n, 0.0 if thr is None else thr), np.full(n, lo), np.full(n, hi),
        np.full(n, thr is not None), *out)
    return out


def test_check_kernel_equals_the_envelope_where_the_tool_lobe_starts(light_tool):
    depth, freq, _ = batch_scan(*light_tool, WINDOWS)
    env = zoa.envelope(*light_tool, WINDOWS)
    assert np.allclose(depth, env.depth_limit_m[~env.is_intersection], rtol=BATCH_RTOL)
    assert np.allclose(freq, env.chatter_frequency_hz[~env.is_intersection], rtol=BATCH_RTOL)


def test_check_kernel_nearest_stable_speed_leaves_the_tool_lobe(light_tool):
    """A 20 mm cut at 21 990 rpm chatters on the tool's lobe 0 (check called it stable): the
    nearest stable speed is stable, and no speed of a dense grid (exact limits) closer to it is
    (up to 1e-6 of the distance: the kernel steps out of the unstable set by 1e-9 of the speed
    first, and the limit rises by 7e-6 per 1e-7 of the speed there)."""
    rpm0, thr, lo, hi = 21990.0, 0.02, 20000.0, 24000.0
    depth, _, near = batch_scan(*light_tool, [rpm0], thr=thr, lo=lo, hi=hi)
    assert depth[0] < thr
    best = near[0]
    assert lo <= best <= hi
    assert zoa.envelope(*light_tool, [best]).depth_limit_m[0] >= thr
    for side in (+1, -1):
        grid = rpm0 + side * np.linspace(0.0, abs(best - rpm0) * (1 - 1e-6), 1500)
        grid = np.sort(grid[(grid >= lo) & (grid <= hi)])
        assert np.all(zoa.envelope(*light_tool, grid).depth_limit_m < thr)


def test_grid_lines_of_the_check_kernel_are_predicts():
    """``zoa_batch._k_grid`` (check) and ``zoa.default_chatter_frequencies`` (predict) give the same
    grid, lines around a lightly damped mode included (rounding of the log lines aside)."""
    model = ModalModel([24.8, 720.0, 735.0], [0.04, 1e-4, 0.02], [3e6, 4e6, 4.4e6], np.eye(3))
    fn = model.natural_frequency_hz
    for n_freq in (2000, 10_000):
        grid = zoa.default_chatter_frequencies(model, n_freq=n_freq)
        out = np.empty(n_freq + 3 * (2 * zoa.MODE_LINES + 1))
        n = zoa_batch._PY_KERNELS["_k_grid"](fn.min() / 3, fn.max() * 3, n_freq, fn, model.damping_ratio,
                                            model.stiffness_N_m, out)
        assert n == grid.size > n_freq
        assert np.allclose(out[:n], grid, rtol=1e-14, atol=0)
