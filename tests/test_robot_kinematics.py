"""Robot description, forward kinematics, tool-tip Jacobian and mass matrix (planner.robot),
on the real KUKA KR 500 R2800-2 URDF with a 150 kg spindle.

Cross-checks against independent computations: the Jacobian against complex-step derivatives of
forward kinematics (exact to rounding: Squire & Trapp, SIAM Review 40, 1998), the mass matrix
against the kinetic energy of each body from its own spatial velocity (tool body not lumped).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from planner.robot import RobotError, forward_kinematics, mass_matrix, read_robot, tip_jacobian, tool_axis, write_robot
from planner.robot.dynamics import body_inertias
from planner.robot.kinematics import flange_frames, link_frames
from robot_helpers import urdf_path, write_robot_file

H = 1e-20  # complex step: no subtractive cancellation, any small step is exact to rounding


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    return read_robot(write_robot_file(tmp_path_factory.mktemp("robot")))


def random_poses(robot, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(robot.lower_rad, robot.upper_rad, (n, 6))


def test_reads_the_chain_and_limits(robot):
    assert robot.joint_names == tuple(f"joint_{i}" for i in range(1, 7))
    assert robot.lower_rad[1] == pytest.approx(-2.268928025) and robot.upper_rad[1] == pytest.approx(8.72664625e-2)
    assert robot.link_mass_kg[0] == pytest.approx(587.48)
    mass, _, _ = body_inertias(robot)
    assert mass[5] == pytest.approx(23.3927 + 150.0)


def test_zero_pose_matches_the_urdf_geometry(robot):
    # At q = 0 the KR 500's arm is stretched horizontally along +X: joint 2 at 0.5 m, upper arm
    # 1.25 m, forearm + wrist to the flange 0.7217 + 0.3178 + 0.2052 + 0.0808 m, the 0.0755 + 0.1173
    # lateral offsets cancelled by the forearm's 0.1928; the tool0 flange's z axis points along +X, the tip 0.45 m
    # further out. Height: 0.3646 + 0.4354 + 0.15 (forearm offset) = 0.95 m.
    t = forward_kinematics(robot, np.zeros(6))[0]
    assert t[:3, 3] == pytest.approx([0.5 + 1.25 + 0.7217 + 0.3178 + 0.2052 + 0.0808 + 0.45, 0.0, 0.95], abs=1e-12)
    assert tool_axis(robot, np.zeros(6))[0] == pytest.approx([-1, 0, 0], abs=1e-12)


def test_jacobian_matches_complex_step_forward_kinematics(robot):
    q = random_poses(robot, 20, seed=1)
    jac = tip_jacobian(robot, q)
    for i in range(6):
        dq = q.astype(complex)
        dq[:, i] += 1j * H
        t = forward_kinematics(robot, dq)
        dp = t[:, :3, 3].imag / H
        d_rot = t[:, :3, :3].imag / H
        w_hat = d_rot @ np.swapaxes(t[:, :3, :3].real, 1, 2)
        w = np.stack([w_hat[:, 2, 1], w_hat[:, 0, 2], w_hat[:, 1, 0]], axis=-1)
        np.testing.assert_allclose(jac[:, :3, i], dp, rtol=0, atol=1e-13)
        np.testing.assert_allclose(jac[:, 3:, i], w, rtol=0, atol=1e-13)


def test_mass_matrix_matches_kinetic_energy_body_by_body(robot):
    # Independent computation: each body's (and the tool body's, not lumped) centre-of-mass
    # velocity and angular velocity from the complex-step time derivative of its frame along
    # q(t) = q + t qd, then T = sum 1/2 m v^2 + 1/2 w . (R I R^T) w; compare with 1/2 qd^T M qd.
    rng = np.random.default_rng(2)
    q = random_poses(robot, 30, seed=3)
    qd = rng.normal(size=q.shape)
    m = mass_matrix(robot, q)
    qc = q + 1j * H * qd
    rot, pos = link_frames(robot, qc)
    fl = flange_frames(robot, qc)
    bodies = [(robot.link_mass_kg[b], robot.link_com_m[b], robot.link_inertia_kg_m2[b], rot[:, b], pos[:, b])
              for b in range(6)]
    tool = robot.tool
    bodies.append((tool.mass_kg, tool.center_of_mass_m, tool.inertia_kg_m2, fl[:, :3, :3], fl[:, :3, 3]))
    energy = np.zeros(len(q))
    for mass, com, inertia, r, p in bodies:
        c = p + r @ com
        v = c.imag / H
        r_dot, r_re = r.imag / H, r.real
        w_hat = r_dot @ np.swapaxes(r_re, 1, 2)
        w = np.stack([w_hat[:, 2, 1], w_hat[:, 0, 2], w_hat[:, 1, 0]], axis=-1)
        iw = r_re @ inertia @ np.swapaxes(r_re, 1, 2)
        energy += 0.5 * mass * np.sum(v * v, axis=1) + 0.5 * np.einsum("ni,nij,nj->n", w, iw, w)
    expected = 0.5 * np.einsum("ni,nij,nj->n", qd, m, qd)
    np.testing.assert_allclose(expected, energy, rtol=1e-12)
    # symmetric positive definite
    np.testing.assert_array_equal(m, np.swapaxes(m, 1, 2))
    assert np.linalg.eigvalsh(m).min() > 0


def test_mass_matrix_does_not_depend_on_joint_1(robot):
    # Without gravity the arm's inertia seen by its joints cannot depend on the base rotation.
    q = random_poses(robot, 5, seed=4)
    q2 = q.copy()
    q2[:, 0] += 1.0
    np.testing.assert_allclose(mass_matrix(robot, q), mass_matrix(robot, q2), rtol=1e-12, atol=1e-9)


def test_write_robot_round_trip(robot, tmp_path):
    out = write_robot(robot.with_joints(joint_stiffness_N_m_rad=np.arange(1, 7) * 1e6), tmp_path / "sub" / "r.yaml")
    back = read_robot(out)
    np.testing.assert_array_equal(back.joint_stiffness_N_m_rad, np.arange(1, 7) * 1e6)
    np.testing.assert_array_equal(back.joint_origin, robot.joint_origin)
    np.testing.assert_array_equal(back.tool.inertia_kg_m2, robot.tool.inertia_kg_m2)


def test_pose_outside_limits(robot):
    q = np.zeros(6)
    q[1] = 0.5  # joint 2 upper limit is 5 deg
    with pytest.raises(RobotError, match=r"joint 2 \(joint_2\) within \[-130, 5\] deg, found 28.6479 deg"):
        robot.check_joints(q)


# ------------------------------------------------------------------------------- bad URDFs
def _edited(tmp_path, edit):
    text = urdf_path().read_text()
    new = edit(text)
    assert new != text
    urdf = tmp_path / "bad.urdf"
    urdf.write_text(new)
    robot_file = write_robot_file(tmp_path)
    robot_file.write_text(robot_file.read_text().replace(str(urdf_path()), str(urdf)))
    return robot_file, urdf


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace('<joint name="joint_3" type="revolute">', '<joint name="joint_3" type="prismatic">'),
     r"joint\[@name='joint_3'\]: expected a revolute \(or fixed\) joint, found type 'prismatic'"),
    (lambda t: re.sub(r'(<link name="link_4">)\s*<inertial>.*?</inertial>', r"\1", t, flags=re.S),
     r"link\[@name='link_4'\]/inertial: expected the mass and inertia of a moving link, found none"),
    (lambda t: t.replace("</robot>", '<link name="extra"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1"/>'
                         '</inertial></link><joint name="side" type="revolute"><parent link="link_3"/>'
                         '<child link="extra"/><axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint></robot>'),
     r"joint\[@name='side'\]: expected a serial chain from 'base_link' to 'tool0'.*branching off it"),
    (lambda t: t.replace('<joint name="link6-tool0" type="fixed">\n    <child link="tool0" />',
                         '<joint name="link6-tool0" type="fixed">\n    <child link="tool0x" />'),
     r"link\[@name='tool0'\]: expected a serial chain from 'base_link' to 'tool0'"),
    (lambda t: t.replace('<robot name="kr500_r2800_2">', '<robot name="kr500_r2800_2"'),
     r"document: expected URDF \(XML\)"),
])
def test_bad_urdf_one_line_error_naming_file_and_element(tmp_path, edit, message):
    robot_file, urdf = _edited(tmp_path, edit)
    with pytest.raises(RobotError, match=re.escape(str(urdf)) + ": " + message) as info:
        read_robot(robot_file)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("old, new, message", [
    ("stiffness_N_m_rad: [2.3e6", "stiffness_N_m_rad: [-2.3e6", r"joints.stiffness_N_m_rad: expected six stiffnesses > 0"),
    ("mass_kg: 150.0", "mas_kg: 150.0", r"tool.mass_kg: expected a number >= 0, found nothing"),
    ("urdf: ", "urdf: missing", r"urdf: expected an existing URDF file, found no such file"),
    ("damping_ratio:", "damping_N_m_s_rad: [1, 1, 1, 1, 1, 1]\n  damping_ratio:",
     r"joints.damping_ratio: expected one of damping_ratio and damping_N_m_s_rad, found both"),
])
def test_bad_robot_file_fields(tmp_path, old, new, message):
    robot_file = write_robot_file(tmp_path)
    robot_file.write_text(robot_file.read_text().replace(old, new, 1))
    with pytest.raises(RobotError, match=re.escape(str(robot_file)) + ": " + message):
        read_robot(robot_file)


def test_same_tool_described_on_the_kuka_flange_frame(robot, tmp_path):
    # KUKA's `flange` frame has x out of the flange where `tool0` has z: the same physical tool,
    # described on `flange` (tip along x, axis -x, inertia permuted), gives the same tool tip, tool
    # axis, Jacobian and mass matrix; its rotation reference falls back to the flange y axis.
    text = write_robot_file(tmp_path).read_text()
    text = (text.replace("flange_link: tool0", "flange_link: flange")
            .replace("tip_m: [0.0, 0.0, 0.45]", "tip_m: [0.45, 0.0, 0.0]")
            .replace("axis: [0.0, 0.0, -1.0]", "axis: [-1.0, 0.0, 0.0]")
            .replace("center_of_mass_m: [0.0, 0.0, 0.20]", "center_of_mass_m: [0.20, 0.0, 0.0]")
            .replace("[[4.0, 0, 0], [0, 4.0, 0], [0, 0, 1.5]]", "[[1.5, 0, 0], [0, 4.0, 0], [0, 0, 4.0]]"))
    (tmp_path / "flange.yaml").write_text(text)
    other = read_robot(tmp_path / "flange.yaml")
    q = random_poses(robot, 10, seed=9)
    np.testing.assert_allclose(forward_kinematics(other, q)[:, :3, 3], forward_kinematics(robot, q)[:, :3, 3],
                               atol=1e-12)
    np.testing.assert_allclose(tool_axis(other, q), tool_axis(robot, q), atol=1e-12)
    np.testing.assert_allclose(tip_jacobian(other, q), tip_jacobian(robot, q), atol=1e-12)
    np.testing.assert_allclose(mass_matrix(other, q), mass_matrix(robot, q), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(other.tool.reference_axis, [0, 1, 0])
