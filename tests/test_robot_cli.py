"""``robomill robot calibrate``, ``robomill robot model`` and ``--robot ... --joints-deg ...`` on
lobes/predict, in process: exit codes, one-line errors, nothing half-written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from oma.modal_io import read_modal_model, write_modal_model
from planner.cli import main
from planner.robot import read_robot
from robot_helpers import identified_models, region_poses, urdf_path, write_robot_file

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "kr500_acetal"
POSE = ["0", "-60", "100", "0", "50", "0"]


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    d = tmp_path_factory.mktemp("cell")
    truth = read_robot(write_robot_file(d, name="truth.yaml"))
    write_robot_file(d, stiffness=False, name="bare.yaml")
    rng = np.random.default_rng(21)
    paths = []
    for i, m in enumerate(identified_models(truth, region_poses(truth, 4, rng), rng)):
        paths.append(d / f"pose{i}.yaml")
        write_modal_model(m, paths[-1])
    return d, paths


@pytest.fixture(scope="module")
def calibrated(cell):
    d, paths = cell
    out = d / "out" / "calibrated.yaml"
    code = main(["robot", "calibrate", str(d / "bare.yaml"), "--models", *map(str, paths), "-o", str(out),
                 "--correction", "off", "--json"])
    assert code == 0
    return out


def test_calibrate_writes_the_robot_and_reports_the_cli_keys(cell, calibrated, capsys):
    d, paths = cell
    out = d / "cal2.yaml"
    code, stdout, err = _run(capsys, "robot", "calibrate", d / "bare.yaml", "--models", *paths, "-o", out, "--json")
    assert code == 0, err
    payload = json.loads(stdout)
    assert {"robot", "joint_stiffness_N_m_rad", "identifiable", "fit_error", "leave_one_out", "next_pose_deg",
            "warnings"} <= set(payload)
    assert len(payload["joint_stiffness_N_m_rad"]) == 6 and len(payload["fit_error"]) == 4
    robot = read_robot(out)
    np.testing.assert_allclose(robot.joint_stiffness_N_m_rad, payload["joint_stiffness_N_m_rad"])
    # formats.md: paths in a robot file are relative to it (they were relative to the working directory)
    assert robot.calibration["models"] == [p.name for p in paths]
    in_sub = read_robot(calibrated_path(d))
    assert [(d / "out" / m).resolve() for m in in_sub.calibration["models"]] == [p.resolve() for p in paths]
    # a model given twice is one pose, not two: exit 2 naming it (it made joints "identifiable")
    code, _, err = _run(capsys, "robot", "calibrate", d / "bare.yaml", "--models", *paths, paths[0], "-o",
                        d / "twice.yaml")
    assert code == 2 and f"{paths[0]}: pose.joints_deg: expected a pose apart from {paths[0]}'s" in err
    assert not (d / "twice.yaml").exists()


def calibrated_path(d):
    return d / "out" / "calibrated.yaml"


def test_model_at_a_pose_and_its_trust(calibrated, tmp_path, capsys):
    out = tmp_path / "m.yaml"
    code, stdout, err = _run(capsys, "robot", "model", calibrated, "--joints-deg", *POSE, "-o", out, "--json")
    assert code == 0, err
    payload = json.loads(stdout)
    assert payload["trusted"] is True and payload["model"]["pose"]["joints_deg"] == [0, -60, 100, 0, 50, 0]
    assert read_modal_model(out).n_modes == len(payload["model"]["modes"])
    far = ["0", "-125", "100", "0", "50", "0"]
    code, stdout, err = _run(capsys, "robot", "model", calibrated, "--joints-deg", *far, "--json")
    assert code == 0 and json.loads(stdout)["trusted"] is False
    assert "joint(s) 2" in json.loads(stdout)["warnings"][0]


def test_robot_option_on_lobes_and_predict_equals_the_written_model(calibrated, tmp_path, capsys):
    model = tmp_path / "m.yaml"
    assert main(["robot", "model", str(calibrated), "--joints-deg", *POSE, "-o", str(model)]) == 0
    capsys.readouterr()
    setup = EXAMPLE / "setup.yaml"
    common = ["--rpm", "1000", "3000", "--json"]
    _, by_model, _ = _run(capsys, "lobes", setup, "--model", model, *common)
    code, by_robot, err = _run(capsys, "lobes", setup, "--robot", calibrated, "--joints-deg", *POSE, *common)
    assert code == 0, err
    assert json.loads(by_robot) == json.loads(by_model)
    code, out, err = _run(capsys, "predict", setup, "--robot", calibrated, "--joints-deg", *POSE, "--rpm", "2000",
                          "--depth", "0.001", "--json")
    assert code == 0, err
    assert "stable" in json.loads(out) and "trusted: false" not in err
    far = ["0", "-125", "100", "0", "50", "0"]
    code, out, err = _run(capsys, "predict", setup, "--robot", calibrated, "--joints-deg", *far, "--rpm", "2000",
                          "--depth", "0.001", "--json")
    assert code == 0 and "stable" in json.loads(out)  # answered, with a warning on stderr
    assert "pose outside the calibrated region" in err and "(trusted: false)" in err


@pytest.mark.parametrize("case", ["no_pose", "pose_outside", "bad_urdf", "no_stiffness", "outside_limits",
                                  "model_and_robot", "joints_no_robot"])
def test_bad_input_exit_2_one_line_nothing_written(case, cell, calibrated, tmp_path, capsys):
    d, paths = cell
    out = tmp_path / "out.yaml"
    if case == "no_pose":
        bad = tmp_path / "nopose.yaml"
        write_modal_model(read_modal_model(paths[0]).with_modes(joints_deg=None), bad)
        argv = ["robot", "calibrate", d / "bare.yaml", "--models", paths[1], bad, "-o", out]
        expected = f"{bad}: pose.joints_deg: expected the pose"
    elif case == "pose_outside":
        bad = tmp_path / "outside.yaml"
        model = read_modal_model(paths[0])
        write_modal_model(model.with_modes(joints_deg=[0, 20, 90, 0, 45, 0]), bad)
        argv = ["robot", "calibrate", d / "bare.yaml", "--models", paths[1], bad, "-o", out]
        expected = f"{bad}: pose.joints_deg: expected joint 2 (joint_2) within [-130, 5] deg, found 20 deg"
    elif case == "bad_urdf":
        urdf = tmp_path / "bad.urdf"
        urdf.write_text(urdf_path().read_text().replace('<joint name="joint_3" type="revolute">',
                                                        '<joint name="joint_3" type="continuous">'))
        robot_file = tmp_path / "robot.yaml"
        robot_file.write_text((d / "bare.yaml").read_text().replace(str(urdf_path()), str(urdf)))
        argv = ["robot", "calibrate", robot_file, "--models", *paths, "-o", out]
        expected = f"{urdf}: joint[@name='joint_3']: expected a revolute (or fixed) joint, found type 'continuous'"
    elif case == "no_stiffness":
        argv = ["robot", "model", d / "bare.yaml", "--joints-deg", *POSE, "-o", out]
        expected = "bare.yaml: joints.stiffness_N_m_rad: expected joint stiffness"
    elif case == "outside_limits":
        argv = ["robot", "model", calibrated, "--joints-deg", "0", "-60", "100", "0", "150", "0", "-o", out]
        expected = "--joints-deg: expected joint 5 (joint_5) within [-120, 120] deg, found 150 deg"
    elif case == "model_and_robot":
        argv = ["lobes", EXAMPLE / "setup.yaml", "--model", paths[0], "--robot", calibrated, "--joints-deg", *POSE,
                "-o", out.with_suffix(".png")]
        expected = "--robot: expected either --model or --robot, not both"
    else:
        argv = ["predict", EXAMPLE / "setup.yaml", "--model", paths[0], "--joints-deg", *POSE, "--rpm", "2000",
                "--depth", "0.001"]
        expected = "--joints-deg: expected used with --robot only"
    code, stdout, err = _run(capsys, *argv, "--json")
    assert code == 2
    assert stdout == "" and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and expected in err, err
    assert not out.exists()


def test_an_overdamped_robot_mode_is_written_read_back_and_planned_with(tmp_path, capsys):
    """Large joint damping (N m s/rad) makes some joint-space modes overdamped: ``robot model`` writes
    them as they are (formats.md's G(w) holds for any damping), the reader takes them back with a
    warning (it rejected them before, so ``plan --model`` on ``robot model``'s own output was exit 2),
    and the file's receptance is the robot model's."""
    from planner.diagnosis.response import mode_filter
    from planner.robot.dynamics import robot_modal_model

    path = write_robot_file(tmp_path)
    text = path.read_text().replace("damping_ratio: [0.05, 0.05, 0.05, 0.05, 0.05, 0.05]",
                                    "damping_N_m_s_rad: [20000, 20000, 20000, 5000, 5000, 5000]")
    path.write_text(text)
    robot = read_robot(path)
    q = np.radians([float(v) for v in POSE])
    model = robot_modal_model(robot, q)
    assert model.damping_ratio.max() > 1.0  # the case: at least one overdamped mode
    out = tmp_path / "model.yaml"
    assert main(["robot", "model", str(path), "--joints-deg", *POSE, "-o", str(out)]) == 0
    with pytest.warns(UserWarning, match="an overdamped mode"):
        back = read_modal_model(out)
    f = np.array([2.0, 8.0, 20.0])
    np.testing.assert_allclose(back.receptance(f), model.receptance(f), rtol=1e-9)
    capsys.readouterr()
    assert main(["plan", str(EXAMPLE / "setup.yaml"), "--model", str(out), "--json"]) in (0, 1)
    assert json.loads(capsys.readouterr().out)["success"] in (True, False)
    # diagnose's sampled mode filter takes an overdamped mode: unit static gain, and its frequency
    # response at 5 Hz within 1 % of the continuous w^2 / (w^2 - W^2 + 2 i zeta w W)
    fn, zeta, fs = 50.0, 1.78, 1000.0
    b, a = (v[0] for v in mode_filter(np.array([fn]), np.array([zeta]), fs))
    assert b.sum() / a.sum() == pytest.approx(1.0, rel=1e-9)
    zz = np.exp(-2j * np.pi * 5.0 / fs * np.arange(3))
    w, ww = 2 * np.pi * fn, 2 * np.pi * 5.0
    assert abs((b @ zz) / (a @ zz) / (w**2 / (w**2 - ww**2 + 2j * zeta * w * ww)) - 1) < 0.01
