"""Toolpath check (planner/check.py, planner/check_plots.py).

Ground truth:
- a straight path with one model: every per-point result equals stability.lobes.predict_point
  at that point (an independent implementation of the same ZOA solve and forced response);
- the 1-DOF ZOA limit in closed form: at the speed of a lobe's bottom the limit is
  ``1 / (2 B_nn min Re G)`` with ``min Re G = -1 / (4 k zeta (1 + zeta))`` (B_nn = -N Kr / 4, slot);
- closed-form straight-flute slot forces: one tooth cuts at a time, the resultant peaks at
  ``phi = 90 deg``, ``a sqrt((Ktc fz + Kte)^2 + (Krc fz + Kre)^2)``; mean power
  ``Omega R a N / (2 pi) [Ktc fz (cos phi_st - cos phi_ex) + Kte (phi_ex - phi_st)]``;
- force harmonics against a brute-force FFT of the pointwise helix force;
- the example cell (examples/kr500_acetal): which points lie beyond the identified poses follows
  from how its path was built (path parameter s outside [0, 1]).
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import planner.check_forces as check_forces  # noqa: E402
from oma.cutting import Cut, CuttingCoefficients, Material, Tool, engagement_angles  # noqa: E402
from oma.errors import ModelError  # noqa: E402
from oma.modal import ModalModel  # noqa: E402
from oma.modal_io import read_modal_model  # noqa: E402
from planner.check import VIOLATION_KINDS, ToolpathCheck, check_toolpath  # noqa: E402
from planner.check_plots import VIOLATION_STYLE  # noqa: E402
from planner.poses import PoseModels  # noqa: E402
from planner.toolpath import Toolpath  # noqa: E402
from planner.toolpath_io import read_toolpath  # noqa: E402
from stability import zoa_batch  # noqa: E402
from stability import zoa  # noqa: E402
from stability.forced import default_harmonics  # noqa: E402
from stability.lobes import predict_point  # noqa: E402
from stability.oriented import engaged_axial_integral, force_coefficients  # noqa: E402
from stability.setup import Limits  # noqa: E402
from stability.setup_io import read_setup  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "kr500_acetal"

# ------------------------------------------------------------------------------------ tolerances
#: The check and predict_point solve the same ZOA phase condition to 4e-15 in frequency; the
#: receptance products are summed in a different order, so limits agree to rounding (~1e-14).
LIMIT_RTOL = 1e-9
#: predict_point takes force harmonics from cell means with an alias correction, stated to 1e-4
#: of each harmonic (measured here ~1e-7); the check integrates them exactly. The static
#: deflection (exact in both) dominates the surface location error: measured differences 6e-7.
SLE_RTOL = 1e-5
#: Peak force uses the same angle set as stability.forced; power is a closed-form mean in both.
FORCE_RTOL = 1e-12
#: Closed forms against the check (rounding only).
CLOSED_FORM_RTOL = 1e-9
#: The exact force harmonics against an FFT of 2^16 pointwise samples of the (continuous, kinked)
#: helix force: the FFT's aliasing falls as 1/M^2, ~1e-9 of the largest harmonic here.
HARMONIC_RTOL = 1e-7
#: The peak force (4096 angles plus both sides of the entry/exit angles) against 2^16 uniform
#: angles: where the peak sits at a kink the uniform grid misses it by up to slope x spacing, about
#: pi / 2^16 = 5e-5 relative.
PEAK_GRID_RTOL = 1e-4
#: Feed directions rounded to 0.01 deg (the default) move the frame by <= 1.5e-4 rad; the measured
#: change of the limit and SLE of an oblique cut on the example's anisotropic model is ~1e-5.
FRAME_ROUNDING_RTOL = 1e-3

# ------------------------------------------------------------------------------------ 1-DOF cell
FN, ZETA, MASS = 922.0, 0.011, 0.03993  # Insperger-Stepan / Ding benchmark structure
STIFF = MASS * (2 * np.pi * FN) ** 2
TEETH, KT, KR = 2, 6e8, 2e8
STRAIGHT = Tool(TEETH, 0.01)
SLOT_COEF = CuttingCoefficients(KT, KR)
B_NN = -TEETH * KR / 4  # slotting, mode along n
A_MIN = 1.0 / (2.0 * B_NN * (-1.0 / (4.0 * STIFF * ZETA * (1.0 + ZETA))))  # lobe-bottom depth, m


def one_dof() -> ModalModel:
    return ModalModel([FN], [ZETA], [STIFF], [[0, 1, 0]])  # along n = a x f for f = +X, a = +Z


def lobe_bottom_rpm(k: int) -> float:
    """Speed at which lobe ``k`` has its bottom: chatter at ``f* = fn sqrt(1 + 2 zeta)``."""
    r = np.sqrt(1.0 + 2.0 * ZETA)
    g = 1.0 / (STIFF * (1.0 - r**2 + 2j * ZETA * r))
    lam = B_NN * g
    eps = np.pi + 2.0 * np.arctan2(lam.imag, lam.real)
    return 60.0 * FN * r / (TEETH * (eps / (2 * np.pi) + k))


def line_path(n, *, tool=STRAIGHT, coef=SLOT_COEF, rpm=10000.0, depth=1e-4, ae=None, fz=1e-4, milling="down",
              direction=(1.0, 0.0, 0.0), joints=None, limits=Limits()) -> Toolpath:
    """A straight path of ``n`` points 1 mm apart along ``direction``, tool axis +Z."""
    step = 1e-3 * np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    full = lambda v: np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()  # noqa: E731
    return Toolpath(
        tool=tool, material=Material("test", coef), tool_axis=[0.0, 0.0, 1.0],
        positions_m=np.arange(n)[:, None] * step[None, :],
        joints_deg=np.zeros((n, 6)) if joints is None else joints,
        spindle_rpm=full(rpm), feed_per_tooth_m=full(fz),
        radial_depth_m=full(tool.diameter_m if ae is None else ae), axial_depth_m=full(depth),
        milling=np.broadcast_to(np.asarray(milling), (n,)).copy(), limits=limits,
    )


def check_one(toolpath, model, **kwargs) -> ToolpathCheck:
    with pytest.warns(UserWarning, match="pose is not checked"):
        return check_toolpath(toolpath, [model], **kwargs)


def cut_at(toolpath, i) -> Cut:
    a = np.asarray(toolpath.tool_axis, dtype=float)
    return Cut(toolpath.feed_per_tooth_m[i], toolpath.radial_depth_m[i], str(toolpath.milling[i]),
               toolpath.feed_directions()[i], np.cross(a, toolpath.feed_directions()[i]))


@pytest.fixture(scope="module")
def example():
    toolpath = read_toolpath(EXAMPLE / "toolpath.yaml")
    models = [read_modal_model(p) for p in sorted((EXAMPLE / "poses").glob("pose_*.yaml"))]
    return toolpath, models, check_toolpath(toolpath, models)


# ------------------------------------------------------------------------------- against predict_point
def test_straight_path_with_one_model_equals_predict_point_at_every_point():
    """Speeds, depths, engagements and both milling modes varied along a line; the example's
    planning model (robot + spindle modes, helix tool, edge forces)."""
    model = read_modal_model(EXAMPLE / "models" / "planning_model.yaml")
    tool = Tool(2, 0.0254, np.deg2rad(30.0))
    coef = CuttingCoefficients(1.2e8, 4.5e7, 2.0e7, 2.0e3, 3.0e3, 5.0e2)
    n = 8
    path = line_path(n, tool=tool, coef=coef, direction=(0.0, 1.0, 0.0), limits=Limits(stability_margin=0.8))
    path = replace(path, spindle_rpm=np.array([2700.0, 2700.0, 5200.0, 5200.0, 9000.0, 12000.0, 700.0, 2700.0]),
                   axial_depth_m=np.array([0.006, 0.015, 0.004, 0.004, 0.002, 0.010, 0.020, 0.006]),
                   radial_depth_m=np.array([0.006, 0.006, 0.012, 0.012, 0.0254, 0.003, 0.006, 0.020]),
                   milling=np.array(["down", "down", "up", "down", "down", "up", "down", "up"]),
                   feed_per_tooth_m=np.array([5e-4, 5e-4, 2e-4, 2e-4, 1e-4, 3e-4, 5e-4, 4e-4]))
    result = check_one(path, model)
    assert result.n_points == n and np.all(result.in_span)
    for i in range(n):
        op = predict_point(model, tool, cut_at(path, i), coef, spindle_rpm=path.spindle_rpm[i],
                           axial_depth_m=path.axial_depth_m[i])
        assert result.depth_limit_m[i] == pytest.approx(op.depth_limit_m, rel=LIMIT_RTOL)
        assert result.chatter_frequency_hz[i] == pytest.approx(op.chatter_frequency_hz, rel=LIMIT_RTOL)
        assert result.stability_margin[i] == pytest.approx(op.depth_limit_m / path.axial_depth_m[i], rel=LIMIT_RTOL)
        assert result.surface_location_error_m[i] == pytest.approx(op.surface_location_error_m, rel=SLE_RTOL)
        assert result.peak_force_N[i] == pytest.approx(op.peak_force_N, rel=FORCE_RTOL)
        assert result.power_W[i] == pytest.approx(op.power_W, rel=FORCE_RTOL)
    # the planned depth of point 1 (15 mm) is above the 12 mm limit: chatter, and only there and at 6
    assert list(np.flatnonzero(result.flagged("chatter"))) == [i for i in range(n) if
                                                                result.depth_limit_m[i] * 0.8 < path.axial_depth_m[i]]


def test_harmonic_count_follows_stability_forced():
    model = read_modal_model(EXAMPLE / "models" / "planning_model.yaml")
    tool = Tool(2, 0.0254, np.deg2rad(30.0))
    for rpm in (300.0, 2700.0, 24000.0):
        f_tp = tool.teeth * rpm / 60.0
        mine = int(min(2000, max(32, np.ceil(4.0 * model.natural_frequency_hz.max() / f_tp))))
        assert mine == default_harmonics(model, tool, rpm)


@pytest.mark.parametrize("milling, ae, depth", [("down", 0.006, 0.006), ("up", 0.010, 0.015), ("down", 0.0254, 0.003)])
def test_force_harmonics_equal_a_brute_force_fft(milling, ae, depth):
    tool = Tool(2, 0.0254, np.deg2rad(30.0))
    coef = CuttingCoefficients(1.2e8, 4.5e7, 2.0e7, 2.0e3, 3.0e3, 5.0e2)
    cut = Cut(5e-4, ae, milling, [0, 1, 0], [-1, 0, 0])
    unit, mean_torque, peak = check_forces.force_shapes(tool, coef, cut, [depth], 33)
    exact = unit * check_forces._helix_filter(tool, [depth], 33)[0]
    m = 2**16
    phi = np.pi * np.arange(m) / m  # one tooth pitch
    force = engaged_axial_integral(tool, cut, phi, depth) @ force_coefficients(coef, cut.feed_per_tooth_m).T
    brute = (np.fft.fft(force, axis=0)[:34] / m).T
    assert np.max(np.abs(exact - brute)) <= HARMONIC_RTOL * np.max(np.abs(exact))
    st, ex = engagement_angles(tool, cut)  # mean torque: R a N / (2 pi) [Ktc fz (cos st - cos ex) + Kte (ex - st)]
    closed = tool.diameter_m / 2 * depth * 2 / (2 * np.pi) * (coef.Ktc_N_m2 * 5e-4 * (np.cos(st) - np.cos(ex))
                                                               + coef.Kte_N_m * (ex - st))
    assert mean_torque[0] == pytest.approx(closed, rel=CLOSED_FORM_RTOL)
    sampled = np.max(np.hypot(force[:, 0], force[:, 1]))  # the check adds the entry/exit angles
    assert sampled <= peak[0] <= sampled * (1 + PEAK_GRID_RTOL)


def test_frame_rounding_changes_an_oblique_cut_by_little():
    """A path at 37 deg to X on an anisotropic model: exact with direction_resolution_deg = 0, and
    within the rounding's effect with the default 0.01 deg."""
    model = read_modal_model(EXAMPLE / "models" / "planning_model.yaml")
    tool = Tool(2, 0.0254, np.deg2rad(30.0))
    coef = CuttingCoefficients(1.2e8, 4.5e7, 2.0e7, 2.0e3, 3.0e3, 5.0e2)
    ang = np.deg2rad(37.0)
    path = line_path(3, tool=tool, coef=coef, rpm=5200.0, depth=0.004, ae=0.006, fz=5e-4,
                     direction=(np.cos(ang), np.sin(ang), 0.0))
    exact = check_one(path, model, direction_resolution_deg=0)
    rounded = check_one(path, model)
    op = predict_point(model, tool, cut_at(path, 0), coef, spindle_rpm=5200.0, axial_depth_m=0.004)
    assert exact.depth_limit_m[0] == pytest.approx(op.depth_limit_m, rel=LIMIT_RTOL)
    assert exact.surface_location_error_m[0] == pytest.approx(op.surface_location_error_m, rel=SLE_RTOL)
    assert rounded.depth_limit_m[0] == pytest.approx(op.depth_limit_m, rel=FRAME_ROUNDING_RTOL)
    assert rounded.surface_location_error_m[0] == pytest.approx(op.surface_location_error_m, rel=FRAME_ROUNDING_RTOL)
    assert rounded.evaluations["frames"] == 1


# ------------------------------------------------------------------------------- closed forms
def test_depth_crossing_the_one_dof_limit_flags_exactly_the_points_above_the_margin():
    k = 2
    rpm = lobe_bottom_rpm(k)
    fraction = 0.8
    depth = fraction * A_MIN * np.linspace(0.5, 1.5, 20)  # no point on the threshold itself
    path = replace(line_path(20, rpm=rpm), axial_depth_m=depth)
    result = check_one(path, one_dof(), limits=Limits(stability_margin=fraction, spindle_rpm=(5000.0, 25000.0)))
    assert np.allclose(result.depth_limit_m, A_MIN, rtol=LIMIT_RTOL)
    expected = depth > fraction * A_MIN
    assert np.array_equal(result.flagged("chatter"), expected)
    assert np.allclose(result.stability_margin, A_MIN / depth, rtol=LIMIT_RTOL)
    chatter = [v for v in result.violations if v["kind"] == "chatter"]
    assert [v["index"] for v in chatter] == list(np.flatnonzero(expected))
    for v in chatter:
        assert v["value"] == depth[v["index"]]
        assert v["limit"] == pytest.approx(fraction * A_MIN, rel=LIMIT_RTOL)
    assert np.all(np.isnan(result.nearest_stable_rpm[~expected]))


def test_force_torque_and_power_limits_flag_exactly_where_the_closed_forms_exceed_them():
    """Peak force, MEAN torque (formats.md: the spindle's continuous rating) and mean power against
    their closed forms for a straight-fluted slot; the torque limit sits between depths where the
    mean torque is below it and the peak torque far above it, so only the mean is flagged."""
    coef = CuttingCoefficients(KT, KR, 0.0, 2.0e4, 1.0e4)  # edge forces too
    rpm, fz = 10000.0, 1e-4
    depth = np.linspace(0.2e-3, 2.0e-3, 19)
    path = replace(line_path(19, coef=coef, rpm=rpm, fz=fz), axial_depth_m=depth)
    peak = depth * np.hypot(KT * fz + coef.Kte_N_m, KR * fz + coef.Kre_N_m)  # one tooth, phi = 90 deg
    st, ex = 0.0, np.pi  # slot
    torque = STRAIGHT.diameter_m / 2 * depth * TEETH / (2 * np.pi) * (
        KT * fz * (np.cos(st) - np.cos(ex)) + coef.Kte_N_m * (ex - st))
    power = 2 * np.pi * rpm / 60 * torque
    limits = Limits(max_force_N=float(np.mean(peak[8:10])), spindle_power_W=float(np.mean(power[12:14])),
                    spindle_torque_N_m=float(np.mean(torque[15:17])))
    stiff = ModalModel([FN], [ZETA], [1e6 * STIFF], [[0, 1, 0]])  # no chatter flags in the way
    result = check_one(path, stiff, limits=limits)
    assert np.allclose(result.peak_force_N, peak, rtol=CLOSED_FORM_RTOL)
    assert np.allclose(result.power_W, power, rtol=CLOSED_FORM_RTOL)
    assert np.allclose(result.mean_torque_N_m, torque, rtol=CLOSED_FORM_RTOL)
    assert np.array_equal(result.flagged("force"), peak > limits.max_force_N)
    assert np.array_equal(result.flagged("power"), power > limits.spindle_power_W)
    assert np.array_equal(result.flagged("torque"), torque > limits.spindle_torque_N_m)
    assert result.counts() == {"chatter": 0, "surface_error": 0, "force": 10, "power": 6, "torque": 3,
                               "pose_out_of_range": 0}
    expected_of = {"force": (peak, limits.max_force_N), "power": (power, limits.spindle_power_W),
                   "torque": (torque, limits.spindle_torque_N_m)}
    for v in result.violations:
        values, limit = expected_of[v["kind"]]
        assert v["value"] == pytest.approx(values[v["index"]], rel=CLOSED_FORM_RTOL)
        assert v["limit"] == limit


def test_surface_error_limit_flags_exactly_where_predict_point_exceeds_it():
    depth = np.linspace(0.05e-3, 0.5e-3, 10)
    path = replace(line_path(10, rpm=12000.0, ae=0.003), axial_depth_m=depth)
    sle = np.array([predict_point(one_dof(), STRAIGHT, cut_at(path, i), SLOT_COEF, spindle_rpm=12000.0,
                                  axial_depth_m=d).surface_location_error_m for i, d in enumerate(depth)])
    allowed = float(np.mean(np.sort(np.abs(sle))[4:6]))
    result = check_one(path, one_dof(), limits=Limits(surface_location_error_m=allowed))
    assert np.allclose(result.surface_location_error_m, sle, rtol=SLE_RTOL)
    assert np.array_equal(result.flagged("surface_error"), np.abs(sle) > allowed)
    assert result.counts()["surface_error"] == 5


def dense_wall(op, tool, cut, n: int = 4001):
    """|SLE| at ``n`` heights from the tip to the top of the wall, by the library: the steady
    displacement of predict_point's forced response along the wall's normal when the tooth
    finishes each height (the tip's instant plus ``kappa z / Omega``, the definition of cli.md's
    profile, which samples it at 21 heights)."""
    from stability.oriented import helix_lag_per_m

    fr = op.forced
    z = np.linspace(0.0, fr.axial_depth_m, n)
    t = fr.finishing_time_s + helix_lag_per_m(tool) * z / (2 * np.pi * fr.spindle_rpm / 60)
    return z, np.abs(cut.normal_direction @ fr.displacement_at(t))


#: A dense sampling (4001 heights) of a wall over which the largest harmonic turns < 3 times is
#: within ~(2 pi 3 / 4000)^2 / 8 = 3e-6 below its maximum; predict_point's harmonics differ from the
#: check's exact ones by ~1e-7 (SLE_RTOL above).
WALL_RTOL = 1e-5


def test_surface_error_is_bounded_on_the_whole_wall_not_the_tip():
    """formats.md bounds |SLE| on the finished wall. With a helix the wall at height z is finished
    kappa z / Omega after the tip, and near the example's 720 Hz tool modes (22 500 rpm, 2 teeth)
    it is far larger at the top than at the tip: points whose tip is within the limit but whose
    wall is not are violations, valued at the wall's largest |SLE| (ground truth: predict_point's
    profile, and its forced response sampled densely), with the height where it is."""
    setup = read_setup(EXAMPLE / "setup.yaml")
    model = read_modal_model(EXAMPLE / "models" / "planning_model.yaml")
    coef = setup.material.cutting_coefficients
    rpm = np.array([22500.0, 22500.0, 21717.0, 15000.0, 9000.0, 2700.0])
    depth = np.array([12e-3, 6e-3, 24e-3, 10e-3, 5e-3, 6e-3])
    path = replace(line_path(6, tool=setup.tool, coef=coef, fz=6e-4, ae=setup.cut.radial_depth_m),
                   spindle_rpm=rpm, axial_depth_m=depth)
    limit = 3e-4
    result = check_one(path, model, limits=Limits(surface_location_error_m=limit))
    tip, profile, wall, height = (np.zeros(6) for _ in range(4))
    for i in range(6):
        cut = cut_at(path, i)
        op = predict_point(model, setup.tool, cut, coef, spindle_rpm=rpm[i], axial_depth_m=depth[i])
        tip[i], profile[i] = op.surface_location_error_m, np.max(np.abs(op.surface_location_error_profile_m))
        z, v = dense_wall(op, setup.tool, cut)
        wall[i], height[i] = v.max(), z[np.argmax(v)]
    # the premise: at points 0 and 1 the tip is within the limit, the wall (already its 21 samples) is not
    assert np.all(np.abs(tip[:2]) < 0.7 * limit) and np.all(profile[:2] > 1.2 * limit)
    assert np.array_equal(result.flagged("surface_error"), wall > limit)
    assert result.flagged("surface_error").tolist() == [True, True, True, False, False, False]
    assert np.allclose(result.surface_location_error_m, tip, rtol=SLE_RTOL)  # the per-point SLE: the tip's (cli.md)
    assert np.all(result.wall_surface_error_m >= profile * (1 - SLE_RTOL))
    assert np.allclose(result.wall_surface_error_m, wall, rtol=WALL_RTOL)
    assert np.allclose(result.surface_error_height_m, height, atol=depth.max() / 2000)
    for v in result.violations:
        i = v["index"]
        assert v["kind"] == "surface_error" and v["limit"] == limit
        assert v["value"] == pytest.approx(wall[i], rel=WALL_RTOL)
        assert v["height_m"] == pytest.approx(height[i], abs=depth[i] / 2000)
    assert result.surface_error_height_m[0] == pytest.approx(depth[0], rel=1e-9)  # here: the top of the wall


# ------------------------------------------------------------------------------- nearest stable speed
def test_nearest_stable_speed_is_stable_and_no_closer_stable_speed_exists():
    rpm0 = lobe_bottom_rpm(2) * 1.003  # just off the bottom of lobe 2
    fraction, lo, hi = 0.8, 5000.0, 25000.0
    depth = fraction * A_MIN * np.array([1.2, 1.6, 2.5, 4.0])
    path = replace(line_path(4, rpm=rpm0, ae=STRAIGHT.diameter_m), axial_depth_m=depth)
    result = check_one(path, one_dof(), limits=Limits(stability_margin=fraction, spindle_rpm=(lo, hi)))
    assert result.flagged("chatter").all()
    cut = cut_at(path, 0)
    for i, a in enumerate(depth):
        best = result.nearest_stable_rpm[i]
        assert lo <= best <= hi
        # stable there, re-checked by predict_point
        op = predict_point(one_dof(), STRAIGHT, cut, SLOT_COEF, spindle_rpm=best, axial_depth_m=a)
        assert fraction * op.depth_limit_m >= a
        # no closer stable speed on a fine grid on either side (exact limits at every grid speed)
        dist = abs(best - rpm0)
        for side in (+1, -1):
            grid = rpm0 + side * np.linspace(0.0, dist * (1 - 1e-7), 1500)
            grid = np.sort(grid[(grid >= lo) & (grid <= hi)])
            env = zoa.envelope(one_dof(), STRAIGHT, cut, SLOT_COEF, grid)
            assert np.all(fraction * env.depth_limit_m < a), (i, side)
    # the deeper the cut, the farther the nearest stable speed
    assert np.all(np.diff(np.abs(result.nearest_stable_rpm - rpm0)) >= 0)
    v = [v for v in result.violations if v["kind"] == "chatter"]
    assert [x["nearest_stable_rpm"] for x in v] == list(result.nearest_stable_rpm)


@pytest.mark.parametrize("seed, milling", [(7, "up"), (11, "down")])
def test_nearest_stable_speed_on_oblique_modes_beats_a_dense_speed_grid(seed, milling):
    """Three oblique modes (both eigenvalue branches act), partial immersion, helix and an axial
    force: at three depths above the limit the nearest stable speed is stable and no speed of an
    8000-speed grid (exact limits there) that is closer is stable."""
    rng = np.random.default_rng(seed)
    model = ModalModel(rng.uniform(400, 1600, 3), rng.uniform(0.01, 0.05, 3), rng.uniform(5e6, 3e7, 3),
                       rng.normal(size=(3, 3)))
    tool = Tool(3, 0.016, np.deg2rad(30.0))
    coef = CuttingCoefficients(7e8, 2.1e8, 1e8, 1e4, 1e4)
    ae, rpm0, lo, hi = rng.uniform(0.1, 1.0) * 0.016, rng.uniform(6000, 22000), 2000.0, 30000.0
    cut = Cut(1e-4, ae, milling, [1, 0, 0], [0, 1, 0])
    limit0 = zoa.envelope(model, tool, cut, coef, [rpm0]).depth_limit_m[0]
    depth = limit0 * np.array([1.05, 1.5, 3.0])
    path = replace(line_path(3, tool=tool, coef=coef, rpm=rpm0, ae=ae, milling=milling), axial_depth_m=depth)
    result = check_one(path, model, limits=Limits(spindle_rpm=(lo, hi)))
    env = zoa.envelope(model, tool, cut, coef, np.linspace(lo, hi, 8000))
    assert result.flagged("chatter").all()
    for a, best in zip(depth, result.nearest_stable_rpm):
        stable = env.depth_limit_m >= a
        if np.isnan(best):
            assert not stable.any()
            continue
        assert zoa.envelope(model, tool, cut, coef, [best]).depth_limit_m[0] >= a
        assert not np.any(stable & (np.abs(env.rpm - rpm0) < abs(best - rpm0) * (1 - 1e-9)))


def test_lowest_lobe_across_an_eigenvalue_order_swap_is_kept():
    """The compiled kernel repeats stability.zoa's lowest-lobe search, and had its bug: across an
    eigenvalue-order swap of the example's 720/735 Hz tool (3 flutes, ae/D = 0.1) it skipped lobe 1
    (6.0 mm) at 9934-9941 rpm, gave 49.9 mm there and offered 9934.95 rpm as a stable speed for a
    6.5 mm cut at 9930 rpm. Limits equal predict_point's; the nearest stable speed is stable and
    no stable speed of a dense grid (exact limits) is closer."""
    model = read_modal_model(EXAMPLE / "models" / "tool_mode.yaml")
    tool = Tool(3, 0.016, np.deg2rad(45.0))
    coef = CuttingCoefficients(7.96e8, 1.68e8, 2.22e8, 2.77e4, 3.08e4, 1.8e3)
    rpm, depth, lo, hi = np.array([9930.0, 9937.0, 9941.0]), 0.0065, 9000.0, 11000.0
    path = replace(line_path(3, tool=tool, coef=coef, ae=0.0016, depth=depth), spindle_rpm=rpm)
    result = check_one(path, model, limits=Limits(spindle_rpm=(lo, hi)))
    cut = cut_at(path, 0)
    for i, r in enumerate(rpm):
        op = predict_point(model, tool, cut, coef, spindle_rpm=r, axial_depth_m=depth)
        assert result.depth_limit_m[i] == pytest.approx(op.depth_limit_m, rel=LIMIT_RTOL)
        assert abs(result.chatter_frequency_hz[i] - 749.0) < 1.0  # lobe 1 of the tool mode
    assert result.flagged("chatter").all()
    for r, best in zip(rpm, result.nearest_stable_rpm):
        assert lo <= best <= hi
        assert predict_point(model, tool, cut, coef, spindle_rpm=best, axial_depth_m=depth).stable
        for side in (+1, -1):
            grid = r + side * np.linspace(0.0, abs(best - r) * (1 - 1e-7), 1500)
            grid = np.sort(grid[(grid >= lo) & (grid <= hi)])
            assert np.all(zoa.envelope(model, tool, cut, coef, grid).depth_limit_m < depth)


def test_progress_goes_to_standard_error(capsys):
    result = check_one(line_path(3, rpm=lobe_bottom_rpm(2)), one_dof(), progress=True)
    captured = capsys.readouterr()
    assert "check: stability" in captured.err and "1/1" in captured.err and captured.out == ""
    assert result.evaluations["structure_groups"] == 1


def test_nearest_stable_speed_respects_the_speed_range():
    rpm0 = lobe_bottom_rpm(2)
    path = replace(line_path(2, rpm=rpm0), axial_depth_m=np.full(2, 1.5 * A_MIN))
    narrow = check_one(path, one_dof(), limits=Limits(spindle_rpm=(rpm0 - 50.0, rpm0 + 50.0)))
    assert narrow.flagged("chatter").all() and np.all(np.isnan(narrow.nearest_stable_rpm))
    assert narrow.to_dict()["violations"][0]["nearest_stable_rpm"] is None
    # a range that starts above the lobe: its lower end is the answer when it is stable there
    start = rpm0 * 1.4
    shifted = check_one(path, one_dof(), limits=Limits(spindle_rpm=(start, 2 * rpm0)))
    op = predict_point(one_dof(), STRAIGHT, cut_at(path, 0), SLOT_COEF, spindle_rpm=start, axial_depth_m=1.5 * A_MIN)
    assert op.stable
    assert shifted.nearest_stable_rpm[0] == start


# ------------------------------------------------------------------------------- poses and caching
def test_example_points_beyond_the_identified_poses_are_flagged(example):
    toolpath, models, result = example
    s = (toolpath.positions_m[:, 0] + 0.15) / 0.3  # the path parameter of make_example.py (part frame x)
    beyond = (s < 0) | (s > 1)
    assert np.array_equal(result.flagged("pose_out_of_range"), beyond)
    assert np.array_equal(result.in_span, ~beyond)
    assert beyond[-int(0.07 * toolpath.n_points):].all()  # the last ~8 % of the path (18 of 240 points)
    for v in result.violations:
        if v["kind"] == "pose_out_of_range":
            assert v["beyond_range"] and v["value"] > v["limit"]
    # chatter where the path is cut 15 mm deep, nowhere else (its limit is ~12 mm at 2700 rpm)
    assert np.array_equal(result.flagged("chatter"), toolpath.axial_depth_m > 0.01)
    assert result.flagged("chatter").sum() > 0 and np.all(np.isfinite(result.nearest_stable_rpm[result.flagged("chatter")]))


def test_out_of_span_points_use_the_model_at_the_nearest_span_point(example):
    toolpath, models, result = example
    poses = PoseModels.fit(models)
    for i in (0, toolpath.n_points - 1):
        assert not result.in_span[i]
        joints = np.round(toolpath.joints_deg[i] / 0.01) * 0.01  # the check's pose rounding
        model = poses.at(joints, out_of_span="clamp")
        # the check works in the machine frame (the example's path is in the part frame)
        op = predict_point(model, toolpath.tool, cut_at(toolpath.in_machine_frame(), i),
                           toolpath.material.cutting_coefficients,
                           spindle_rpm=toolpath.spindle_rpm[i], axial_depth_m=toolpath.axial_depth_m[i])
        assert result.depth_limit_m[i] == pytest.approx(op.depth_limit_m, rel=LIMIT_RTOL)
        assert result.surface_location_error_m[i] == pytest.approx(op.surface_location_error_m, rel=SLE_RTOL)
    assert any("outside the span" in note for note in result.notes)


def test_repeated_poses_are_computed_once(example, monkeypatch):
    toolpath, models, _ = example
    poses = np.round(toolpath.joints_deg[[40, 120, 200]], 2)
    n = 60
    path = line_path(n, tool=toolpath.tool, coef=toolpath.material.cutting_coefficients, rpm=2700.0, depth=0.006,
                     ae=0.006, fz=5e-4, direction=(0.0, 1.0, 0.0), joints=poses[np.arange(n) % 3])
    path = replace(path, axial_depth_m=np.where(np.arange(n) % 2 == 0, 0.006, 0.015))
    computed = []
    kernel = zoa_batch.scan_kernel()

    def counting(fn, *args):
        computed.append(fn.shape[0])  # structure groups whose frequency grid is computed
        return kernel(fn, *args)

    monkeypatch.setattr(zoa_batch, "scan_kernel", lambda: counting)
    result = check_toolpath(path, models)
    assert sum(computed) == 3
    ev = result.evaluations
    assert (ev["models"], ev["structure_groups"], ev["force_shapes"], ev["forced_groups"]) == (3, 3, 2, 6)
    assert ev["limits"] == 6  # (3 poses) x (2 depths: the threshold of the chatter test differs)
    # every repetition has the result of its first occurrence, which is predict_point's
    for name in ("depth_limit_m", "surface_location_error_m", "peak_force_N", "power_W"):
        values = getattr(result, name)
        assert np.array_equal(values, values[np.arange(n) % 6])
    for i in range(3):
        op = predict_point(PoseModels.fit(models).at(poses[i]), path.tool, cut_at(path, i),
                           path.material.cutting_coefficients, spindle_rpm=2700.0, axial_depth_m=path.axial_depth_m[i])
        assert result.depth_limit_m[i] == pytest.approx(op.depth_limit_m, rel=LIMIT_RTOL)


def test_pose_rounding_merges_poses_closer_than_the_resolution(example):
    toolpath, models, _ = example
    base = np.round(toolpath.joints_deg[100], 2)
    joints = np.array([base, base + 0.001, base + 0.004, base + 0.02])
    path = line_path(4, tool=toolpath.tool, coef=toolpath.material.cutting_coefficients, rpm=2700.0, depth=0.006,
                     ae=0.006, fz=5e-4, direction=(0.0, 1.0, 0.0), joints=joints)
    assert check_toolpath(path, models).evaluations["models"] == 2
    exact = check_toolpath(path, models, pose_resolution_deg=0)
    assert exact.evaluations["models"] == 4
    op = predict_point(PoseModels.fit(models).at(joints[2]), path.tool, cut_at(path, 2),
                       path.material.cutting_coefficients, spindle_rpm=2700.0, axial_depth_m=0.006)
    assert exact.depth_limit_m[2] == pytest.approx(op.depth_limit_m, rel=LIMIT_RTOL)


# ------------------------------------------------------------------------------- SDM
def test_sdm_method_equals_predict_point_and_finds_a_stable_speed():
    rpm0 = lobe_bottom_rpm(2)
    path = replace(line_path(2, rpm=rpm0), axial_depth_m=np.array([0.5 * A_MIN, 1.3 * A_MIN]))
    lo, hi = 0.9 * rpm0, 1.2 * rpm0
    result = check_one(path, one_dof(), method="sdm", limits=Limits(spindle_rpm=(lo, hi)))
    op = predict_point(one_dof(), STRAIGHT, cut_at(path, 0), SLOT_COEF, spindle_rpm=rpm0, axial_depth_m=0.5 * A_MIN,
                       method="sdm")
    assert result.depth_limit_m[0] == pytest.approx(op.depth_limit_m, rel=LIMIT_RTOL)
    assert list(np.flatnonzero(result.flagged("chatter"))) == [1]
    best = result.nearest_stable_rpm[1]
    assert lo <= best <= hi
    at_best = predict_point(one_dof(), STRAIGHT, cut_at(path, 1), SLOT_COEF, spindle_rpm=best,
                            axial_depth_m=1.3 * A_MIN, method="sdm")
    assert at_best.depth_limit_m >= 1.3 * A_MIN


# ------------------------------------------------------------------------------- output and errors
def test_to_dict_is_json_with_the_cli_keys(example):
    _, _, result = example
    out = json.loads(json.dumps(result.to_dict(per_point=True)))
    assert out["points"] == result.n_points == 240
    assert len(out["violations"]) == len(result.violations)
    assert {v["kind"] for v in out["violations"]} <= set(VIOLATION_KINDS)
    assert all({"index", "kind", "value", "limit"} <= set(v) for v in out["violations"])
    assert out["counts"] == result.counts() and out["ok"] is False
    assert len(out["stability_margin"]) == 240 and out["in_span"][0] is False
    indices = [v["index"] for v in out["violations"]]
    assert indices == sorted(indices)
    assert "per_point" not in result.to_dict() and "stability_margin" not in result.to_dict()


def test_plot_colours_the_path_by_margin_and_marks_violations(example):
    _, _, result = example
    fig, ax = result.plot()
    try:
        labels = ax.get_legend_handles_labels()[1]
        counts = result.counts()
        assert sorted(labels) == sorted(f"{VIOLATION_STYLE[k][3]} ({counts[k]})" for k in VIOLATION_KINDS if counts.get(k))
        margin_points = ax.collections[0]
        assert len(margin_points.get_offsets()) == result.n_points
        colours = margin_points.get_array()
        assert colours[result.flagged("chatter")].max() < colours[~result.flagged("chatter")].min()
        assert ax.get_xlabel() == "x (mm)" and "240 points" in ax.get_title()
        assert len(fig.axes) == 2  # the path and its colour bar
    finally:
        plt.close(fig)
    with pytest.raises(ValueError, match="must contain the pass threshold"):
        result.plot(margin_range=(2.0, 3.0))


def test_importing_the_check_does_not_import_matplotlib_or_numba():
    code = "import sys, planner.check; sys.exit(('matplotlib' in sys.modules) or ('numba' in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT).returncode == 0


def test_bad_input_is_rejected(example):
    toolpath, models, _ = example
    with pytest.raises(ValueError, match="method must be one of 'zoa', 'sdm'"):
        check_toolpath(toolpath, models, method="fdm")
    with pytest.raises(ValueError, match="expected at least one modal model"):
        check_toolpath(toolpath, [])
    with pytest.raises(TypeError, match="models\\[1\\] is a str"):
        check_toolpath(toolpath, [models[0], "pose.yaml"])
    with pytest.raises(ModelError, match="models\\[2\\].pose.joints_deg"):
        check_toolpath(toolpath, [models[0], models[1], replace(models[2], joints_deg=None)])
    with pytest.raises(ValueError, match="pose_resolution_deg must be a number >= 0"):
        check_toolpath(toolpath, models, pose_resolution_deg=-1)
    with pytest.raises(ValueError, match="no cutting coefficients"):
        check_toolpath(replace(toolpath, material=Material("acetal")), models)
    with pytest.raises(ValueError, match="stability_margin must be a positive fraction"):
        check_toolpath(toolpath, models, limits=Limits(stability_margin=0.0))
    plunge = replace(toolpath, positions_m=toolpath.positions_m * [0, 0, 1] + [0, 0, 1] * np.arange(240)[:, None])
    with pytest.raises(ValueError, match="point 0: no feed direction across the tool axis"):
        check_toolpath(plunge, models)
    with pytest.raises(ValueError, match="kind must be one of"):
        check_toolpath(toolpath, models).flagged("vibration")
