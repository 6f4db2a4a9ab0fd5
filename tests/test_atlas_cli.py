"""``robomill atlas`` bad input: exit 2, one line naming what is wrong, nothing written; and the
pieces of the atlas without physics (grid, ranking, chunking, table I/O)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atlas_cases import SETUP, robot_file


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    return robot_file(tmp_path_factory.mktemp("atlas_robot"))


def _run(args, capsys):
    from planner.cli import main

    code = main(["atlas", *map(str, args), "--scheduler", "serial", "--no-progress", "--json"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _one_line(err: str) -> str:
    assert err.count("\n") == 1 and err.startswith("robomill: "), err
    return err


def test_region_the_robot_cannot_reach(robot, tmp_path, capsys):
    out = tmp_path / "out"
    code, stdout, err = _run([robot, SETUP, "-o", out, "--box-m", 6, 6, 0, 7, 7, 1, "--step-m", 0.5], capsys)
    assert code == 2 and stdout == ""
    assert "--box-m" in _one_line(err) and "none of the 27 positions at any of the 12 rotations" in err
    assert not out.exists()


@pytest.mark.parametrize("drop, field", [("limits", "limits.spindle_rpm"), ("axial_depth_m", "limits.axial_depth_m")])
def test_setup_without_limits(robot, tmp_path, capsys, drop, field):
    import yaml

    doc = yaml.safe_load(SETUP.read_text())
    if drop == "limits":
        del doc["limits"]
    else:
        del doc["limits"][drop]
    setup = tmp_path / "setup.yaml"
    setup.write_text(yaml.safe_dump(doc))
    out = tmp_path / "out"
    code, stdout, err = _run([robot, setup, "-o", out, "--step-m", 0.5], capsys)
    assert code == 2 and stdout == ""
    assert str(setup) in _one_line(err) and field in err
    assert not out.exists()


def test_robot_without_joint_stiffness(tmp_path, capsys):
    from robot_helpers import write_robot_file

    bare = write_robot_file(tmp_path, stiffness=False)
    code, _, err = _run([bare, SETUP, "-o", tmp_path / "out", "--step-m", 0.5], capsys)
    assert code == 2 and "stiffness" in _one_line(err)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, match", [
    (["--step-m", "0"], "--step-m"),
    (["--step-m", "1e-4"], "--step-m"),  # 10^13 points: a unit slip
    (["--box-m", "2", "0", "0", "1", "1", "1"], "--box-m"),
    (["--rpm", "6000", "1000"], "--rpm"),
    (["--workers", "0"], "--workers"),
    (["--scheduler", "localhost:8786"], "--scheduler"),
])
def test_bad_options(robot, tmp_path, capsys, args, match):
    from planner.cli import main

    code = main(["atlas", str(robot), str(SETUP), "-o", str(tmp_path / "out"), "--no-progress", *args])
    assert code == 2 and match in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


def test_grid_positions_and_frame():
    from planner.atlas import Region

    r = Region([0, 0, 0.5], [0.2, 0.1, 0.5], 0.1, [0.0], origin_m=[1.0, 2.0, 0.0], rpy_deg=[0, 0, 90])
    assert r.shape == (3, 2, 1)  # a plane: z fixed
    p = r.positions_m()
    assert np.allclose(p[:2], [[0, 0, 0.5], [0, 0.1, 0.5]])  # z fastest, then y
    m = r.to_machine(p)
    assert np.allclose(m[1], [1.0 - 0.1, 2.0, 0.5])  # yaw 90 deg: workpiece y is machine -x
    with pytest.raises(ValueError, match="--rotations-deg"):
        Region([0, 0, 0], [1, 1, 1], 0.1, [])


def test_ranking_rule():
    from planner.atlas.run import best_rows

    nan, inf = math.nan, math.inf
    cols = {"mrr_m3_s": np.array([1.0, 2.0, 2.0, nan, nan, nan, 3.0, 3.0, 3.0]),
            "stability_reserve": np.array([9.0, 1.5, 2.0, nan, nan, nan, inf, inf, 5.0]),
            "min_depth_limit_m": np.array([0.1, 0.1, 0.1, nan, nan, nan, 0.1, 0.3, 0.9])}
    # point 0: MRR ties broken by the reserve; point 1: none; point 2: inf reserves tie, then the limit
    assert best_rows(cols, 3, 3).tolist() == [2, -1, 7]


def test_chunk_sizes():
    from planner.atlas.run import chunk_points

    assert chunk_points(10_000, 12, 500) == 333  # ~1 s of work at 0.25 ms per (position, rotation)
    assert chunk_points(10_000, 12, 1000) == 166
    assert chunk_points(40, 3, 500) == 3  # small runs still give >= 16 tasks
    assert chunk_points(1, 12, 500) == 1


def test_table_round_trip(tmp_path):
    from planner.atlas.io import read_table, write_table

    cols = {"x_m": np.array([0.1, 0.2]), "reachable": np.array([True, False]),
            "active_constraint": np.array(["power", "unreachable"], dtype=object)}
    path = write_table(tmp_path / "t.parquet", cols, metadata={"format": "robomill-atlas/1"})
    back, meta = read_table(path)
    assert meta == {"format": "robomill-atlas/1"}
    assert back["x_m"].tolist() == [0.1, 0.2] and back["reachable"].tolist() == [True, False]
    assert back["active_constraint"].tolist() == ["power", "unreachable"]
    assert [p.name for p in tmp_path.iterdir()] == ["t.parquet"]


def test_demo_section(tmp_path):
    """The demo's atlas section: a report section with two figures and the table written."""
    from planner.atlas import Region, demo_section
    from planner.report import Report

    from atlas_cases import stability_bound_setup

    report = Report("atlas", tmp_path)
    region = Region([1.5, -0.6, 0.6], [2.4, 0.6, 0.6], 0.3, [-90.0, 0.0, 90.0])
    result = demo_section(report, robot_file(tmp_path), stability_bound_setup(), tmp_path, region=region)
    section = report.sections[-1]
    assert len(section.figures) == 2 and all((tmp_path / f).stat().st_size > 5_000 for f, _ in section.figures)
    assert (tmp_path / "atlas.parquet").exists()
    assert report.summary["atlas"]["best"] == result.best and result.best["active_constraint"] == "stability"
    # the best placement is the largest MRR of the table
    assert result.best["mrr_m3_s"] == np.nanmax(result.columns["mrr_m3_s"])


def test_cli_writes_table_figures_and_json(robot, tmp_path, capsys):
    import json

    from planner.atlas.io import read_table

    out = tmp_path / "out"
    code, stdout, err = _run([robot, SETUP, "-o", out, "--box-m", 1.8, -0.3, 0.6, 2.1, 0.3, 0.6, "--step-m", 0.3,
                              "--rotations-deg", 0, 90], capsys)
    assert code == 0, err
    d = json.loads(stdout)
    assert d["points"] == 6 and d["table"] == str(out / "atlas.parquet")
    assert set(d["best"]) >= {"position_m", "rotation_deg", "mrr_m3_s", "spindle_rpm", "axial_depth_m"}
    cols, meta = read_table(d["table"])
    assert cols["mrr_m3_s"].size == 12 and meta["best"] == d["best"]
    assert sorted(p.name for p in out.iterdir()) == ["atlas.parquet", "atlas_mrr.png", "atlas_rotation.png"]
