"""robomill-setup/1 and robomill-toolpath/1: reading, round trips and invalid files (formats.md)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from oma._fields import FileWarning
from oma.cutting import CuttingCoefficients, Material, Tool
from oma.errors import SetupError, ToolpathError
from planner.toolpath import Toolpath
from planner.toolpath_io import read_toolpath, write_toolpath
from stability.setup import Limits
from stability.setup_io import read_setup, write_setup


def edit(path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


# -------------------------------------------------------------------------------------- setup
def test_read_setup_example(valid_setup_file):
    s = read_setup(valid_setup_file)
    assert s.tool == Tool(2, 0.0254, 30.0 * math.pi / 180.0)
    assert s.cut.spindle_rpm is None and s.cut.axial_depth_m is None  # what is being chosen
    assert s.cut.milling == "down" and s.cut.radial_depth_m == 0.006
    np.testing.assert_array_equal(s.cut.tool_axis, [0, 0, 1])
    assert s.material == Material("acetal", CuttingCoefficients(1.2e8, 4.5e7, 2.0e7, 2.0e3, 3.0e3, 5.0e2))
    assert s.limits == Limits(spindle_rpm=(500.0, 12000.0), axial_depth_m=(0.0005, 0.02),
                              feed_per_tooth_m=(0.00005, 0.0006), spindle_power_W=8000.0,
                              spindle_torque_N_m=40.0, max_force_N=1500.0,
                              surface_location_error_m=0.0001, stability_margin=0.8)


def test_setup_round_trip_is_exact(tmp_path, valid_setup_file):
    s = read_setup(valid_setup_file)
    back = read_setup(write_setup(s, tmp_path / "copy.yaml"))
    assert back.tool == s.tool and back.material == s.material and back.limits == s.limits
    assert back.name == s.name
    for f in ("feed_per_tooth_m", "radial_depth_m", "milling", "spindle_rpm", "axial_depth_m", "window_s"):
        assert getattr(back.cut, f) == getattr(s.cut, f)
    np.testing.assert_array_equal(back.cut.feed_direction, s.cut.feed_direction)
    np.testing.assert_array_equal(back.cut.normal_direction, s.cut.normal_direction)


def test_setup_round_trip_with_speed_depth_name_and_odd_helix(tmp_path, valid_setup_file):
    edit(valid_setup_file, "  milling: down", "  milling: down\n  spindle_rpm: 2700.0\n  axial_depth_m: 0.003")
    edit(valid_setup_file, "helix_deg: 30.0", "helix_deg: 37.123456789")
    edit(valid_setup_file, "format: robomill-setup/1", "format: robomill-setup/1\nname: pocket 3")
    s = read_setup(valid_setup_file)
    assert s.cut.spindle_rpm == 2700.0 and s.cut.axial_depth_m == 0.003 and s.name == "pocket 3"
    path = write_setup(s, tmp_path / "copy.yaml")
    assert "helix_deg: 37.123456789\n" in path.read_text() or "helix_deg: 37.123456789}" in path.read_text()
    back = read_setup(path)
    assert back.tool.helix_rad == s.tool.helix_rad  # deg -> rad -> deg -> rad: same double
    assert back.cut.spindle_rpm == 2700.0 and back.name == "pocket 3"


def test_setup_without_limits(tmp_path, valid_setup_file):
    text = valid_setup_file.read_text()
    valid_setup_file.write_text(text[:text.index("limits:")])
    s = read_setup(valid_setup_file)
    assert s.limits == Limits()
    assert "limits" not in write_setup(s, tmp_path / "c.yaml").read_text()


@pytest.mark.parametrize("old, new, field, expected, found", [
    ("spindle_rpm: [500, 12000]", "spindle_rpm: [12000, 500]", "limits.spindle_rpm",
     "[low, high] with low <= high", "a list of 2 [12000.0, 500.0]"),
    ("spindle_rpm: [500, 12000]", "spindle_rpm: [0, 12000]", "limits.spindle_rpm",
     "[low, high] with both > 0", "0.0"),
    ("spindle_rpm: [500, 12000]", "spindle_rpm: 12000", "limits.spindle_rpm",
     "a list of 2 numbers", "12000"),
    ("stability_margin: 0.8", "stability_margin: 1.5", "limits.stability_margin", "a number > 0 and <= 1", "1.5"),
    ("max_force_N: 1500", "max_force_N: -1", "limits.max_force_N", "a number > 0", "-1"),
    ("helix_deg: 30.0", "helix_deg: 95", "tool.helix_deg", "a number >= 0 and < 90", "95"),
    ("milling: down", "milling: both", "cut.milling", "one of up, down", "the text 'both'"),
    ("radial_depth_m: 0.006", "radial_depth_m: -0.006", "cut.radial_depth_m", "a number > 0", "-0.006"),
    ("teeth: 2", "teeth: 2.5", "tool.teeth", "an integer >= 1", "2.5"),
])
def test_setup_bad_values(valid_setup_file, old, new, field, expected, found):
    edit(valid_setup_file, old, new)
    with pytest.raises(SetupError, match=rf"setup\.yaml: {re.escape(field)}: expected {re.escape(expected)}, "
                                         rf"found {re.escape(found)}$"):
        read_setup(valid_setup_file)


def test_setup_unknown_key_in_limits(valid_setup_file):
    edit(valid_setup_file, "  max_force_N: 1500", "  max_force_n: 1500")
    with pytest.raises(SetupError, match=r"limits\.max_force_n: expected one of the keys spindle_rpm, .* "
                                         r"or an x_ extension, found the unknown key 'max_force_n'"):
        read_setup(valid_setup_file)


def test_setup_needs_cutting_coefficients(valid_setup_file):
    text = valid_setup_file.read_text()
    start, end = text.index("material:"), text.index("limits:")
    valid_setup_file.write_text(text[:start] + "material: {name: acetal}\n" + text[end:])
    with pytest.raises(SetupError, match=r"material\.cutting_coefficients: expected a mapping, found nothing"):
        read_setup(valid_setup_file)


def test_setup_zero_feed_direction(valid_setup_file):
    edit(valid_setup_file, "feed_direction: [0, 1, 0]", "feed_direction: [0, 0, 0]")
    with pytest.raises(SetupError, match=r"cut\.feed_direction: expected a non-zero direction vector"):
        read_setup(valid_setup_file)


def test_setup_not_perpendicular(valid_setup_file):
    edit(valid_setup_file, "normal_direction: [-1, 0, 0]", "normal_direction: [-0.7071067811865476, 0.7071067811865476, 0]")
    with pytest.raises(SetupError, match=r"cut\.normal_direction: expected a direction perpendicular to "
                                         r"feed_direction \(\|f\.n\| <= 0\.001\), found f\.n = 0\.707107"):
        read_setup(valid_setup_file)


def test_setup_python_tag(valid_setup_file):
    edit(valid_setup_file, "tool: {teeth: 2,", "tool: !!python/name:os.getcwd {teeth: 2,")
    with pytest.raises(SetupError, match=r"setup\.yaml: line 2: expected plain YAML without language-specific "
                                         r"tags, found the tag tag:yaml\.org,2002:python/name:os\.getcwd \(not allowed\)"):
        read_setup(valid_setup_file)


def test_setup_wrong_format(valid_setup_file):
    edit(valid_setup_file, "format: robomill-setup/1", "format: robomill-setup")
    with pytest.raises(SetupError, match=r"format: expected 'robomill-setup/1', found the text 'robomill-setup'"):
        read_setup(valid_setup_file)


# ----------------------------------------------------------------------------------- toolpath
def test_read_toolpath_example(valid_toolpath_file):
    tp = read_toolpath(valid_toolpath_file)
    assert tp.n_points == 4 and tp.points_file == "toolpath.csv"
    np.testing.assert_array_equal(tp.positions_m[1], [1.2, 0.025, 0.5])
    np.testing.assert_array_equal(tp.joints_deg[0], [88.44, -13.62, 72.42, 180.90, 59.55, -0.67])
    np.testing.assert_array_equal(tp.spindle_rpm, [2700, 2700, 2700, 3000])
    np.testing.assert_array_equal(tp.milling, ["down", "down", "down", "up"])
    np.testing.assert_array_equal(tp.tool_axis, [0, 0, 1])
    assert tp.limits == Limits(spindle_rpm=(500.0, 12000.0), max_force_N=1500.0)
    assert tp.material.cutting_coefficients == CuttingCoefficients(1.2e8, 4.5e7)
    # feed along +Y, +Y, then -X (the last point keeps the last segment's direction); n = a x f
    f = tp.feed_directions()
    np.testing.assert_allclose(f, [[0, 1, 0], [0, 1, 0], [-1, 0, 0], [-1, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(tp.normal_directions(), [[-1, 0, 0], [-1, 0, 0], [0, -1, 0], [0, -1, 0]],
                               atol=1e-15)


def assert_same_toolpath(a: Toolpath, b: Toolpath) -> None:
    for name in ("tool_axis", "positions_m", "joints_deg", "spindle_rpm", "feed_per_tooth_m",
                 "radial_depth_m", "axial_depth_m", "milling"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.tool == b.tool and a.material == b.material and a.limits == b.limits
    assert a.points_file == b.points_file


def test_toolpath_round_trip_is_exact(tmp_path, valid_toolpath_file):
    tp = read_toolpath(valid_toolpath_file)
    out = tmp_path / "out"
    out.mkdir()
    back = read_toolpath(write_toolpath(tp, out / "path.yaml"))
    assert_same_toolpath(tp, back)


def test_toolpath_round_trip_with_per_point_axis(tmp_path):
    rng = np.random.default_rng(11)
    n = 50
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    tp = Toolpath(
        tool=Tool(4, 0.016, math.radians(40.0)), material=Material(None, CuttingCoefficients(6e8, 2e8)),
        tool_axis=axis, positions_m=np.cumsum(rng.uniform(0.001, 0.01, size=(n, 3)), axis=0),
        joints_deg=rng.uniform(-170, 170, size=(n, 6)), spindle_rpm=rng.uniform(3000, 9000, n),
        feed_per_tooth_m=rng.uniform(5e-5, 2e-4, n), radial_depth_m=rng.uniform(1e-3, 8e-3, n),
        axial_depth_m=rng.uniform(1e-3, 5e-3, n), milling=rng.choice(["up", "down"], n),
        points_file="pts.csv")
    path = write_toolpath(tp, tmp_path / "tp.yaml")
    assert "tool_axis" not in path.read_text()
    assert (tmp_path / "pts.csv").read_text().splitlines()[0].endswith("tool_axis_x,tool_axis_y,tool_axis_z")
    assert_same_toolpath(tp, read_toolpath(path))


def _edit_points(path, fn):
    csv = path.parent / "toolpath.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(fn(lines)) + "\n")


def test_toolpath_milling_not_up_or_down(valid_toolpath_file):
    _edit_points(valid_toolpath_file, lambda ls: ls[:3] + [ls[3].replace(",down", ",climb")] + ls[4:])
    with pytest.raises(ToolpathError, match=r"toolpath\.csv: row 3, column milling: expected up or down, "
                                            r"found the text 'climb'"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_missing_column(valid_toolpath_file):
    _edit_points(valid_toolpath_file, lambda ls: [line.rsplit(",", 1)[0] for line in ls])
    with pytest.raises(ToolpathError, match=r"toolpath\.csv: column milling: expected a column milling, found no such column"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_unknown_column(valid_toolpath_file):
    _edit_points(valid_toolpath_file, lambda ls: [ls[0] + ",coolant"] + [l + ",on" for l in ls[1:]])
    with pytest.raises(ToolpathError, match=r"toolpath\.csv: column coolant: expected only the columns x_m,.*"
                                            r"found the unknown column 'coolant'"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_extension_columns_are_ignored(valid_toolpath_file):
    """formats.md: readers ignore keys that start with x_ (user extensions), text or numbers."""
    plain = read_toolpath(valid_toolpath_file)
    _edit_points(valid_toolpath_file, lambda ls: [ls[0] + ",x_operator,x_pass"] + [l + ",Jan,3" for l in ls[1:]])
    extended = read_toolpath(valid_toolpath_file)
    np.testing.assert_array_equal(extended.positions_m, plain.positions_m)
    np.testing.assert_array_equal(extended.axial_depth_m, plain.axial_depth_m)


@pytest.mark.parametrize("column, value, expected", [
    ("spindle_rpm", "0", "a number > 0"),
    ("axial_depth_m", "-0.001", "a number > 0"),
    ("feed_per_tooth_m", "nan", "a finite number"),
    ("q3_deg", "inf", "a finite number"),
])
def test_toolpath_bad_point_values(valid_toolpath_file, column, value, expected):
    header = valid_toolpath_file.parent.joinpath("toolpath.csv").read_text().splitlines()[0].split(",")
    j = header.index(column)

    def change(lines):
        cells = lines[2].split(",")
        cells[j] = value
        return lines[:2] + [",".join(cells)] + lines[3:]

    _edit_points(valid_toolpath_file, change)
    with pytest.raises(ToolpathError, match=rf"toolpath\.csv: row 2, column {column}: expected {expected}, found"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_text_in_number_column(valid_toolpath_file):
    _edit_points(valid_toolpath_file, lambda ls: ls[:1] + [ls[1].replace("2700", "fast", 1)] + ls[2:])
    with pytest.raises(ToolpathError, match=r"toolpath\.csv: line 2, column spindle_rpm: expected a number, found the text 'fast'"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_coincident_points(valid_toolpath_file):
    _edit_points(valid_toolpath_file, lambda ls: ls[:2] + [ls[1]] + ls[3:])
    with pytest.raises(ToolpathError, match=r"toolpath\.csv: row 2: expected a point away from the one before it"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_single_point(valid_toolpath_file):
    _edit_points(valid_toolpath_file, lambda ls: ls[:2])
    with pytest.raises(ToolpathError, match=r"toolpath\.csv: rows: expected at least two points .*found 1 point$"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_zero_tool_axis(valid_toolpath_file):
    edit(valid_toolpath_file, "tool_axis: [0, 0, 1]", "tool_axis: [0, 0, 0]")
    with pytest.raises(ToolpathError, match=r"toolpath\.yaml: tool_axis: expected a non-zero direction vector"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_non_unit_axis_warns(valid_toolpath_file):
    edit(valid_toolpath_file, "tool_axis: [0, 0, 1]", "tool_axis: [0, 0, 10]")
    with pytest.warns(FileWarning, match=r"tool_axis: direction has length 10") as record:
        tp = read_toolpath(valid_toolpath_file)
    assert record[0].filename == __file__  # attributed to the caller, not to robomill's helpers
    np.testing.assert_array_equal(tp.tool_axis, [0, 0, 1])


def test_toolpath_axis_both_in_yaml_and_columns(valid_toolpath_file):
    _edit_points(valid_toolpath_file, lambda ls: [ls[0] + ",tool_axis_x,tool_axis_y,tool_axis_z"]
                 + [l + ",0,0,1" for l in ls[1:]])
    with pytest.raises(ToolpathError, match=r"toolpath\.yaml: tool_axis: expected the tool axis either in the "
                                            r"YAML or as columns of the points file, not both"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_without_any_axis(valid_toolpath_file):
    edit(valid_toolpath_file, "tool_axis: [0, 0, 1]\n", "")
    with pytest.raises(ToolpathError, match=r"toolpath\.yaml: tool_axis: expected a tool axis .*found nothing"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_missing_points_file(valid_toolpath_file):
    (valid_toolpath_file.parent / "toolpath.csv").unlink()
    with pytest.raises(ToolpathError, match=r"toolpath\.csv: file: expected the points file named in points, found no such file"):
        read_toolpath(valid_toolpath_file)


def test_toolpath_unknown_key_and_tag(valid_toolpath_file):
    edit(valid_toolpath_file, "points: toolpath.csv", "points: toolpath.csv\npoint_spacing_m: 0.001")
    with pytest.raises(ToolpathError, match=r"toolpath\.yaml: point_spacing_m: expected one of the keys"):
        read_toolpath(valid_toolpath_file)
    edit(valid_toolpath_file, "point_spacing_m: 0.001", "x_point_spacing_m: 0.001")
    assert read_toolpath(valid_toolpath_file).n_points == 4
    edit(valid_toolpath_file, "points: toolpath.csv", "points: !!python/object/apply:os.getcwd []")
    with pytest.raises(ToolpathError, match=r"line 6: expected plain YAML without language-specific tags"):
        read_toolpath(valid_toolpath_file)
