"""``robomill posture``: the rotation about the tool axis along a path.

The reference is a brute-force sweep: the path checked at every constant rotation of a 5-deg grid
(every branch, as :func:`planner.check.check_toolpath` picks it), its best smallest margin; the
posture choice (10-deg grid, varying rotation, refinement) must come within 2 % of it or beat it.
The spindle sits 0.25 m off the flange axis, so the rotation moves the whole arm (with an inline
spindle only joint 6 would turn and the margin would not change).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from robot_helpers import JOINTS_YAML, ROBOT_YAML, TOOLPATH_HEADER, toolpath_yaml, urdf_path  # noqa: E402

from planner.check import check_toolpath  # noqa: E402
from planner.cli import main  # noqa: E402
from planner.robot import forward_kinematics, read_robot, tool_axis  # noqa: E402
from planner.robot.posture import choose_posture, constant_rotation_margins  # noqa: E402
from planner.toolpath_io import read_toolpath  # noqa: E402

# the workpiece frame and limits of the toolpath files of these tests
PATH_OPTIONS = dict(origin_m=[1.2, 0.0, 0.4], rpy_deg=[0, 0, 0], limits="{stability_margin: 0.8}")


def offset_robot(directory, *, stiffness=True, name="robot.yaml") -> Path:
    text = ROBOT_YAML.format(urdf=urdf_path(), joints=JOINTS_YAML if stiffness else "")
    text = text.replace("tip_m: [0.0, 0.0, 0.45]", "tip_m: [0.0, 0.25, 0.40]")
    text = text.replace("center_of_mass_m: [0.0, 0.0, 0.20]", "center_of_mass_m: [0.0, 0.12, 0.20]")
    path = Path(directory) / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    d = tmp_path_factory.mktemp("posture")
    offset_robot(d)
    (d / "path.yaml").write_text(toolpath_yaml("robot.yaml", **PATH_OPTIONS))
    # an L-shaped path: along +y, then along +x (the feed turns, and the reference with it)
    y = np.linspace(-0.2, 0.1, 12)
    x = np.linspace(0.0, 0.15, 7)[1:]
    pts = [(0.0, float(v)) for v in y] + [(float(u), 0.1) for u in x]
    rows = [f"{px!r},{py!r},0.0,2700,0.0005,0.006,0.012,down" for px, py in pts]
    (d / "path.csv").write_text(TOOLPATH_HEADER + "\n" + "\n".join(rows) + "\n")
    return d, read_robot(d / "robot.yaml"), read_toolpath(d / "path.yaml")


@pytest.fixture(scope="module")
def chosen(cell):
    _, robot, tp = cell
    return choose_posture(robot, tp)


def test_posture_within_two_percent_of_the_best_constant_rotation(cell, chosen):
    _, robot, tp = cell
    sweep = constant_rotation_margins(robot, tp, np.arange(-180.0, 180.0, 5.0))
    best = float(sweep.max())
    assert np.isfinite(best) and best > 0
    # the rotation matters on this cell: the best constant rotation is well above the worst feasible one
    assert best > 1.3 * sweep[np.isfinite(sweep)].min()
    assert chosen.min_margin_after >= 0.98 * best
    assert chosen.min_margin_after >= chosen.min_margin_before
    assert chosen.unreachable == ()


def test_posture_path_is_smooth_one_branch_and_reproduces_the_targets(cell, chosen):
    _, robot, tp = cell
    out = chosen.toolpath
    q = np.radians(out.joints_deg)
    machine = tp.in_machine_frame()
    np.testing.assert_allclose(forward_kinematics(robot, q)[:, :3, 3], machine.positions_m, atol=1e-9)
    np.testing.assert_allclose(tool_axis(robot, q), np.broadcast_to(machine.tool_axis, q.shape[:1] + (3,)),
                               atol=1e-9)
    # the flange angle from the fixed reference moves at most one grid step between stations (here
    # every point is a station), also at the corner where the feed turns by 90 deg
    assert np.all(np.abs(np.diff(chosen.flange_angle_deg)) <= 10.0 + 1e-9)
    # no configuration flip: the joints move continuously
    assert np.max(np.abs(np.diff(out.joints_deg, axis=0))) < 15.0
    np.testing.assert_array_equal(out.tool_rotation_deg, chosen.rotation_deg)
    # the margins after are those of an independent check of the written joints
    again = check_toolpath(out, robot=robot)
    np.testing.assert_allclose(again.stability_margin, chosen.margin_after, rtol=1e-12)


def test_margin_before_is_the_check_at_rotation_zero(cell, chosen):
    _, robot, tp = cell
    before = check_toolpath(tp, robot=robot)
    np.testing.assert_allclose(chosen.margin_before, before.stability_margin, rtol=1e-12)


def test_cli_posture(cell, tmp_path, capsys):
    import json

    d, _, _ = cell
    out = tmp_path / "o" / "posed.yaml"
    out.parent.mkdir()
    code = main(["posture", str(d / "path.yaml"), "--stations", "6", "-o", str(out), "--json"])
    payload = json.loads(capsys.readouterr().out)
    assert code == 0 and set(payload) >= {"points", "min_margin_before", "min_margin_after", "unreachable",
                                          "toolpath"}
    back = read_toolpath(out)
    assert back.has_joints and Path(back.robot_file).resolve() == (d / "robot.yaml").resolve()
    # a robot without joint stiffness: exit 2, one line, nothing written
    bare = offset_robot(tmp_path, stiffness=False, name="bare.yaml")
    out2 = tmp_path / "o" / "never.yaml"
    assert main(["posture", str(d / "path.yaml"), "--robot", str(bare), "-o", str(out2)]) == 2
    err = capsys.readouterr().err
    assert "joints.stiffness_N_m_rad: expected joint stiffness" in err and len(err.strip().splitlines()) == 1
    assert not out2.exists() and sorted(p.name for p in out.parent.iterdir()) == ["posed.csv", "posed.yaml"]
    assert main(["posture", str(d / "path.yaml"), "--rotations", "1"]) == 2
    assert "--rotations: expected an integer >= 2" in capsys.readouterr().err


def test_cli_posture_beside_its_input_leaves_the_input_alone(cell, tmp_path, capsys):
    """The output names its own points file: written beside the input it used to take the input's
    points file name and overwrite it (the YAML of both then named one CSV with the new joints)."""
    import shutil

    d, _, _ = cell
    work = tmp_path / "w"
    shutil.copytree(d, work)
    before = {p.name: p.read_bytes() for p in work.iterdir()}
    assert main(["posture", str(work / "path.yaml"), "--stations", "6", "-o", str(work / "path_posed.yaml")]) == 0
    assert all((work / name).read_bytes() == data for name, data in before.items())
    assert read_toolpath(work / "path_posed.yaml").has_joints and (work / "path_posed.csv").exists()
    assert main(["posture", str(work / "path.yaml"), "-o", str(work / "path.yaml")]) == 2
    assert "-o: expected a file other than the input toolpath" in capsys.readouterr().err


def test_unreachable_points_are_reported(cell, tmp_path, capsys):
    d, robot, tp = cell
    far = np.array(tp.positions_m)
    far[-1] = [5.0, 0.1, 0.0]
    result = choose_posture(robot, replace(tp, positions_m=far), stations=None, n_rotations=12)
    assert result.unreachable == (tp.n_points - 1,)
    assert np.all(np.isnan(result.toolpath.joints_deg[-1])) and np.isnan(result.margin_after[-1])
    with pytest.raises(ValueError, match="n_rotations must be at least 2"):
        choose_posture(robot, tp, n_rotations=1)


def test_points_the_calibration_does_not_cover_are_named(cell):
    """A margin at a pose the calibration does not cover is an extrapolation: the posture's notes
    count such points of the chosen posture, the same count as an independent check of the written
    joints (the posture said nothing while moving a path out of the covered region)."""
    from planner.robot.calibrate import calibrate
    from robot_helpers import identified_models, region_poses

    d, robot, tp = cell
    rng = np.random.default_rng(3)
    poses = region_poses(robot, 4, rng, scale=0.2)  # a small region: most of the path lies outside it
    cal = calibrate(robot, identified_models(robot, poses, rng), correction=False).robot
    result = choose_posture(cal, tp, stations=6, n_rotations=12)
    again = check_toolpath(result.toolpath, robot=cal)
    outside = int(np.sum(~np.asarray(again.in_span) & np.isfinite(result.margin_after)))
    named = [n for n in result.notes if "calibration does not cover" in n]
    assert outside > 0 and len(named) == 1 and named[0].startswith(f"{outside} point(s)")
