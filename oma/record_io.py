"""Read and write ``robomill-record/1`` directories (formats.md).

A record is a directory with ``record.yaml`` and one signal file, ``.csv`` (a header row, comma
separated, one column per signal) or ``.npz`` (one 1-D array per column). Every column of the
signal file is declared in ``signals.columns`` with its quantity, machine axis and unit; reading
converts to SI (um -> m, g -> m/s^2, mm/s -> m/s, deg -> rad) and keeps the file's unit in
:attr:`~oma.record.Channel.unit`, so :func:`write_record` writes the same units back.

Values are converted by :class:`oma._fields.UnitScale`: a record read from a file and written
again holds the same numbers (bit for bit in SI; textually the same for values the file gave with
up to 15 significant digits). A record built in memory and written with a scaled unit (``um``,
``g``, ``deg`` ...) reads back within one unit in the last place for the few values whose scaling
has no exact inverse; in SI units (``N``, ``m``, ``s``, ``m/s``, ``m/s2``) it reads back exactly.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from ._fields import DEG_TO_RAD, STANDARD_GRAVITY_M_S2, Fields, UnitScale, csv_text, describe, dump_yaml, load_yaml
from ._fields import read_csv_table
from ._sections import dump_cut, dump_material, dump_sensors, dump_tool, parse_cut, parse_material, parse_sensors
from ._sections import parse_tool
from .errors import RecordError
from .io import atomic_write
from .record import AXES, Channel, Record

__all__ = ["read_record", "write_record", "FORMAT", "UNITS", "TIME_STEP_TOLERANCE"]

FORMAT = "robomill-record/1"
RECORD_YAML = "record.yaml"

#: Units a signal column may have, per quantity, and their conversion to SI.
UNITS: dict[str, dict[str, UnitScale]] = {
    "time": {"s": UnitScale()},
    "force": {"N": UnitScale()},
    "displacement": {"m": UnitScale(), "mm": UnitScale(divisor=1e3), "um": UnitScale(divisor=1e6)},
    "velocity": {"m/s": UnitScale(), "mm/s": UnitScale(divisor=1e3)},
    "acceleration": {"m/s2": UnitScale(), "g": UnitScale(multiplier=STANDARD_GRAVITY_M_S2)},
    "joint_angle": {"deg": UnitScale(multiplier=DEG_TO_RAD)},
}
#: Largest relative deviation of a time step from ``1 / sample_rate_hz`` (formats.md: 1 %).
TIME_STEP_TOLERANCE = 0.01
_JOINT_NAMES = tuple(f"q{i}" for i in range(1, 7))


# ------------------------------------------------------------------------------------- reading
def read_record(path) -> Record:
    """Read a ``robomill-record/1`` record.

    Parameters
    ----------
    path : str or path-like
        The record directory, or its ``record.yaml``.

    Returns
    -------
    Record
        Signals in SI units, ``(n_channels, n_samples)``; the time column (if any) in
        ``time_s``; joint angles (quantity ``joint_angle``, file unit ``deg``) in rad.

    Raises
    ------
    RecordError
        Anything that makes the record invalid (formats.md): a missing or unreadable file, an
        unknown key (other than ``x_...``), a wrong type or non-positive physical value, an
        unknown quantity, axis or unit, a column of the signal file that is not declared or a
        declared column that is missing, a ragged CSV row, a value that is not a finite number,
        a time column that does not increase in steps of ``1 / sample_rate_hz`` (within 1 %),
        no samples at all, columns of different lengths, non-perpendicular feed and normal
        directions. The message names the file, the field, what was expected and what was found.

    Warns
    -----
    oma._fields.FileWarning
        A direction vector whose length is off 1 by more than 1 % (it is normalised).
    """
    p = Path(os.fspath(path))
    yaml_path = p / RECORD_YAML if p.is_dir() else p
    if not yaml_path.exists():
        what = "a record directory with record.yaml" if p.is_dir() or p.suffix == "" else "an existing record.yaml"
        raise RecordError(os.fspath(yaml_path), "file", what, "no such file")
    directory = yaml_path.parent
    root = load_yaml(yaml_path, error=RecordError)
    root.format(FORMAT)
    name = root.text("name")
    fs = root.positive("sample_rate_hz")
    signals = root.mapping_at("signals", required=True)
    file_name = signals.text("file", required=True)
    if (not file_name or Path(file_name).name != file_name or file_name in (".", "..")
            or Path(file_name).suffix.lower() not in (".csv", ".npz")):
        signals.fail("file", "a file name in the record directory ending in .csv or .npz",
                     describe(file_name))
    columns = _parse_columns(signals)
    signals.done()
    tool = parse_tool(root.mapping_at("tool", required=True))
    cut = parse_cut(root.mapping_at("cut", required=True), tool=tool, speed_and_depth_required=True)
    material_node = root.mapping_at("material")
    material = parse_material(material_node) if material_node is not None else None
    robot = root.mapping_at("robot")
    robot_model = joints = None
    if robot is not None:
        robot_model = robot.text("model")
        joints = robot.vector("joints_deg", 6, required=False)
        robot.done()
    sensors_node = root.mapping_at("sensors")
    sensors = parse_sensors(sensors_node) if sensors_node is not None else None
    root.done()

    signal_path = directory / file_name
    if Path(file_name).suffix.lower() == ".csv":
        table = read_csv_table(signal_path, error=RecordError,
                               missing="the signal file named in signals.file", allowed=tuple(columns),
                               allowed_text="only columns declared in signals.columns")
    else:
        table = _read_npz(signal_path, allowed=tuple(columns))
    data, time_s, channels = _assemble(table, columns, signal_path, yaml_path, fs)
    return Record(
        sample_rate_hz=fs, channels=channels, data=data, tool=tool, cut=cut, material=material,
        sensors=sensors, name=name, robot_model=robot_model, joints_deg=joints, time_s=time_s,
        signal_file=file_name, path=os.fspath(p),
    )


def _parse_columns(signals: Fields) -> dict[str, tuple[str, str | None, str]]:
    """``signals.columns`` -> ``{name: (quantity, axis, unit)}`` in declared order."""
    columns_node = signals.mapping_at("columns", required=True)
    out: dict[str, tuple[str, str | None, str]] = {}
    seen: dict[tuple[str, str | None], str] = {}
    for name in list(columns_node.mapping):
        if not isinstance(name, str) or not name.strip() or name != name.strip() or "," in name:
            columns_node.fail(str(name), "a column name (text without commas or edge spaces)",
                              describe(name))
        col = columns_node.mapping_at(name, required=True)
        quantity = col.choice("quantity", tuple(UNITS))
        if quantity in ("time", "joint_angle"):
            if col.has("axis"):
                col.fail("axis", f"no axis for a {quantity} column", describe(col.mapping["axis"]))
            axis = None
        else:
            axis = col.choice("axis", AXES)
        unit = col.choice("unit", tuple(UNITS[quantity]))
        col.done()
        if quantity == "joint_angle" and name not in _JOINT_NAMES:
            columns_node.fail(name, "joint_angle columns named q1 .. q6", repr(name))
        key = (quantity, name if quantity == "joint_angle" else axis)
        if key in seen:
            what = f"{quantity} along {axis}" if axis else quantity
            columns_node.fail(name, f"one column of {what}", f"a second one besides {seen[key]!r}")
        seen[key] = name
        out[name] = (quantity, axis, unit)
    if not out:
        columns_node.fail(None, "at least one declared column", "none")
    return out


def _read_npz(path: Path, *, allowed: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Arrays of a signal ``.npz`` (one 1-D numeric array per column), pickles refused; an array
    whose name is not in ``allowed`` is reported before any array is read."""
    file = os.fspath(path)
    if not path.exists():
        raise RecordError(file, "file", "the signal file named in signals.file", "no such file")
    out = {}
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise RecordError(file, "file", "an .npz archive of 1-D arrays",
                              f"a single array of shape {np.shape(loaded)}")
        with loaded as npz:
            for key in npz.files:
                if key not in allowed:
                    raise RecordError(file, f"column {key}", "only columns declared in signals.columns",
                                      f"the unknown column {key!r}")
            for key in npz.files:
                a = npz[key]
                if not isinstance(a, np.ndarray) or a.dtype.kind not in "iuf":
                    found = f"dtype {a.dtype}" if isinstance(a, np.ndarray) else "not an array"
                    raise RecordError(file, f"array {key}", "a real numeric array", found)
                if a.ndim != 1:
                    raise RecordError(file, f"array {key}", "a 1-D array", f"shape {a.shape}")
                out[key] = a.astype(float)
    except RecordError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, NotImplementedError) as exc:
        # np.load raises ValueError for pickled data, BadZipFile/OSError/EOFError for damage
        raise RecordError(file, "file", "a readable .npz archive without pickled objects",
                          f"{type(exc).__name__}: {str(exc)[:80]}") from None
    return out


def _assemble(table: dict[str, np.ndarray], columns, signal_path: Path, yaml_path: Path, fs: float):
    """Check the signal table against the declared columns; SI data, time and channels."""
    sig_file, yaml_file = os.fspath(signal_path), os.fspath(yaml_path)
    for name in table:
        if name not in columns:
            raise RecordError(sig_file, f"column {name}", "only columns declared in signals.columns",
                              f"the unknown column {name!r}")
    for name in columns:
        if name not in table:
            raise RecordError(sig_file, f"column {name}",
                              f"the column {name!r} declared in {yaml_path.name}", "no such column")
    lengths = {name: table[name].size for name in columns}
    n = max(lengths.values())
    for name, size in lengths.items():
        if size != n:
            raise RecordError(sig_file, f"column {name}", f"{n} samples like the other columns",
                              f"{size} samples")
    if n == 0:
        raise RecordError(sig_file, "signals", "at least one sample", "no samples")
    channels, rows, time_s = [], [], None
    for name, (quantity, axis, unit) in columns.items():
        values = table[name]
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise RecordError(sig_file, f"column {name}, sample {bad[0] + 1}", "finite numbers",
                              repr(float(values[bad[0]])))
        si = UNITS[quantity][unit].to_si(values)
        if quantity == "time":
            _check_time(si, fs, sig_file, name)
            time_s = si
            continue
        channels.append(Channel(name=name, quantity=quantity, axis=axis, unit=unit))
        rows.append(si)
    if not channels:
        raise RecordError(yaml_file, "signals.columns", "at least one signal besides time",
                          "only a time column")
    return np.vstack(rows), time_s, tuple(channels)


def _check_time(t: np.ndarray, fs: float, file: str, name: str) -> None:
    if t.size < 2:
        return
    dt = np.diff(t)
    nonincreasing = np.flatnonzero(dt <= 0)
    if nonincreasing.size:
        k = nonincreasing[0]
        raise RecordError(file, f"column {name}, sample {k + 2}", "increasing times",
                          f"{float(t[k + 1])!r} after {float(t[k])!r}")
    with np.errstate(over="ignore", invalid="ignore"):  # absurd times overflow: still an error
        off = np.abs(dt * fs - 1.0)
    off = np.where(np.isfinite(off), off, np.inf)
    worst = int(np.argmax(off))
    if off[worst] > TIME_STEP_TOLERANCE:
        raise RecordError(file, f"column {name}, sample {worst + 2}",
                          f"time steps of 1/sample_rate_hz = {1.0 / fs!r} s within 1 %",
                          f"a step of {float(dt[worst])!r} s")


# ------------------------------------------------------------------------------------- writing
def write_record(record: Record, directory, *, signal_file: str | None = None) -> Path:
    """Write a record as a ``robomill-record/1`` directory.

    Parameters
    ----------
    record : Record
        The record (SI signals; each channel's ``unit`` is the unit written).
    directory : str or path-like
        The record directory to create (or update: ``record.yaml`` and the signal file are
        replaced, other files in it are kept).
    signal_file : str, optional
        Name of the signal file, ``*.csv`` or ``*.npz``; default ``record.signal_file``.

    Returns
    -------
    pathlib.Path
        The record directory.

    Raises
    ------
    ValueError
        A channel whose quantity, axis or unit is not one of formats.md, a cut without spindle
        speed or axial depth, or a bad file name (the file would not read back).

    Notes
    -----
    CSV numbers are written with ``repr`` (the shortest text that reads back as the same double);
    the time column, if the record has one, is written first as ``t`` (s). The directory is
    written through :func:`oma.io.atomic_write`: no half-written record is left behind.
    """
    if record.cut.spindle_rpm is None or record.cut.axial_depth_m is None:
        raise ValueError("a record's cut needs spindle_rpm and axial_depth_m (formats.md)")
    name = signal_file or record.signal_file
    suffix = Path(name).suffix.lower()
    if Path(name).name != name or suffix not in (".csv", ".npz"):
        raise ValueError(f"signal_file must be a file name ending in .csv or .npz, got {name!r}")
    columns: dict[str, dict] = {}
    arrays: dict[str, np.ndarray] = {}
    if record.time_s is not None:
        tname = "t" if all(c.name != "t" for c in record.channels) else "time"
        columns[tname] = {"quantity": "time", "unit": "s"}
        arrays[tname] = np.asarray(record.time_s, dtype=float)
    for ch, si in zip(record.channels, record.data):
        if ch.quantity not in UNITS or ch.quantity == "time" or ch.unit not in UNITS[ch.quantity]:
            raise ValueError(f"channel {ch.name}: quantity {ch.quantity!r} with unit {ch.unit!r} "
                             f"is not a record column (formats.md)")
        if ch.name in columns or not ch.name or "," in ch.name:
            raise ValueError(f"channel name {ch.name!r} is empty, repeated or contains a comma")
        entry = {"quantity": ch.quantity}
        if ch.quantity != "joint_angle":
            if ch.axis not in AXES:
                raise ValueError(f"channel {ch.name}: axis must be one of X, Y, Z, got {ch.axis!r}")
            entry["axis"] = ch.axis
        entry["unit"] = ch.unit
        columns[ch.name] = entry
        arrays[ch.name] = UNITS[ch.quantity][ch.unit].from_si(si)

    doc: dict = {"format": FORMAT}
    if record.name is not None:
        doc["name"] = record.name
    doc["sample_rate_hz"] = float(record.sample_rate_hz)
    doc["signals"] = {"file": name, "columns": columns}
    doc["tool"] = dump_tool(record.tool)
    doc["cut"] = dump_cut(record.cut)
    if record.material is not None:
        doc["material"] = dump_material(record.material)
    if record.robot_model is not None or record.joints_deg is not None:
        robot: dict = {}
        if record.robot_model is not None:
            robot["model"] = record.robot_model
        if record.joints_deg is not None:
            robot["joints_deg"] = [float(q) for q in record.joints_deg]
        doc["robot"] = robot
    if record.sensors is not None:
        sensors = dump_sensors(record.sensors)
        if sensors:
            doc["sensors"] = sensors

    target = Path(os.fspath(directory))
    with atomic_write(target, directory=True, last=(RECORD_YAML,)) as tmp:
        if suffix == ".csv":
            (tmp / name).write_text(csv_text(arrays), encoding="utf-8", newline="")
        else:
            with open(tmp / name, "wb") as fh:
                np.savez(fh, **arrays)
        (tmp / RECORD_YAML).write_text(dump_yaml(doc), encoding="utf-8")
    return target
