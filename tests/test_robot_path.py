"""``check --robot``: a Cartesian toolpath (part frame, no joints) checked with the robot model.

Cross-checks: the joints found reproduce every target through forward kinematics (an independent
computation: the chain's transforms, not the closed-form IK); the vectorised per-point model gives
the same stability limit and surface error as the check with the single model
``robot_modal_model`` at that pose; the new violation kinds on constructed cases.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from robot_helpers import TOOLPATH_HEADER, toolpath_yaml, write_robot_file  # noqa: E402

from oma.errors import ToolpathError  # noqa: E402
from oma.modal_io import read_modal_model  # noqa: E402
from planner.check import ROBOT_KINDS, check_toolpath  # noqa: E402
from planner.cli import main  # noqa: E402
from planner.robot import forward_kinematics, read_robot, robot_modal_model, tool_axis  # noqa: E402
from planner.robot.path import SINGULARITY_THRESHOLD, singularity_measure, solve_path  # noqa: E402
from planner.toolpath_io import read_toolpath, write_toolpath  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "kr500_acetal"

# the workpiece frame and limits of the toolpath files of these tests
PATH_OPTIONS = dict(origin_m=[1.5, 0.2, 0.5], rpy_deg=[0, 0, 30],
                    limits="{stability_margin: 0.8, surface_location_error_m: 0.0003}")


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    d = tmp_path_factory.mktemp("cell")
    robot_file = write_robot_file(d)
    (d / "path.yaml").write_text(toolpath_yaml(robot_file.name, **PATH_OPTIONS))
    y = np.linspace(-0.2, 0.2, 9)
    rows = [f"0.0,{float(v)!r},0.0,2700,0.0005,0.006,0.006,down" for v in y]
    (d / "path.csv").write_text(TOOLPATH_HEADER + "\n" + "\n".join(rows) + "\n")
    return d, read_robot(robot_file), read_toolpath(d / "path.yaml")


def test_toolpath_with_robot_reads_and_round_trips(cell, tmp_path):
    d, robot, tp = cell
    assert tp.joints_deg is None and tp.robot_file == str(d / "robot.yaml")
    np.testing.assert_array_equal(tp.workpiece_origin_m, [1.5, 0.2, 0.5])
    machine = tp.in_machine_frame()
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(machine.positions_m[0], [1.5 + 0.2 * s, 0.2 - 0.2 * c, 0.5], atol=1e-15)
    rot = np.full(tp.n_points, np.nan)
    rot[2] = 15.0
    (tmp_path / "sub").mkdir()
    out = write_toolpath(replace(tp, tool_rotation_deg=rot), tmp_path / "sub" / "out.yaml")
    back = read_toolpath(out)
    assert Path(back.robot_file).resolve() == (d / "robot.yaml").resolve()
    np.testing.assert_array_equal(back.tool_rotation_deg, rot)
    np.testing.assert_array_equal(back.workpiece_rpy_deg, [0, 0, 30])
    assert back.joints_deg is None


@pytest.mark.parametrize("yaml_extra, csv_text, match", [
    ("", TOOLPATH_HEADER + ",tool_rotation_deg\n0,0,0,2700,0.0005,0.006,0.006,down,0\n0,1,0,2700,0.0005,0.006,0.006,down,0\n",
     r"column tool_rotation_deg: expected a robot"),
    ("", TOOLPATH_HEADER + "\n0,0,0,2700,0.0005,0.006,0.006,down\n0,1,0,2700,0.0005,0.006,0.006,down\n",
     r"column q1_deg: expected a column q1_deg"),
    ("robot: nothere.yaml\n", TOOLPATH_HEADER + "\n0,0,0,2700,0.0005,0.006,0.006,down\n0,1,0,2700,0.0005,0.006,0.006,down\n",
     r"robot: expected a robomill-robot/1 file .*no such file"),
    ("robot: robot.yaml\n", "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg," + TOOLPATH_HEADER
     + "\n0,0,0,0,0,nan,0,0,0,2700,0.0005,0.006,0.006,down\n" + "0," * 6 + "0,1,0,2700,0.0005,0.006,0.006,down\n",
     r"row 1, column q6_deg: expected a finite number \(or all six"),
])
def test_toolpath_robot_errors(tmp_path, yaml_extra, csv_text, match):
    write_robot_file(tmp_path)
    text = toolpath_yaml("x", **PATH_OPTIONS).replace("robot: x\n", yaml_extra)
    (tmp_path / "p.yaml").write_text(text)
    (tmp_path / "path.csv").write_text(csv_text)
    with pytest.raises(ToolpathError, match=match):
        read_toolpath(tmp_path / "p.yaml")


def test_ik_joints_reproduce_the_targets(cell):
    """Forward kinematics of the joints found puts the tip on every target (machine frame) with the
    tool along the path's axis and the flange reference axis along the feed (rotation 0)."""
    _, robot, tp = cell
    result = check_toolpath(tp, robot=robot, pose_resolution_deg=0)
    q = np.radians(result.joints_deg)
    machine = tp.in_machine_frame()
    tips = forward_kinematics(robot, q)
    np.testing.assert_allclose(tips[:, :3, 3], machine.positions_m, atol=1e-9)  # IK round trip, m
    np.testing.assert_allclose(tool_axis(robot, q), np.broadcast_to(machine.tool_axis, (tp.n_points, 3)), atol=1e-9)
    x = tips[:, :3, :3] @ robot.tool.reference_axis
    np.testing.assert_allclose(x, machine.feed_directions(), atol=1e-9)
    # one branch (no configuration flip): the joints move little between neighbouring points
    assert np.max(np.abs(np.diff(result.joints_deg, axis=0))) < 10.0
    assert result.ok or set(result.counts()) == set(ROBOT_KINDS)


def test_per_point_model_equals_the_single_model_check(cell):
    """The vectorised robot model (six modes per pose + the tool mode) gives the stability limit
    and surface error of the check with ``robot_modal_model`` at the same pose."""
    _, robot, tp = cell
    tool = read_modal_model(EXAMPLE / "models" / "tool_mode.yaml")
    full = check_toolpath(tp, robot=robot, tool_model=tool, pose_resolution_deg=0)
    machine = tp.in_machine_frame()
    for i in (0, 4, 8):
        model = robot_modal_model(robot, np.radians(full.joints_deg[i]), tool_model=tool)
        j = i + 1 if i + 1 < tp.n_points else i - 1
        pair = [min(i, j), max(i, j)]
        sub = replace(machine, positions_m=machine.positions_m[pair], joints_deg=full.joints_deg[pair],
                      **{k: getattr(machine, k)[pair] for k in ("spindle_rpm", "feed_per_tooth_m", "radial_depth_m",
                                                                  "axial_depth_m", "milling")})
        with pytest.warns(UserWarning, match="one modal model"):
            single = check_toolpath(sub, [model])
        k = pair.index(i)
        # the per-point model keeps modes down to 1e-9 of the largest tip compliance, robot_modal_model
        # drops them: the difference is of that order
        assert single.depth_limit_m[k] == pytest.approx(full.depth_limit_m[i], rel=1e-7)
        assert single.surface_location_error_m[k] == pytest.approx(full.surface_location_error_m[i], rel=1e-7)


def test_unreachable_joint_limit_and_singularity(cell, tmp_path):
    d, robot, tp = cell
    machine = tp.in_machine_frame()
    n = tp.n_points
    # point 3 far outside the reach: unreachable; its stability is unknown (NaN), the rest is evaluated
    far = np.array(machine.positions_m)
    far[3] = [6.0, 0.0, 0.0]
    far[4] = [6.0, 0.05, 0.0]
    res = check_toolpath(replace(machine, positions_m=far), robot=robot)
    assert np.flatnonzero(res.flagged("unreachable")).tolist() == [3, 4]
    assert np.isnan(res.stability_margin[3]) and np.isfinite(res.stability_margin[0])
    assert np.all(np.isnan(res.joints_deg[3]))
    # given joints win: one pose outside joint 2's range, one at the wrist singularity (q5 = 0)
    base = check_toolpath(tp, robot=robot, pose_resolution_deg=0)
    joints = np.full((n, 6), np.nan)
    joints[5] = base.joints_deg[5]
    joints[5, 1] = math.degrees(robot.upper_rad[1]) + 2.0
    joints[6] = base.joints_deg[6]
    joints[6, 4] = 0.0
    res = check_toolpath(replace(tp, joints_deg=joints), robot=robot)
    lim = [v for v in res.violations if v["kind"] == "joint_limit"]
    assert [v["index"] for v in lim] == [5] and lim[0]["value"] == pytest.approx(2.0, abs=1e-9)
    sing = [v for v in res.violations if v["kind"] == "singularity"]
    assert [v["index"] for v in sing] == [6]
    assert sing[0]["value"] < SINGULARITY_THRESHOLD == sing[0]["limit"]
    assert singularity_measure(robot, np.radians(joints[6]))[0] < 1e-9  # q5 = 0: exactly singular
    np.testing.assert_array_equal(res.joints_deg[5], joints[5])  # given joints win


def test_branch_is_kept_and_solve_path_marks_given_rows(cell):
    _, robot, tp = cell
    m = tp.in_machine_frame()
    n = m.n_points
    axes = np.broadcast_to(m.tool_axis, (n, 3))
    free = solve_path(robot, m.positions_m, axes, m.feed_directions(), np.zeros(n))
    assert free.branch >= 0 and free.reachable.all() and not free.given.any()
    other = (free.branch + 4) % 8  # the other shoulder
    forced = solve_path(robot, m.positions_m, axes, m.feed_directions(), np.zeros(n), branch=other)
    assert not np.allclose(forced.joints_rad[forced.reachable], free.joints_rad[forced.reachable])


def test_cli_check_robot(cell, tmp_path, capsys):
    d, robot, tp = cell
    code = main(["check", str(d / "path.yaml"), "--json"])
    out = capsys.readouterr().out
    assert code in (0, 1) and '"unreachable"' in out
    bare = write_robot_file(tmp_path, stiffness=False, name="bare.yaml")
    assert main(["check", str(d / "path.yaml"), "--robot", str(bare)]) == 2
    err = capsys.readouterr().err
    assert "joints.stiffness_N_m_rad: expected joint stiffness" in err and len(err.strip().splitlines()) == 1
    assert main(["check", str(d / "path.yaml"), "--robot", str(d / "robot.yaml"), "--models",
                 str(EXAMPLE / "poses" / "pose_1.yaml")]) == 2
    assert "either --models or --robot" in capsys.readouterr().err
    # the example's robot is not calibrated yet: exit 2, one line
    assert main(["check", str(EXAMPLE / "toolpath.yaml")]) == 2
    assert "robot.yaml: joints.stiffness_N_m_rad: expected joint stiffness" in capsys.readouterr().err
    # a toolpath with neither a robot nor --models
    plain = tmp_path / "plain.yaml"
    plain.write_text((d / "path.yaml").read_text().replace("robot: robot.yaml\n", ""))
    (tmp_path / "path.csv").write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg," + TOOLPATH_HEADER + "\n"
                                       + "".join(f"0,-90,90,0,30,0,0.0,{y},0.0,2700,0.0005,0.006,0.006,down\n"
                                                 for y in (0.0, 0.1)))
    assert main(["check", str(plain)]) == 2
    assert "robot: expected a robot" in capsys.readouterr().err


def test_lowest_mode_map_is_the_robot_model_at_the_ik_pose(cell):
    """One grid point of the map against ``robot_modal_model`` at the pose found by the check."""
    from planner.robot.path import lowest_mode_map

    _, robot, tp = cell
    machine = tp.in_machine_frame()
    x, y, z = machine.positions_m[4]
    freq, stiff = lowest_mode_map(robot, [x, x + 0.1], [y], z, tool_axis=machine.tool_axis,
                                  feed=machine.feed_directions()[4], branch=2)
    res = check_toolpath(tp, robot=robot, pose_resolution_deg=0)
    model = robot_modal_model(robot, np.radians(res.joints_deg[4]), min_tip_fraction=0.01)
    assert freq.shape == (1, 2) and np.all(np.isfinite(freq))
    assert freq[0, 0] == pytest.approx(model.natural_frequency_hz.min(), rel=1e-9)


def test_trust_of_a_calibrated_robot_marks_poses_it_does_not_cover(cell):
    """A robot calibrated at poses along one stretch of the path: points far from them are not
    trusted (in_span false, a note), the ones at the calibration poses are."""
    from planner.robot.calibrate import calibrate

    _, robot, tp = cell
    base = check_toolpath(tp, robot=robot, pose_resolution_deg=0)
    assert base.in_span.all() and any("no calibration record" in n for n in base.notes)
    poses = [robot_modal_model(robot, np.radians(base.joints_deg[i])) for i in (0, 1, 2)]
    poses = [replace(m, joints_deg=base.joints_deg[i]) for m, i in zip(poses, (0, 1, 2))]
    cal = calibrate(robot, poses).robot
    # the last two points raised 0.4 m: joints 2 and 3 move far beyond the calibration poses' range
    high = np.array(tp.positions_m)
    high[-2:, 2] += 0.4
    res = check_toolpath(replace(tp, positions_m=high), robot=cal, pose_resolution_deg=0)
    moved = np.abs(res.joints_deg[-1, 1:3] - base.joints_deg[2, 1:3]).max()
    assert moved > 10.0  # the trust rule's margin on joint ranges is 10 deg
    assert res.in_span[0] and not res.in_span[-2:].any()
    assert set(res.counts()) == set(ROBOT_KINDS)  # untrusted is a note, not a violation kind
    assert any("calibration does not cover" in n for n in res.notes)
