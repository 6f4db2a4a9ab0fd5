"""robomill-record/1: reading (SI conversion), writing (file units back), round trips, and every
way a record can be invalid (formats.md). Error tests check the message names the file, the
field, what was expected and what was found."""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest

from oma._fields import DEG_TO_RAD, STANDARD_GRAVITY_M_S2, FileWarning
from oma.cutting import Cut, CuttingCoefficients, Material, Sensors, Tool
from oma.errors import InputError, RecordError
from oma.io import atomic_write
from oma.record import Channel, Record
from oma.record_io import read_record, write_record


# ----------------------------------------------------------------------------------- helpers
def edit_yaml(directory, old: str, new: str) -> None:
    """Replace one piece of record.yaml (which must be there) to damage the example."""
    path = directory / "record.yaml"
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


def edit_csv(directory, fn) -> None:
    """Apply ``fn(list_of_lines) -> list_of_lines`` to signals.csv."""
    path = directory / "signals.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(fn(lines)) + "\n")


def csv_numbers(path) -> tuple[list[str], np.ndarray]:
    """Header and numbers of a CSV, parsed independently of robomill."""
    lines = path.read_text().splitlines()
    return lines[0].split(","), np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])


def message_parts(exc: InputError, file_part: str, field: str):
    """The message has the form ``file: field: expected ..., found ...``."""
    text = str(exc)
    assert file_part in exc.file
    assert exc.field == field, (exc.field, field)
    assert text.startswith(f"{exc.file}: {field}: expected "), text
    assert ", found " in text


def simple_record(*, units=("N", "m", "m/s2"), n=500, seed=1, with_time=True) -> Record:
    """An in-memory record with random SI signals (force, displacement, acceleration on X)."""
    rng = np.random.default_rng(seed)
    data = np.vstack([rng.normal(scale=100.0, size=n), rng.normal(scale=1e-5, size=n),
                      rng.normal(scale=3.0, size=n)])
    channels = (Channel("Fx", "force", "X", units[0]), Channel("x", "displacement", "X", units[1]),
                Channel("ax", "acceleration", "X", units[2]))
    fs = 2000.0
    return Record(
        sample_rate_hz=fs, channels=channels, data=data,
        tool=Tool(teeth=3, diameter_m=0.012, helix_rad=math.radians(35.0)),
        cut=Cut(feed_per_tooth_m=1e-4, radial_depth_m=0.003, milling="up",
                feed_direction=[0.6, 0.8, 0.0], normal_direction=[0.8, -0.6, 0.0],
                spindle_rpm=9000.0, axial_depth_m=0.002, window_s=(0.01, 0.2)),
        material=Material("Al7075", CuttingCoefficients(7.0e8, 2.1e8, 1.0e8, 1.5e4, 2.0e4, 1.0e3)),
        sensors=Sensors(force_noise_variance_N2=0.5), name="memory", robot_model="ABB IRB 6660",
        joints_deg=[1.0, 2.5, -3.0, 4.0, 5.0, 6.0], time_s=np.arange(n) / fs if with_time else None,
    )


def assert_same_record(a: Record, b: Record) -> None:
    np.testing.assert_array_equal(a.data, b.data)
    assert a.channels == b.channels
    assert a.sample_rate_hz == b.sample_rate_hz
    if a.time_s is None:
        assert b.time_s is None
    else:
        np.testing.assert_array_equal(a.time_s, b.time_s)
    assert a.tool == b.tool
    np.testing.assert_array_equal(a.cut.feed_direction, b.cut.feed_direction)
    np.testing.assert_array_equal(a.cut.normal_direction, b.cut.normal_direction)
    for f in ("feed_per_tooth_m", "radial_depth_m", "milling", "spindle_rpm", "axial_depth_m",
              "window_s"):
        assert getattr(a.cut, f) == getattr(b.cut, f), f
    assert a.material == b.material
    assert a.sensors == b.sensors
    assert (a.name, a.robot_model) == (b.name, b.robot_model)
    np.testing.assert_array_equal(a.joints_deg, b.joints_deg)


# ----------------------------------------------------------------------------------- reading
def test_read_example_converts_to_si(valid_record_dir, example_record_signals):
    rec = read_record(valid_record_dir)
    cols = example_record_signals
    assert [c.name for c in rec.channels] == ["Fx", "Fy", "Fz", "x", "y", "z"]
    assert [c.unit for c in rec.channels] == ["N"] * 3 + ["um"] * 3
    # um -> m is one correctly rounded division by the exact 1e6
    np.testing.assert_array_equal(rec.displacement, np.vstack([cols[c] for c in "xyz"]) / 1e6)
    np.testing.assert_array_equal(rec.force, np.vstack([cols[c] for c in ("Fx", "Fy", "Fz")]))
    np.testing.assert_array_equal(rec.time_s, cols["t"])
    assert rec.sample_rate_hz == 1000.0 and rec.n_samples == 1000
    assert rec.tool.teeth == 2 and rec.tool.diameter_m == 0.0254
    assert rec.tool.helix_rad == pytest.approx(math.pi / 6, rel=4e-16)  # 30 deg, to rounding
    assert rec.cut.spindle_rpm == 2700.0 and rec.cut.milling == "down"
    np.testing.assert_array_equal(rec.cut.tool_axis, [0.0, 0.0, 1.0])  # a = f x n = +Z
    assert rec.cut.window_s == (0.2, 0.9)
    # 1.2e8 (no sign in the exponent) is a number, not the text PyYAML's YAML 1.1 would make it
    assert rec.material.cutting_coefficients == CuttingCoefficients(1.2e8, 4.5e7, 2.0e7, 2.0e3, 3.0e3, 5.0e2)
    assert rec.sensors == Sensors(0.56, 0.75, 1.5e-5)
    assert rec.robot_model == "KUKA KR500-3"
    np.testing.assert_array_equal(rec.joints_deg, [88.44, -13.62, 72.42, 180.90, 59.55, -0.67])
    assert rec.signal_file == "signals.csv"


def test_read_accepts_record_yaml_path_and_npz(valid_record_dir, valid_record_npz_dir):
    a = read_record(valid_record_dir / "record.yaml")
    b = read_record(valid_record_npz_dir)
    assert b.signal_file == "signals.npz"
    np.testing.assert_array_equal(a.data, b.data)
    np.testing.assert_array_equal(a.time_s, b.time_s)


def test_units_g_and_um_read_as_si_and_write_back_in_file_units(tmp_path, valid_record_dir):
    edit_yaml(valid_record_dir, "z:  {quantity: displacement, axis: Z, unit: um}",
              "z:  {quantity: acceleration, axis: Z, unit: g}")
    edit_yaml(valid_record_dir, "y:  {quantity: displacement, axis: Y, unit: um}",
              "y:  {quantity: velocity, axis: Y, unit: mm/s}")
    header, original = csv_numbers(valid_record_dir / "signals.csv")
    rec = read_record(valid_record_dir)
    np.testing.assert_array_equal(rec.signal("acceleration", "Z"), original[:, 6] * STANDARD_GRAVITY_M_S2)
    np.testing.assert_array_equal(rec.signal("displacement", "X"), original[:, 4] / 1e6)
    np.testing.assert_array_equal(rec.signal("velocity", "Y"), original[:, 5] / 1e3)
    out = write_record(rec, tmp_path / "copy")
    header2, written = csv_numbers(out / "signals.csv")
    assert header2 == header
    np.testing.assert_array_equal(written, original)  # the file's own numbers, in its units
    text = (out / "record.yaml").read_text()
    assert "unit: g" in text and "unit: um" in text and "unit: mm/s" in text
    # and the file as text: a column written with <= 15 digits comes back character for character
    assert (out / "signals.csv").read_text().splitlines()[1:4] == \
        (valid_record_dir / "signals.csv").read_text().splitlines()[1:4]


def test_joint_angles_read_in_rad_written_in_deg(tmp_path, valid_record_dir):
    edit_yaml(valid_record_dir, "    x:  {quantity: displacement, axis: X, unit: um}",
              "    q1: {quantity: joint_angle, unit: deg}")
    edit_csv(valid_record_dir, lambda lines: [lines[0].replace(",x,", ",q1,")] + lines[1:])
    _, original = csv_numbers(valid_record_dir / "signals.csv")
    rec = read_record(valid_record_dir)
    ch = rec.channels[3]
    assert (ch.name, ch.quantity, ch.axis, ch.unit) == ("q1", "joint_angle", None, "deg")
    np.testing.assert_array_equal(rec.data[3], original[:, 4] * DEG_TO_RAD)
    out = write_record(rec, tmp_path / "copy")
    _, written = csv_numbers(out / "signals.csv")
    np.testing.assert_array_equal(written[:, 4], original[:, 4])


# ------------------------------------------------------------------------------ round trips
@pytest.mark.parametrize("signal_file", ["signals.csv", "signals.npz"])
def test_round_trip_of_read_record_is_exact(tmp_path, valid_record_dir, signal_file):
    rec = read_record(valid_record_dir)
    again = read_record(write_record(rec, tmp_path / "out", signal_file=signal_file))
    assert again.signal_file == signal_file
    assert_same_record(rec, again)


@pytest.mark.parametrize("signal_file", ["signals.csv", "signals.npz"])
def test_round_trip_of_si_record_is_exact(tmp_path, signal_file):
    rec = simple_record()
    again = read_record(write_record(rec, tmp_path / "out", signal_file=signal_file))
    assert_same_record(rec, again)


@pytest.mark.parametrize("signal_file", ["signals.csv", "signals.npz"])
def test_round_trip_with_scaled_units_within_one_ulp(tmp_path, signal_file):
    # Random SI doubles written in um and g: scaling by 1e6 or 9.80665 has no exact inverse for a
    # few per cent of doubles, so those read back one unit in the last place away; the rest, and
    # everything else of the record, is exact.
    rec = simple_record(units=("N", "um", "g"), n=4000)
    again = read_record(write_record(rec, tmp_path / "out", signal_file=signal_file))
    np.testing.assert_array_equal(again.data[0], rec.data[0])
    np.testing.assert_array_max_ulp(again.data[1:], rec.data[1:], maxulp=1)
    exact = np.mean(again.data[1:] == rec.data[1:])
    assert exact > 0.8  # measured about 0.9-0.95; most values do have an exact preimage
    # reading that file and writing it again is then exact (a file value always has a preimage)
    third = read_record(write_record(again, tmp_path / "out2", signal_file=signal_file))
    np.testing.assert_array_equal(third.data, again.data)


def test_record_without_time_column_and_optional_sections(tmp_path):
    rec = simple_record(with_time=False)
    rec = Record(sample_rate_hz=rec.sample_rate_hz, channels=rec.channels, data=rec.data,
                 tool=rec.tool, cut=rec.cut)
    out = write_record(rec, tmp_path / "bare")
    text = (out / "record.yaml").read_text()
    for key in ("material:", "robot:", "sensors:", "name:", "quantity: time"):
        assert key not in text
    again = read_record(out)
    assert again.time_s is None and again.material is None and again.sensors is None
    np.testing.assert_array_equal(again.data, rec.data)


def test_writer_keeps_other_files_and_replaces_record(tmp_path, valid_record_dir):
    (valid_record_dir / "reference_frf.csv").write_text("freq_hz,XX_re,XX_im\n1.0,1e-7,0.0\n")
    rec = simple_record()
    write_record(rec, valid_record_dir)
    assert (valid_record_dir / "reference_frf.csv").exists()
    assert_same_record(rec, read_record(valid_record_dir))


def test_writer_leaves_nothing_behind_on_failure(tmp_path, valid_record_dir, monkeypatch):
    before = {p.name: p.read_bytes() for p in valid_record_dir.iterdir()}

    def broken_savez(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", broken_savez)
    rec = read_record(valid_record_dir)
    with pytest.raises(OSError, match="disk full"):
        write_record(rec, valid_record_dir, signal_file="signals.npz")
    with pytest.raises(OSError, match="disk full"):
        write_record(rec, tmp_path / "new_record", signal_file="signals.npz")
    assert {p.name: p.read_bytes() for p in valid_record_dir.iterdir()} == before
    assert not (tmp_path / "new_record").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_atomic_write_file_replaces_only_on_success(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old"
    with atomic_write(target) as tmp:
        assert tmp.parent == target.parent and tmp != target
        tmp.write_text("new")
    assert target.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_writer_rejects_unknown_unit():
    rec = simple_record(units=("N", "inch", "m/s2"))
    with pytest.raises(ValueError, match="unit 'inch'"):
        write_record(rec, "/nonexistent/never")


# ------------------------------------------------------------------------- missing files
def test_missing_directory(tmp_path):
    with pytest.raises(RecordError, match=r"nothing: file: expected a record directory with "
                                          r"record\.yaml, found no such file") as e:
        read_record(tmp_path / "nothing")
    message_parts(e.value, "nothing", "file")


def test_directory_without_record_yaml(tmp_path):
    (tmp_path / "empty_record").mkdir()
    with pytest.raises(RecordError, match=r"empty_record/record\.yaml: file: expected a record "
                                          r"directory with record\.yaml, found no such file"):
        read_record(tmp_path / "empty_record")


def test_record_yaml_is_a_directory(tmp_path):
    (tmp_path / "rec" / "record.yaml").mkdir(parents=True)
    with pytest.raises(RecordError, match=r"record\.yaml: file: expected a YAML file, found a directory"):
        read_record(tmp_path / "rec")


def test_missing_signal_file(valid_record_dir):
    (valid_record_dir / "signals.csv").unlink()
    with pytest.raises(RecordError, match=r"signals\.csv: file: expected the signal file named in "
                                          r"signals\.file, found no such file"):
        read_record(valid_record_dir)


def test_unreadable_yaml_bytes(valid_record_dir):
    (valid_record_dir / "record.yaml").write_bytes(b"format: \xff\xfe\x00\x01garbage")
    with pytest.raises(RecordError, match=r"record\.yaml: YAML: expected valid UTF-8 YAML text"):
        read_record(valid_record_dir)


def test_signal_file_outside_the_directory(valid_record_dir):
    edit_yaml(valid_record_dir, "file: signals.csv", "file: ../signals.csv")
    with pytest.raises(RecordError, match=r"signals\.file: expected a file name in the record "
                                          r"directory ending in \.csv or \.npz, found the text '\.\./signals\.csv'"):
        read_record(valid_record_dir)


# ------------------------------------------------------------------------------- columns
def test_undeclared_column(valid_record_dir):
    edit_yaml(valid_record_dir, "    z:  {quantity: displacement, axis: Z, unit: um}\n", "")
    with pytest.raises(RecordError, match=r"signals\.csv: column z: expected only columns declared "
                                          r"in signals\.columns, found the unknown column 'z'") as e:
        read_record(valid_record_dir)
    message_parts(e.value, "signals.csv", "column z")


def test_undeclared_text_column_is_named_before_its_cells(valid_record_dir, valid_record_npz_dir):
    edit_csv(valid_record_dir, lambda ls: [ls[0] + ",note"] + [line + ",ok" for line in ls[1:]])
    with pytest.raises(RecordError, match=r"signals\.csv: column note: expected only columns declared "
                                          r"in signals\.columns, found the unknown column 'note'"):
        read_record(valid_record_dir)
    path = valid_record_npz_dir / "signals.npz"
    arrays = dict(np.load(path))
    np.savez(path, extra=np.zeros(1000), **arrays)
    with pytest.raises(RecordError, match=r"signals\.npz: column extra: expected only columns declared "
                                          r"in signals\.columns, found the unknown column 'extra'"):
        read_record(valid_record_npz_dir)


def test_declared_column_missing(valid_record_dir):
    edit_yaml(valid_record_dir, "    z:  {quantity: displacement, axis: Z, unit: um}\n",
              "    z:  {quantity: displacement, axis: Z, unit: um}\n"
              "    ax: {quantity: acceleration, axis: X, unit: g}\n")
    with pytest.raises(RecordError, match=r"signals\.csv: column ax: expected the column 'ax' "
                                          r"declared in record\.yaml, found no such column"):
        read_record(valid_record_dir)


def test_unknown_unit(valid_record_dir):
    edit_yaml(valid_record_dir, "axis: X, unit: um", "axis: X, unit: inch")
    with pytest.raises(RecordError, match=r"record\.yaml: signals\.columns\.x\.unit: expected one of "
                                          r"m, mm, um, found the text 'inch'") as e:
        read_record(valid_record_dir)
    message_parts(e.value, "record.yaml", "signals.columns.x.unit")


def test_unit_of_another_quantity(valid_record_dir):
    edit_yaml(valid_record_dir, "Fx: {quantity: force, axis: X, unit: N}",
              "Fx: {quantity: force, axis: X, unit: um}")
    with pytest.raises(RecordError, match=r"signals\.columns\.Fx\.unit: expected one of N, found the text 'um'"):
        read_record(valid_record_dir)


def test_unknown_quantity(valid_record_dir):
    edit_yaml(valid_record_dir, "Fz: {quantity: force,", "Fz: {quantity: pressure,")
    with pytest.raises(RecordError, match=r"signals\.columns\.Fz\.quantity: expected one of time, "
                                          r"force, displacement, velocity, acceleration, joint_angle, "
                                          r"found the text 'pressure'"):
        read_record(valid_record_dir)


def test_unknown_axis(valid_record_dir):
    edit_yaml(valid_record_dir, "Fy: {quantity: force, axis: Y", "Fy: {quantity: force, axis: W")
    with pytest.raises(RecordError, match=r"signals\.columns\.Fy\.axis: expected one of X, Y, Z, "
                                          r"found the text 'W'"):
        read_record(valid_record_dir)


def test_lowercase_axis_is_not_an_axis(valid_record_dir):
    edit_yaml(valid_record_dir, "Fy: {quantity: force, axis: Y", "Fy: {quantity: force, axis: y")
    with pytest.raises(RecordError, match=r"signals\.columns\.Fy\.axis: expected one of X, Y, Z"):
        read_record(valid_record_dir)


def test_two_columns_of_the_same_quantity_and_axis(valid_record_dir):
    edit_yaml(valid_record_dir, "Fy: {quantity: force, axis: Y", "Fy: {quantity: force, axis: X")
    with pytest.raises(RecordError, match=r"signals\.columns\.Fy: expected one column of force along "
                                          r"X, found a second one besides 'Fx'"):
        read_record(valid_record_dir)


def test_joint_angle_column_must_be_named_q1_to_q6(valid_record_dir):
    edit_yaml(valid_record_dir, "    x:  {quantity: displacement, axis: X, unit: um}",
              "    x:  {quantity: joint_angle, unit: deg}")
    with pytest.raises(RecordError, match=r"signals\.columns\.x: expected joint_angle columns named "
                                          r"q1 \.\. q6, found 'x'"):
        read_record(valid_record_dir)


# --------------------------------------------------------------------------------- values
def test_nan_in_signal(valid_record_dir):
    edit_csv(valid_record_dir, lambda ls: ls[:10] + [ls[10].replace(ls[10].split(",")[2], "nan", 1)] + ls[11:])
    with pytest.raises(RecordError, match=r"signals\.csv: column Fy, sample 10: expected finite "
                                          r"numbers, found nan") as e:
        read_record(valid_record_dir)
    message_parts(e.value, "signals.csv", "column Fy, sample 10")


def test_inf_in_npz_signal(valid_record_npz_dir):
    path = valid_record_npz_dir / "signals.npz"
    arrays = dict(np.load(path))
    arrays["x"][3] = np.inf
    np.savez(path, **arrays)
    with pytest.raises(RecordError, match=r"signals\.npz: column x, sample 4: expected finite numbers, found inf"):
        read_record(valid_record_npz_dir)


def test_time_step_off_by_more_than_one_percent(valid_record_dir):
    # sample 501 at 0.50002 s: steps of 1.02 ms and 0.98 ms against 1 ms (2 % off)
    edit_csv(valid_record_dir, lambda ls: ls[:501] + ["0.50002" + ls[501][ls[501].index(","):]] + ls[502:])
    with pytest.raises(RecordError, match=r"signals\.csv: column t, sample 501: expected time steps "
                                          r"of 1/sample_rate_hz = 0\.001 s within 1 %, found a step of 0\.00102"):
        read_record(valid_record_dir)


def test_time_jitter_within_one_percent_is_accepted(valid_record_dir):
    edit_csv(valid_record_dir, lambda ls: ls[:501] + ["0.500005" + ls[501][ls[501].index(","):]] + ls[502:])
    rec = read_record(valid_record_dir)  # 0.5 % off: a valid file
    assert rec.time_s[500] == 0.500005


def test_time_not_increasing(valid_record_dir):
    def swap(lines):
        lines[100], lines[101] = lines[101], lines[100]
        return lines
    edit_csv(valid_record_dir, swap)
    with pytest.raises(RecordError, match=r"signals\.csv: column t, sample 101: expected increasing "
                                          r"times, found 0\.099 after 0\.1$"):
        read_record(valid_record_dir)


def test_empty_signals(valid_record_dir):
    edit_csv(valid_record_dir, lambda ls: ls[:1])
    with pytest.raises(RecordError, match=r"signals\.csv: signals: expected at least one sample, found no samples"):
        read_record(valid_record_dir)


def test_empty_signal_file(valid_record_dir):
    (valid_record_dir / "signals.csv").write_text("")
    with pytest.raises(RecordError, match=r"signals\.csv: header: expected a header row of column names"):
        read_record(valid_record_dir)


def test_npz_columns_of_different_lengths(valid_record_npz_dir):
    path = valid_record_npz_dir / "signals.npz"
    arrays = dict(np.load(path))
    arrays["Fz"] = arrays["Fz"][:-7]
    np.savez(path, **arrays)
    with pytest.raises(RecordError, match=r"signals\.npz: column Fz: expected 1000 samples like the "
                                          r"other columns, found 993 samples"):
        read_record(valid_record_npz_dir)


def test_npz_with_pickled_objects_is_refused(valid_record_npz_dir):
    path = valid_record_npz_dir / "signals.npz"
    arrays = dict(np.load(path))
    arrays["x"] = np.array([{"a": 1}] * 1000, dtype=object)
    np.savez(path, **arrays)
    with pytest.raises(RecordError, match=r"signals\.npz: file: expected a readable \.npz archive "
                                          r"without pickled objects"):
        read_record(valid_record_npz_dir)


def test_npz_two_dimensional_array(valid_record_npz_dir):
    path = valid_record_npz_dir / "signals.npz"
    arrays = dict(np.load(path))
    arrays["x"] = arrays["x"].reshape(2, 500)
    np.savez(path, **arrays)
    with pytest.raises(RecordError, match=r"signals\.npz: array x: expected a 1-D array, found shape \(2, 500\)"):
        read_record(valid_record_npz_dir)


def test_ragged_csv_row(valid_record_dir):
    edit_csv(valid_record_dir, lambda ls: ls[:41] + [ls[41].rsplit(",", 1)[0]] + ls[42:])
    with pytest.raises(RecordError, match=r"signals\.csv: line 42: expected 7 values \(one per header "
                                          r"column\), found 6 values"):
        read_record(valid_record_dir)


def test_text_in_a_number_cell(valid_record_dir):
    edit_csv(valid_record_dir, lambda ls: ls[:5] + [ls[5].replace(ls[5].split(",")[1], "12,3x", 1).replace(",12,3x", ",12.3x")] + ls[6:])
    with pytest.raises(RecordError, match=r"signals\.csv: line 6, column Fx: expected a number, found the text '12\.3x'"):
        read_record(valid_record_dir)


# ----------------------------------------------------------------------------- YAML level
def test_unknown_top_level_key(valid_record_dir):
    edit_yaml(valid_record_dir, "sample_rate_hz: 1000.0", "sample_rate_hz: 1000.0\nsample_rate: 1000.0")
    with pytest.raises(RecordError, match=r"record\.yaml: sample_rate: expected one of the keys "
                                          r"format, name, sample_rate_hz, .* or an x_ extension, "
                                          r"found the unknown key 'sample_rate'") as e:
        read_record(valid_record_dir)
    message_parts(e.value, "record.yaml", "sample_rate")


def test_unknown_nested_key(valid_record_dir):
    edit_yaml(valid_record_dir, "  milling: down", "  milling: down\n  feed_directon: [0, 1, 0]")
    with pytest.raises(RecordError, match=r"cut\.feed_directon: expected one of the keys .*"
                                          r"found the unknown key 'feed_directon'"):
        read_record(valid_record_dir)


def test_unknown_key_in_a_column(valid_record_dir):
    edit_yaml(valid_record_dir, "Fx: {quantity: force, axis: X, unit: N}",
              "Fx: {quantity: force, axis: X, unit: N, gain: 2}")
    with pytest.raises(RecordError, match=r"signals\.columns\.Fx\.gain: expected one of the keys "
                                          r"quantity, axis, unit or an x_ extension"):
        read_record(valid_record_dir)


def test_x_prefixed_keys_are_ignored_at_every_level(valid_record_dir):
    edit_yaml(valid_record_dir, "sample_rate_hz: 1000.0", "sample_rate_hz: 1000.0\nx_daq: {rack: 3}")
    edit_yaml(valid_record_dir, "  milling: down", "  milling: down\n  x_operator: anna")
    edit_yaml(valid_record_dir, "Fx: {quantity: force, axis: X, unit: N}",
              "Fx: {quantity: force, axis: X, unit: N, x_gain: 2}")
    assert read_record(valid_record_dir).cut.milling == "down"


def test_string_where_a_number_is_expected(valid_record_dir):
    edit_yaml(valid_record_dir, "sample_rate_hz: 1000.0", "sample_rate_hz: fast")
    with pytest.raises(RecordError, match=r"sample_rate_hz: expected a number > 0, found the text 'fast'"):
        read_record(valid_record_dir)


def test_quoted_number_is_text(valid_record_dir):
    edit_yaml(valid_record_dir, "diameter_m: 0.0254", "diameter_m: '0.0254'")
    with pytest.raises(RecordError, match=r"tool\.diameter_m: expected a number > 0, found the text '0\.0254'"):
        read_record(valid_record_dir)


def test_list_of_two_where_a_three_vector_is_expected(valid_record_dir):
    edit_yaml(valid_record_dir, "feed_direction: [0, 1, 0]", "feed_direction: [0, 1]")
    with pytest.raises(RecordError, match=r"cut\.feed_direction: expected a list of 3 numbers, "
                                          r"found a list of 2 \[0, 1\]"):
        read_record(valid_record_dir)


@pytest.mark.parametrize("value, found", [("2.5", "2.5"), ("true", "true"), ("two", "the text 'two'")])
def test_teeth_not_an_integer(valid_record_dir, value, found):
    edit_yaml(valid_record_dir, "teeth: 2", f"teeth: {value}")
    with pytest.raises(RecordError, match=rf"tool\.teeth: expected an integer >= 1, found {found}"):
        read_record(valid_record_dir)


@pytest.mark.parametrize("old, new, field, expected", [
    ("diameter_m: 0.0254", "diameter_m: 0", "tool.diameter_m", "a number > 0"),
    ("sample_rate_hz: 1000.0", "sample_rate_hz: -1000.0", "sample_rate_hz", "a number > 0"),
    ("spindle_rpm: 2700.0", "spindle_rpm: 0.0", "cut.spindle_rpm", "a number > 0"),
    ("teeth: 2", "teeth: 0", "tool.teeth", "an integer >= 1"),
    ("axial_depth_m: 0.006", "axial_depth_m: -0.006", "cut.axial_depth_m", "a number > 0"),
    ("radial_depth_m: 0.006", "radial_depth_m: 0", "cut.radial_depth_m", "a number > 0"),
    ("feed_per_tooth_m: 0.0005", "feed_per_tooth_m: -5.0e-4", "cut.feed_per_tooth_m", "a number > 0"),
    ("Ktc_N_m2: 1.2e8", "Ktc_N_m2: 0", "material.cutting_coefficients.Ktc_N_m2", "a number > 0"),
    ("Kte_N_m: 2.0e3", "Kte_N_m: -2.0e3", "material.cutting_coefficients.Kte_N_m", "a number >= 0"),
    ("noise_variance_N2: 0.56", "noise_variance_N2: 0", "sensors.force.noise_variance_N2", "a number > 0"),
    ("resolution_m: 1.5e-5", "resolution_m: -1.5e-5", "sensors.displacement.resolution_m", "a number > 0"),
    ("helix_deg: 30.0", "helix_deg: -5", "tool.helix_deg", "a number >= 0 and < 90"),
])
def test_non_positive_physical_quantity(valid_record_dir, old, new, field, expected):
    edit_yaml(valid_record_dir, old, new)
    with pytest.raises(RecordError, match=rf"record\.yaml: {re.escape(field)}: expected {expected}, found") as e:
        read_record(valid_record_dir)
    message_parts(e.value, "record.yaml", field)


def test_radial_depth_above_tool_diameter(valid_record_dir):
    edit_yaml(valid_record_dir, "radial_depth_m: 0.006", "radial_depth_m: 0.03")
    with pytest.raises(RecordError, match=r"cut\.radial_depth_m: expected a radial depth <= the tool "
                                          r"diameter 0\.0254 m, found 0\.03"):
        read_record(valid_record_dir)


def test_nan_in_yaml_number(valid_record_dir):
    edit_yaml(valid_record_dir, "spindle_rpm: 2700.0", "spindle_rpm: .nan")
    with pytest.raises(RecordError, match=r"cut\.spindle_rpm: expected a finite number > 0, found nan"):
        read_record(valid_record_dir)


def test_zero_direction_vector(valid_record_dir):
    edit_yaml(valid_record_dir, "normal_direction: [-1, 0, 0]", "normal_direction: [0, 0, 0]")
    with pytest.raises(RecordError, match=r"cut\.normal_direction: expected a non-zero direction "
                                          r"vector, found a list of 3 \[0\.0, 0\.0, 0\.0\]"):
        read_record(valid_record_dir)


def test_feed_and_normal_not_perpendicular(valid_record_dir):
    # f.n = 0.01 after normalising: ten times the tolerance
    edit_yaml(valid_record_dir, "normal_direction: [-1, 0, 0]", "normal_direction: [-0.99995, 0.01, 0]")
    with pytest.raises(RecordError, match=r"cut\.normal_direction: expected a direction perpendicular "
                                          r"to feed_direction \(\|f\.n\| <= 0\.001\), found f\.n = 0\.01"):
        read_record(valid_record_dir)


def test_nearly_perpendicular_within_tolerance_is_accepted(valid_record_dir):
    edit_yaml(valid_record_dir, "normal_direction: [-1, 0, 0]", "normal_direction: [-1, 0.0005, 0]")
    rec = read_record(valid_record_dir)
    assert abs(np.dot(rec.cut.feed_direction, rec.cut.normal_direction)) <= 1e-3


def test_non_unit_vector_is_normalised_with_a_warning(valid_record_dir):
    edit_yaml(valid_record_dir, "feed_direction: [0, 1, 0]", "feed_direction: [0, 2, 0]")
    with pytest.warns(FileWarning, match=r"record\.yaml: cut\.feed_direction: direction has length 2, normalised"):
        rec = read_record(valid_record_dir)
    np.testing.assert_array_equal(rec.cut.feed_direction, [0.0, 1.0, 0.0])


def test_vector_off_by_less_than_one_percent_is_normalised_silently(valid_record_dir):
    edit_yaml(valid_record_dir, "feed_direction: [0, 1, 0]", "feed_direction: [0, 1.005, 0]")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_record(valid_record_dir)
    np.testing.assert_array_equal(rec.cut.feed_direction, [0.0, 1.0, 0.0])


def test_milling_must_be_up_or_down(valid_record_dir):
    edit_yaml(valid_record_dir, "milling: down", "milling: climb")
    with pytest.raises(RecordError, match=r"cut\.milling: expected one of up, down, found the text 'climb'"):
        read_record(valid_record_dir)


def test_yaml_not_a_mapping(valid_record_dir):
    (valid_record_dir / "record.yaml").write_text("- format: robomill-record/1\n- sample_rate_hz: 1000\n")
    with pytest.raises(RecordError, match=r"record\.yaml: document: expected a YAML mapping \(key: value "
                                          r"lines\), found a list of 2"):
        read_record(valid_record_dir)


def test_empty_yaml(valid_record_dir):
    (valid_record_dir / "record.yaml").write_text("# nothing here\n")
    with pytest.raises(RecordError, match=r"record\.yaml: document: expected a YAML mapping, found an empty document"):
        read_record(valid_record_dir)


def test_python_tag_is_refused_and_never_run(tmp_path, valid_record_dir):
    marker = tmp_path / "pwned"
    edit_yaml(valid_record_dir, "name: kr500-acetal-2700rpm",
              f"name: !!python/object/apply:os.system ['touch {marker}']")
    with pytest.raises(RecordError, match=r"record\.yaml: line 2: expected plain YAML without "
                                          r"language-specific tags, found the tag "
                                          r"tag:yaml\.org,2002:python/object/apply:os\.system \(not allowed\)") as e:
        read_record(valid_record_dir)
    message_parts(e.value, "record.yaml", "line 2")
    assert not marker.exists()


def test_local_tag_is_refused(valid_record_dir):
    edit_yaml(valid_record_dir, "name: kr500-acetal-2700rpm", "name: !secret kr500")
    with pytest.raises(RecordError, match=r"line 2: expected plain YAML without language-specific tags, found the tag !secret"):
        read_record(valid_record_dir)


def test_invalid_yaml_syntax(valid_record_dir):
    edit_yaml(valid_record_dir, "  teeth: 2", "  teeth: [2")
    with pytest.raises(RecordError, match=r"record\.yaml: line \d+: expected valid YAML, found"):
        read_record(valid_record_dir)


def test_duplicate_key(valid_record_dir):
    edit_yaml(valid_record_dir, "  teeth: 2", "  teeth: 2\n  teeth: 3")
    with pytest.raises(RecordError, match=r"record\.yaml: line 16: expected each key once per mapping, "
                                          r"found the key 'teeth' repeated"):
        read_record(valid_record_dir)


@pytest.mark.parametrize("old, new, found", [
    ("format: robomill-record/1", "format: robomill-record/2", "the text 'robomill-record/2'"),
    ("format: robomill-record/1", "format: robomill-modal/1", "the text 'robomill-modal/1'"),
    ("format: robomill-record/1\n", "", "nothing \\(the key is missing\\)"),
])
def test_wrong_or_missing_format(valid_record_dir, old, new, found):
    edit_yaml(valid_record_dir, old, new)
    with pytest.raises(RecordError, match=rf"record\.yaml: format: expected .*robomill-record/1.*, found {found}"):
        read_record(valid_record_dir)


def test_missing_required_section(valid_record_dir):
    text = (valid_record_dir / "record.yaml").read_text()
    start = text.index("tool:\n")
    end = text.index("cut:\n")
    (valid_record_dir / "record.yaml").write_text(text[:start] + text[end:])
    with pytest.raises(RecordError, match=r"record\.yaml: tool: expected a mapping, found nothing \(the key is missing\)"):
        read_record(valid_record_dir)


def test_record_errors_are_value_errors(valid_record_dir):
    edit_yaml(valid_record_dir, "teeth: 2", "teeth: -2")
    with pytest.raises(ValueError):
        read_record(valid_record_dir)
