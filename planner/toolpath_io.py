"""Read and write ``robomill-toolpath/1``: YAML plus a CSV of points (formats.md)::

    format: robomill-toolpath/1
    tool: {teeth: 2, diameter_m: 0.0254, helix_deg: 30.0}
    material: {...}                        # as in a record, with cutting coefficients
    tool_axis: [0, 0, 1]                   # a, machine frame
    limits: {...}                          # optional, as in a setup
    points: toolpath.csv

``toolpath.csv`` has the columns ``x_m,y_m,z_m,q1_deg,...,q6_deg,spindle_rpm,feed_per_tooth_m,
radial_depth_m,axial_depth_m,milling`` (any order), one row per point. The tool axis "may also be
a column" (formats.md): robomill's column names for it are ``tool_axis_x,tool_axis_y,tool_axis_z``
(one unit vector per point), used instead of the YAML ``tool_axis`` (giving both is an error).

With a robot (formats.md "Toolpath with a robot")::

    robot: robot.yaml                      # a robomill-robot/1 file, relative to this file
    workpiece_frame: {origin_m: [1.6, 0, 0.4], rpy_deg: [0, 0, 90]}   # optional

the joint columns may be left out (or left empty, ``nan``, on the rows where inverse kinematics is
to find them: all six of a row or none), positions and tool axis are in the workpiece frame, and
the optional column ``tool_rotation_deg`` fixes the rotation about the tool axis (``nan``: free).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from oma._fields import DIRECTION_LENGTH_TOLERANCE, csv_text, describe, dump_yaml, load_yaml, read_csv_table, warn_user
from oma._sections import dump_limits, dump_material, dump_tool, parse_limits, parse_material, parse_tool
from oma.errors import ToolpathError
from oma.io import atomic_write
from stability.setup import Limits

from .toolpath import Toolpath

__all__ = ["read_toolpath", "write_toolpath", "FORMAT", "POINT_COLUMNS", "TOOL_AXIS_COLUMNS", "ROTATION_COLUMN"]

FORMAT = "robomill-toolpath/1"
POSITION_COLUMNS = ("x_m", "y_m", "z_m")
JOINT_COLUMNS = tuple(f"q{i}_deg" for i in range(1, 7))
#: Required columns of the points file (formats.md).
POINT_COLUMNS = POSITION_COLUMNS + JOINT_COLUMNS + (
    "spindle_rpm", "feed_per_tooth_m", "radial_depth_m", "axial_depth_m", "milling")
#: Optional per-point tool axis columns (robomill's names; formats.md leaves them open).
TOOL_AXIS_COLUMNS = ("tool_axis_x", "tool_axis_y", "tool_axis_z")
#: Optional column with a robot: the rotation about the tool axis, deg (formats.md).
ROTATION_COLUMN = "tool_rotation_deg"
_POSITIVE_COLUMNS = ("spindle_rpm", "feed_per_tooth_m", "radial_depth_m", "axial_depth_m")


def read_toolpath(path) -> Toolpath:
    """Read a ``robomill-toolpath/1`` YAML file and its points CSV.

    Parameters
    ----------
    path : str or path-like
        The YAML file; ``points`` names the CSV in the same directory.

    Returns
    -------
    Toolpath
        SI units; joint angles stay in degrees (``joints_deg``); ``tool_axis`` shape (3,) from
        the YAML or (n_points, 3) from columns, unit vectors.

    Raises
    ------
    ToolpathError
        Anything invalid in either file: unknown key or column, missing column, wrong type,
        non-finite number, a spindle speed, feed or depth <= 0, a radial depth above the tool
        diameter, ``milling`` other than up/down, a zero tool axis, fewer than two points, two
        consecutive points at the same place (no feed direction).

    Warns
    -----
    oma._fields.FileWarning
        A tool axis whose length is off 1 by more than 1 % (it is normalised).
    """
    root = load_yaml(path, error=ToolpathError)
    yaml_file = root.file
    root.format(FORMAT)
    tool = parse_tool(root.mapping_at("tool", required=True))
    material = parse_material(root.mapping_at("material", required=True), coefficients_required=True)
    axis_yaml = root.direction("tool_axis", required=False)
    limits_node = root.mapping_at("limits")
    limits = Limits(**parse_limits(limits_node)) if limits_node is not None else Limits()
    robot_file = root.text("robot", required=False)
    if robot_file is not None:
        resolved = Path(yaml_file).parent / robot_file
        if not robot_file or not resolved.is_file():
            root.fail("robot", "a robomill-robot/1 file (path relative to the toolpath file)",
                      describe(robot_file) + " (no such file)")
        robot_file = os.fspath(resolved)
    origin = rpy = None
    frame = root.mapping_at("workpiece_frame")
    if frame is not None:
        origin = frame.vector("origin_m", 3)
        rpy = frame.vector("rpy_deg", 3, required=False, default=[0.0, 0.0, 0.0])
        frame.done()
    points = root.text("points", required=True)
    if not points or Path(points).name != points or points in (".", "..") or not points.lower().endswith(".csv"):
        root.fail("points", "a .csv file name in the directory of the YAML file", describe(points))
    root.done()

    csv_path = Path(yaml_file).parent / points
    csv_file = os.fspath(csv_path)
    table = read_csv_table(csv_path, error=ToolpathError, missing="the points file named in points",
                           text_columns=("milling",),
                           allowed=POINT_COLUMNS + TOOL_AXIS_COLUMNS + (ROTATION_COLUMN,), extensions=True)
    has_joints = [c in table for c in JOINT_COLUMNS]
    if robot_file is None and ROTATION_COLUMN in table:
        raise ToolpathError(csv_file, f"column {ROTATION_COLUMN}", "a robot (the key robot in the YAML file) "
                            "for a rotation about the tool axis", "no robot")
    for name in POINT_COLUMNS:
        if robot_file is not None and name in JOINT_COLUMNS and not any(has_joints):
            continue
        if name not in table:
            raise ToolpathError(csv_file, f"column {name}", f"a column {name}", "no such column")
    n = table["x_m"].size
    if n < 2:
        raise ToolpathError(csv_file, "rows", "at least two points (a feed direction needs two)",
                            f"{n} point{'s' if n != 1 else ''}")
    joints = None
    if any(has_joints):
        joints = np.column_stack([table[c] for c in JOINT_COLUMNS])
        given = np.isfinite(joints)
        bad = np.flatnonzero(np.any(given, axis=1) & ~np.all(given, axis=1))
        if robot_file is None:
            bad = np.flatnonzero(~np.all(given, axis=1))
        if bad.size:
            j = int(np.flatnonzero(~given[bad[0]])[0])
            raise ToolpathError(csv_file, f"row {bad[0] + 1}, column {JOINT_COLUMNS[j]}",
                                "a finite number" + (" (or all six joints of the row empty/nan: found by "
                                                     "inverse kinematics)" if robot_file else ""),
                                repr(float(joints[bad[0], j])))
    rotation = None
    if ROTATION_COLUMN in table:
        rotation = table[ROTATION_COLUMN]
        bad = np.flatnonzero(np.isinf(rotation))
        if bad.size:
            raise ToolpathError(csv_file, f"row {bad[0] + 1}, column {ROTATION_COLUMN}",
                                "a finite angle in degrees (or nan: free)", repr(float(rotation[bad[0]])))
    for name in POINT_COLUMNS + TOOL_AXIS_COLUMNS:
        if name == "milling" or name not in table or name in JOINT_COLUMNS:
            continue
        col = table[name]
        bad = np.flatnonzero(~np.isfinite(col))
        if bad.size:
            raise ToolpathError(csv_file, f"row {bad[0] + 1}, column {name}", "a finite number",
                                repr(float(col[bad[0]])))
        if name in _POSITIVE_COLUMNS:
            bad = np.flatnonzero(col <= 0)
            if bad.size:
                raise ToolpathError(csv_file, f"row {bad[0] + 1}, column {name}", "a number > 0",
                                    repr(float(col[bad[0]])))
    ae = table["radial_depth_m"]
    bad = np.flatnonzero(ae > tool.diameter_m)
    if bad.size:
        raise ToolpathError(csv_file, f"row {bad[0] + 1}, column radial_depth_m",
                            f"a radial depth <= the tool diameter {tool.diameter_m!r} m",
                            repr(float(ae[bad[0]])))
    milling = table["milling"]
    bad = np.flatnonzero(~np.isin(milling, ("up", "down")))
    if bad.size:
        raise ToolpathError(csv_file, f"row {bad[0] + 1}, column milling", "up or down",
                            describe(str(milling[bad[0]])))
    positions = np.column_stack([table[c] for c in POSITION_COLUMNS])
    step = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    bad = np.flatnonzero(step == 0)
    if bad.size:
        raise ToolpathError(csv_file, f"row {bad[0] + 2}", "a point away from the one before it "
                            "(the feed direction runs from a point to the next)",
                            f"the same position as row {bad[0] + 1}")

    has_columns = [c in table for c in TOOL_AXIS_COLUMNS]
    if any(has_columns) and not all(has_columns):
        missing = [c for c, h in zip(TOOL_AXIS_COLUMNS, has_columns) if not h][0]
        raise ToolpathError(csv_file, f"column {missing}", "all three tool axis columns "
                            + ",".join(TOOL_AXIS_COLUMNS), "no such column")
    if all(has_columns):
        if axis_yaml is not None:
            raise ToolpathError(yaml_file, "tool_axis", "the tool axis either in the YAML or as "
                                "columns of the points file, not both", "both")
        axis = _axis_columns(np.column_stack([table[c] for c in TOOL_AXIS_COLUMNS]), csv_file)
    elif axis_yaml is None:
        raise ToolpathError(yaml_file, "tool_axis", "a tool axis [ax, ay, az] (or the columns "
                            + ",".join(TOOL_AXIS_COLUMNS) + " in the points file)",
                            "nothing (the key is missing)")
    else:
        axis = axis_yaml

    return Toolpath(
        tool=tool, material=material, tool_axis=axis, positions_m=positions,
        joints_deg=joints,
        spindle_rpm=table["spindle_rpm"], feed_per_tooth_m=table["feed_per_tooth_m"],
        radial_depth_m=table["radial_depth_m"], axial_depth_m=table["axial_depth_m"],
        milling=milling, limits=limits, points_file=points, robot_file=robot_file,
        workpiece_origin_m=origin, workpiece_rpy_deg=rpy, tool_rotation_deg=rotation,
    )


def _axis_columns(axis: np.ndarray, file: str) -> np.ndarray:
    """Per-point tool axes made unit; a zero row is an error, a length off by > 1 % warns."""
    length = np.linalg.norm(axis, axis=1)
    bad = np.flatnonzero(length == 0)
    if bad.size:
        raise ToolpathError(file, f"row {bad[0] + 1}, columns tool_axis_*", "a non-zero tool axis",
                            describe(axis[bad[0]].tolist()))
    off = np.flatnonzero(np.abs(length - 1.0) > DIRECTION_LENGTH_TOLERANCE)
    if off.size:
        warn_user(f"{file}: tool axis of {off.size} point(s) (first row {off[0] + 1}) not of "
                  f"unit length ({length[off[0]]:.6g}), normalised")
    unit = np.abs(length - 1.0) <= 4 * np.finfo(float).eps  # keep exact unit vectors as given
    return np.where(unit[:, None], axis, axis / length[:, None])


def write_toolpath(toolpath: Toolpath, path) -> Path:
    """Write a toolpath: the YAML file ``path`` and its points CSV beside it.

    The CSV is named by ``toolpath.points_file``; a per-point tool axis (shape (n, 3)) goes to
    the columns ``tool_axis_x,tool_axis_y,tool_axis_z``, a single one to the YAML ``tool_axis``.
    Numbers are written with ``repr`` precision; both files are written atomically (points first,
    so the YAML never names a points file that is not there).

    Returns
    -------
    pathlib.Path
        The YAML file.
    """
    target = Path(os.fspath(path))
    points = toolpath.points_file
    if Path(points).name != points or not points.lower().endswith(".csv"):
        raise ValueError(f"points_file must be a .csv file name, got {points!r}")
    if (target.parent / points).resolve() == target.resolve():
        raise ValueError("the points file and the YAML file must differ")
    axis = np.asarray(toolpath.tool_axis, dtype=float)
    cols: dict[str, np.ndarray] = {}
    for i, c in enumerate(POSITION_COLUMNS):
        cols[c] = toolpath.positions_m[:, i]
    if toolpath.joints_deg is not None:
        for i, c in enumerate(JOINT_COLUMNS):
            cols[c] = toolpath.joints_deg[:, i]
    for c in ("spindle_rpm", "feed_per_tooth_m", "radial_depth_m", "axial_depth_m"):
        cols[c] = getattr(toolpath, c)
    cols["milling"] = np.asarray(toolpath.milling, dtype=str)
    if toolpath.tool_rotation_deg is not None:
        cols[ROTATION_COLUMN] = toolpath.tool_rotation_deg
    doc: dict = {"format": FORMAT, "tool": dump_tool(toolpath.tool),
                 "material": dump_material(toolpath.material)}
    if toolpath.robot_file is not None:
        robot = Path(os.fspath(toolpath.robot_file))
        try:
            doc["robot"] = Path(os.path.relpath(robot.resolve(), target.parent.resolve())).as_posix()
        except ValueError:  # another drive (Windows)
            doc["robot"] = os.fspath(robot.resolve())
    if toolpath.workpiece_origin_m is not None:
        doc["workpiece_frame"] = {"origin_m": [float(x) for x in toolpath.workpiece_origin_m],
                                  "rpy_deg": [float(x) for x in toolpath.workpiece_rpy_deg]}
    if axis.ndim == 2:
        for i, c in enumerate(TOOL_AXIS_COLUMNS):
            cols[c] = axis[:, i]
    else:
        doc["tool_axis"] = [float(x) for x in axis]
    limits = dump_limits(toolpath.limits)
    if limits:
        doc["limits"] = limits
    doc["points"] = points
    csv = csv_text(cols)
    text = dump_yaml(doc)
    with atomic_write(target.parent / points) as tmp:
        tmp.write_text(csv, encoding="utf-8", newline="")
    with atomic_write(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return target
