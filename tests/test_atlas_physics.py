"""The atlas's per-point physics, cross-checked against independent computations: forward
kinematics of the chosen joints, the robot's modal model, stability.zoa's exact envelope and
predict_point, and a brute-force search of the best cut on that envelope."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atlas_cases import robot_file, same_table, small_region, stability_bound_setup


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    from planner.atlas import build_problem
    from planner.robot import read_robot

    robot = read_robot(robot_file(tmp_path_factory.mktemp("atlas_robot")))
    setup = stability_bound_setup()
    region = small_region()
    problem = build_problem(robot, setup, region)
    pos = region.to_machine(region.positions_m())
    from planner.atlas.evaluate import evaluate_chunk

    return robot, setup, region, problem, pos, evaluate_chunk(problem, pos)


def test_chosen_pose_places_the_tool_and_is_farthest_from_the_joint_limits(case):
    from planner.robot import forward_kinematics
    from planner.robot.ik import inverse_kinematics

    robot, setup, region, problem, pos, out = case
    reach = out["reachable"]
    assert reach.mean() > 0.5  # the box sits in the robot's working range
    q = np.radians(np.column_stack([out[f"q{j}_deg"] for j in range(1, 7)]))[reach]
    t = forward_kinematics(robot, q)
    p = np.repeat(pos, problem.rotations_rad.size, axis=0)[reach]
    assert np.max(np.abs(t[:, :3, 3] - p)) < 1e-9  # tool tip where asked, m
    axis = t[:, :3, :3] @ robot.tool.axis
    assert np.max(np.abs(axis - problem.tool_axis)) < 1e-9
    assert np.all(q >= robot.lower_rad - 1e-12) and np.all(q <= robot.upper_rad + 1e-12)
    # the rule: no other valid branch is farther from the joint limits
    rho = np.tile(problem.rotations_rad, pos.shape[0])[reach]
    sol = inverse_kinematics(robot, p, problem.tool_axis, rho, problem.feed_direction)
    dist = np.where(sol.valid, np.minimum(sol.q - robot.lower_rad, robot.upper_rad - sol.q).min(axis=2), -np.inf)
    assert np.allclose(np.radians(out["joint_limit_distance_deg"][reach]), dist.max(axis=1), rtol=0, atol=1e-12)


def test_lowest_mode_is_the_robot_modal_models(case):
    from planner.robot import robot_modal_model

    robot, setup, region, problem, pos, out = case
    for i in np.flatnonzero(out["reachable"])[::7]:
        q = np.radians([out[f"q{j}_deg"][i] for j in range(1, 7)])
        model = robot_modal_model(robot, q, min_tip_fraction=problem.min_tip_fraction)
        assert math.isclose(out["lowest_mode_hz"][i], model.natural_frequency_hz.min(), rel_tol=1e-12)


def test_best_cut_against_the_exact_zoa_envelope(case):
    """At a sample of rows: the reported limit is stability.lobes.predict_point's at the chosen speed
    (to its 1e-9), and the MRR is the best of a brute-force search over the exact envelope
    (stability.zoa.envelope) on the same speed grid. The atlas ranks the speeds on the envelope
    interpolated between chatter-frequency nodes and solves the limit exactly only at the chosen
    one, so it could pick a worse speed where two are within the interpolation error: measured
    3e-14 over 40 rows (also against 10 000 chatter frequencies); 1e-9 leaves only rounding."""
    from planner.robot import robot_modal_model
    from stability import zoa
    from stability.lobes import predict_point

    robot, setup, region, problem, pos, out = case
    tool, cut, coef = setup.tool, setup.cut, setup.material.cutting_coefficients
    rows = np.flatnonzero(np.isfinite(out["mrr_m3_s"]))[::11][:6]
    assert rows.size >= 4
    for i in rows:
        q = np.radians([out[f"q{j}_deg"][i] for j in range(1, 7)])
        model = robot_modal_model(robot, q, min_tip_fraction=problem.min_tip_fraction)
        rpm = out["spindle_rpm"][i]
        point = predict_point(model, tool, cut, coef, spindle_rpm=rpm, axial_depth_m=1e-3, n_freq=problem.n_freq)
        assert math.isclose(out["depth_limit_m"][i], point.depth_limit_m, rel_tol=1e-9)
        # brute force on the exact envelope at every grid speed
        env = zoa.envelope(model, tool, cut, coef, problem.rpm_grid, n_freq=problem.n_freq)
        keep = np.isin(env.rpm, problem.rpm_grid)
        n, lim = env.rpm[keep], env.depth_limit_m[keep]
        ap = np.minimum(np.minimum(problem.ap_hi_m, problem.power_depth_rpm / n), problem.margin * lim)
        rate = np.where(ap >= problem.ap_lo_m, ap * n, 0.0) * problem.mrr_per_depth_rpm
        assert out["active_constraint"][i] == 0  # this setup is bound by stability
        assert out["mrr_m3_s"][i] == pytest.approx(rate.max(), rel=1e-9)
        # the cut obeys every bound it was planned under
        assert out["axial_depth_m"][i] <= problem.margin * out["depth_limit_m"][i] * (1 + 1e-12)
        assert problem.ap_lo_m <= out["axial_depth_m"][i] <= problem.ap_hi_m * (1 + 1e-12)
        mrr = out["axial_depth_m"][i] * cut.radial_depth_m * problem.feed_per_tooth_m * tool.teeth * rpm / 60
        assert math.isclose(out["mrr_m3_s"][i], mrr, rel_tol=1e-12)


def test_power_bound_is_exact_when_it_binds(tmp_path):
    """With the example's 8 kW spindle over 500-24000 rpm the spindle, not chatter, limits the
    robot's cut (its modes are at 4-12 Hz): the MRR is the power's, P / (specific energy)."""
    from planner.atlas import build_problem
    from planner.atlas.evaluate import evaluate_chunk
    from planner.cut_model import CutModel
    from planner.robot import read_robot
    from stability.setup_io import read_setup

    from atlas_cases import SETUP

    robot = read_robot(robot_file(tmp_path))
    setup = read_setup(SETUP)
    region = small_region(0.6, rotations=(0.0,))
    problem = build_problem(robot, setup, region)
    out = evaluate_chunk(problem, region.to_machine(region.positions_m()))
    power = out["active_constraint"] == 4
    assert power.any()
    cm = CutModel(None, setup.tool, setup.cut, setup.material.cutting_coefficients)
    fz = setup.limits.feed_per_tooth_m[1]
    expect = cm.power(out["spindle_rpm"][power], out["axial_depth_m"][power], fz)
    assert np.allclose(expect, setup.limits.spindle_power_W, rtol=1e-12)
    assert np.allclose(out["power_W"][power], expect, rtol=1e-12)


def test_rows_do_not_depend_on_the_chunking(case):
    from planner.atlas.evaluate import evaluate_chunk

    robot, setup, region, problem, pos, out = case
    parts = [evaluate_chunk(problem, pos[i:i + 3]) for i in range(0, pos.shape[0], 3)]
    joined = {k: np.concatenate([p[k] for p in parts]) for k in out}
    assert same_table(out, joined)


def test_sdm_checks_the_best_rows_at_low_immersion(tmp_path):
    """ae/D = 0.08 (< 0.2): method 'auto' checks the best rows of the n_verify best positions by
    SDM; each SDM limit equals an independent lobe_diagram(method='sdm') of the robot's modal model
    at that row's joints and speed, and the best placement is chosen on the SDM values."""
    from dataclasses import replace

    from planner.atlas import Region, build_problem, run_atlas
    from planner.robot import read_robot, robot_modal_model
    from stability.lobes import lobe_diagram

    robot = read_robot(robot_file(tmp_path))
    setup = stability_bound_setup()
    setup = replace(setup, cut=replace(setup.cut, radial_depth_m=0.002))
    region = Region([1.8, -0.3, 0.6], [2.1, 0.3, 0.6], 0.3, [0.0, 90.0])
    problem = build_problem(robot, setup, region)
    result = run_atlas(problem, region, scheduler="serial", progress=False, n_verify=2)
    c = result.columns
    rows = np.flatnonzero(np.isfinite(c["sdm_depth_limit_m"]))
    assert rows.size == 2 and result.engine["sdm_verified_rows"] == 2
    assert set(rows) <= set(result.best_row_per_point)
    for i in rows:
        q = np.radians([c[f"q{j}_deg"][i] for j in range(1, 7)])
        model = robot_modal_model(robot, q, min_tip_fraction=problem.min_tip_fraction)
        rpm = c["spindle_rpm"][i]
        d = lobe_diagram(model, setup.tool, problem.cut_machine, setup.material.cutting_coefficients,
                         rpm_range=(rpm, 2 * rpm), rpm=[rpm], method="sdm")
        assert c["sdm_depth_limit_m"][i] == d.depth_limit_m[0]
        ap = min(problem.ap_hi_m, problem.margin * d.depth_limit_m[0])
        assert c["sdm_axial_depth_m"][i] == pytest.approx(ap, rel=1e-12)
    best = result.best
    assert best["stability"] == "sdm" and best["sdm_mrr_m3_s"] == np.nanmax(c["sdm_mrr_m3_s"])
