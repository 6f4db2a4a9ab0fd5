"""Closed-form inverse kinematics (planner.robot.ik) checked against forward kinematics."""

from __future__ import annotations

import re

import numpy as np
import pytest

from planner.robot import RobotError, forward_kinematics, read_robot, tool_axis
from planner.robot.ik import (N_BRANCHES, continuous_branch, inverse_kinematics, joint_limit_distance, opw_parameters,
                              singularity_measure, tool_rotation)
from robot_helpers import urdf_path, write_robot_file


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    return read_robot(write_robot_file(tmp_path_factory.mktemp("robot")))


def test_opw_parameters_of_the_kr500(robot):
    # From the URDF's joint origins: shoulder 0.5 m out and 0.8 m up (0.3646 + 0.4354), upper arm
    # 1.25 m, forearm 0.7217 + 0.3178 m with a 0.15 m elbow offset, wrist to flange 0.2052 + 0.0808 m,
    # lateral offsets 0.0755 + 0.1173 - 0.1928 = 0.
    par = opw_parameters(robot)
    expected = {"a1": 0.5, "c1": -0.8, "c2": 1.25, "b": 0.0, "c3": 1.0395, "a2": 0.15, "c4": 0.286}
    for key, value in expected.items():
        assert par[key] == pytest.approx(value, abs=1e-12), key


def test_round_trip_every_branch(robot):
    rng = np.random.default_rng(7)
    n = 10_000
    q = rng.uniform(robot.lower_rad, robot.upper_rad, (n, 6))
    t = forward_kinematics(robot, q)
    ref = rng.normal(size=(n, 3))
    rho = tool_rotation(robot, q, ref)
    sol = inverse_kinematics(robot, t[:, :3, 3], tool_axis(robot, q), rho, ref)
    assert sol.q.shape == (n, N_BRANCHES, 6) and sol.valid.shape == (n, N_BRANCHES)
    qs = sol.q[sol.reachable]
    idx = np.nonzero(sol.reachable)[0]
    back = forward_kinematics(robot, qs)
    assert np.abs(back[:, :3, 3] - t[idx, :3, 3]).max() < 1e-9  # the target: 1e-9 m
    assert np.abs(back[:, :3, :3] - t[idx, :3, :3]).max() < 1e-9
    # the pose we started from is one of the branches (up to whole turns); near the wrist
    # singularity (q5 -> 0) q4 and q6 are ill-conditioned (error ~ eps / |sin q5|), so compare there
    # with that scale
    diff = np.abs((sol.q - q[:, None, :] + np.pi) % (2 * np.pi) - np.pi).max(axis=2)
    scale = 1e-10 / np.maximum(np.abs(np.sin(q[:, 4])), 1e-12)
    assert np.all(np.nanmin(diff, axis=1) < np.maximum(1e-8, scale))
    # flags: valid = reachable and within limits, and within-limits branches are inside
    np.testing.assert_array_equal(sol.valid, sol.reachable & sol.within_limits)
    inside = sol.q[sol.valid]
    assert np.all((inside >= robot.lower_rad - 1e-12) & (inside <= robot.upper_rad + 1e-12))
    outside = sol.q[sol.reachable & ~sol.within_limits]
    assert np.all(((outside < robot.lower_rad) | (outside > robot.upper_rad)).any(axis=1))


def test_rotation_about_the_tool_axis(robot):
    # rotation 0: the flange x axis is the feed direction's part normal to the tool axis
    feed = np.array([[0.3, 1.0, 0.2]])
    a = np.array([[0.0, 0.0, 1.0]])
    for rho in (0.0, 0.7, -2.0):
        sol = inverse_kinematics(robot, [[1.8, 0.4, 0.6]], a, rho, feed)
        q = sol.q[0][sol.valid[0]]
        assert len(q) > 0
        np.testing.assert_allclose(tool_axis(robot, q), np.repeat(a, len(q), 0), atol=1e-12)
        np.testing.assert_allclose(tool_rotation(robot, q, np.repeat(feed, len(q), 0)), rho, atol=1e-12)
        flange_x = forward_kinematics(robot, q)[:, :3, 0]
        expected = np.array([np.cos(rho) * 0.3 - np.sin(rho) * 1.0, np.sin(rho) * 0.3 + np.cos(rho) * 1.0, 0])
        np.testing.assert_allclose(flange_x, np.repeat([expected / np.linalg.norm(expected)], len(q), 0), atol=1e-12)


def test_unreachable_point(robot):
    sol = inverse_kinematics(robot, [[6.0, 0.0, 0.5], [1.8, 0.0, 0.6]], [0, 0, 1], 0.0, [1, 0, 0])
    assert not sol.reachable[0].any() and np.isnan(sol.q[0]).all()
    assert sol.valid[1].any()


def test_reference_parallel_to_the_tool_axis(robot):
    with pytest.raises(ValueError, match="point 0: the reference direction is parallel to the tool axis"):
        inverse_kinematics(robot, [[1.8, 0.0, 0.6]], [0, 0, 1], 0.0, [0, 0, 2])


def test_continuous_branch_along_a_line(robot):
    n = 200
    pos = np.column_stack([np.full(n, 1.9), np.linspace(-0.6, 0.6, n), np.full(n, 0.5)])
    feed = np.array([0.0, 1.0, 0.0])
    sol = inverse_kinematics(robot, pos, [0, 0, 1], 0.3, feed)
    path = continuous_branch(robot, sol)
    assert np.all(path.branch >= 0) and path.flips.size == 0
    step = np.abs(np.diff(path.q, axis=0)).max()
    assert step < np.radians(2.0)  # 6 mm steps: no joint jumps
    np.testing.assert_allclose(forward_kinematics(robot, path.q)[:, :3, 3], pos, atol=1e-9)


def test_singularity_and_limit_measures(robot):
    q = np.radians([[0, -60, 80, 0, 0, 0], [0, -60, 80, 0, 40, 0]])  # wrist singular at q5 = 0
    s = singularity_measure(robot, q)
    assert s[0] < 1e-12 < 1e-3 < s[1] <= 1
    d = joint_limit_distance(robot, q)
    assert d[0, 1] == pytest.approx(np.radians(65))  # joint 2 in [-130, 5] deg at -60 deg
    assert d[1, 4] == pytest.approx(np.radians(80))  # joint 5 in [-120, 120] deg at 40 deg


def test_non_opw_robot_is_rejected(tmp_path):
    text = urdf_path().read_text().replace('xyz="0.2052 0.0 -0.1193"', 'xyz="0.2052 0.05 -0.1193"')
    bad = tmp_path / "offset_wrist.urdf"
    bad.write_text(text)
    robot_file = write_robot_file(tmp_path)
    robot_file.write_text(robot_file.read_text().replace(str(urdf_path()), str(bad)))
    robot = read_robot(robot_file)  # a valid serial chain, but not a spherical wrist
    with pytest.raises(RobotError, match=re.escape(str(bad)) + r": chain base_link -> tool0: expected joints 4, 5 "
                       r"and 6 meeting in one point .* found joint \d 0\.0\d+ m from the wrist centre"):
        inverse_kinematics(robot, [[1.8, 0, 0.6]], [0, 0, 1], 0.0, [1, 0, 0])
