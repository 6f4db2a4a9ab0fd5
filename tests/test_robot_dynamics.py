"""Dynamics at a pose (planner.robot.dynamics): the eigen-solution and the tool-tip modal model
against the direct receptance ``G(w) = J_v (K - w^2 M + i w C)^-1 J_v^T`` of formats.md."""

from __future__ import annotations

import numpy as np
import pytest

from oma.modal import ModalModel
from planner.robot import RobotError, mass_matrix, read_robot, robot_modal_model, robot_modes
from planner.robot.dynamics import damping_matrix, direct_receptance
from robot_helpers import write_robot_file


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    return read_robot(write_robot_file(tmp_path_factory.mktemp("robot")))


POSE = np.radians([10.0, -70.0, 100.0, 20.0, 50.0, -30.0])


def test_modes_are_mass_and_stiffness_orthonormal(robot):
    q = np.random.default_rng(5).uniform(robot.lower_rad, robot.upper_rad, (50, 6))
    modes = robot_modes(robot, q)
    m = mass_matrix(robot, q)
    phi = modes.shapes
    w = 2 * np.pi * modes.frequency_hz
    np.testing.assert_allclose(np.swapaxes(phi, 1, 2) @ m @ phi, np.broadcast_to(np.eye(6), m.shape), atol=1e-10)
    k = np.diag(robot.joint_stiffness_N_m_rad)
    np.testing.assert_allclose(np.swapaxes(phi, 1, 2) @ k @ phi / w[:, :, None] ** 2,
                               np.broadcast_to(np.eye(6), m.shape), atol=1e-10)
    assert np.all(np.diff(modes.frequency_hz, axis=1) >= 0)
    # equal joint damping ratios: every mode has it (strain-energy weights sum to one)
    np.testing.assert_allclose(modes.damping_ratio, 0.05, rtol=1e-12)


def test_modal_model_receptance_matches_the_direct_formula(robot):
    model = robot_modal_model(robot, POSE, min_tip_fraction=0.0)
    freq = np.linspace(0.5, 400.0, 800)
    direct = direct_receptance(robot, POSE, freq)
    np.testing.assert_allclose(model.receptance(freq), direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max())
    np.testing.assert_allclose(model.joints_deg, np.degrees(POSE))
    # stiffness_N_m = w^2 / |J_v phi|^2: the static compliance is J_v K^-1 J_v^T
    from planner.robot import tip_jacobian

    jv = tip_jacobian(robot, POSE)[0, :3]
    np.testing.assert_allclose(model.static_compliance_m_N, jv @ np.diag(1 / robot.joint_stiffness_N_m_rad) @ jv.T,
                               rtol=1e-9)


def test_default_model_drops_only_modes_that_do_not_move_the_tip(robot):
    full = robot_modal_model(robot, POSE, min_tip_fraction=0.0)
    default = robot_modal_model(robot, POSE)
    freq = np.linspace(1, 100, 50)
    np.testing.assert_allclose(default.receptance(freq), full.receptance(freq), rtol=1e-6,
                               atol=1e-6 * np.abs(full.receptance(freq)).max())


def test_viscous_joint_damping_is_close_for_light_damping(robot):
    c = 2 * 0.02 * np.sqrt(robot.joint_stiffness_N_m_rad * 50.0)  # light: about 2 % of critical
    viscous = robot.with_joints(damping_ratio=None, damping_N_m_s_rad=c)
    model = robot_modal_model(viscous, POSE, min_tip_fraction=0.0)
    np.testing.assert_array_equal(damping_matrix(viscous, POSE)[0], np.diag(c))
    freq = np.linspace(0.5, 60.0, 400)
    direct = direct_receptance(viscous, POSE, freq)
    # diagonal modal damping: exact to first order in the off-diagonal modal damping terms
    err = np.abs(model.receptance(freq) - direct).max() / np.abs(direct).max()
    assert err < 0.05


def test_tool_model_in_series(robot):
    tool = ModalModel([600.0], [0.03], [2e7], [[1.0, 0, 0]])
    arm = robot_modal_model(robot, POSE)
    both = robot_modal_model(robot, POSE, tool_model=tool)
    freq = np.array([5.0, 50.0, 600.0])
    np.testing.assert_allclose(both.receptance(freq), arm.receptance(freq) + tool.receptance(freq))
    np.testing.assert_allclose(both.joints_deg, np.degrees(POSE))


def test_vectorised_modes_equal_one_by_one(robot):
    q = np.random.default_rng(6).uniform(robot.lower_rad, robot.upper_rad, (4, 6))
    many = robot_modes(robot, q)
    for i in range(4):
        one = robot_modes(robot, q[i])
        model = many.model(i)
        np.testing.assert_allclose(model.joints_deg, np.degrees(q[i]))
        np.testing.assert_allclose(model.receptance([5.0, 20.0]), robot_modal_model(robot, q[i]).receptance([5.0, 20.0]),
                                   rtol=1e-9)
        np.testing.assert_allclose(many.frequency_hz[i], one.frequency_hz[0], rtol=1e-12)
        np.testing.assert_allclose(many.stiffness_N_m[i], one.stiffness_N_m[0], rtol=1e-9)


def test_errors(robot, tmp_path):
    bare = read_robot(write_robot_file(tmp_path, stiffness=False))
    with pytest.raises(RobotError, match=r"robot.yaml: joints.stiffness_N_m_rad: expected joint stiffness"):
        robot_modal_model(bare, POSE)
    bad = POSE.copy()
    bad[4] = 2.5
    with pytest.raises(RobotError, match=r"joint 5 \(joint_5\) within \[-120, 120\] deg"):
        robot_modal_model(robot, bad)


def test_compiled_kernel_equals_the_numpy_reference(robot):
    from planner.robot import tip_jacobian
    from planner.robot.dynamics import mass_and_jacobian

    q = np.random.default_rng(8).uniform(robot.lower_rad, robot.upper_rad, (200, 6))
    m, jv = mass_and_jacobian(robot, q)
    ref = mass_matrix(robot, q)
    np.testing.assert_allclose(m, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_allclose(jv, tip_jacobian(robot, q)[:, :3], rtol=0, atol=1e-13)
