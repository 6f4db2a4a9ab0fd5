"""The atlas section of the demo report: a small atlas of the example cell, its two figures.

The lead's demo calls it (it does not edit :mod:`planner.demo` itself)::

    from planner.atlas import demo_section
    result = demo_section(report, robot, example.setup, out_dir, tool_model=example.tool_mode)

with ``report`` the demo's :class:`planner.report.Report`, ``robot`` the calibrated example robot
(a :class:`planner.robot.Robot` or a ``robomill-robot/1`` path), the example setup (object or
path) and ``out_dir`` the demo's output directory (the table goes to ``out_dir/atlas.parquet``).
It runs serially by default (a plane of 15 x 21 positions x 12 rotations: a few seconds; a local
cluster would spend longer starting than computing); pass ``scheduler=None`` to run it on a local
Dask cluster as ``robomill atlas`` does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .grid import Region, default_rotations_deg
from .io import write_table
from .problem import build_problem
from .run import AtlasResult, run_atlas

__all__ = ["demo_section", "DEMO_REGION"]

#: The demo's region: a horizontal plane 0.6 m above the robot's base, in front of it, 0.1 m step.
DEMO_REGION = dict(lower_m=(1.2, -1.0, 0.6), upper_m=(2.6, 1.0, 0.6), step_m=0.1)


def demo_section(report, robot, setup, out_dir, *, tool_model=None, region: Region | None = None,
                 scheduler: str | None = "serial", n_workers: int | None = None, rpm_range=None,
                 progress: bool = False) -> AtlasResult:
    """Compute a small atlas and add its section (text, table, two figures) to ``report``.

    Parameters
    ----------
    report : planner.report.Report
    robot : planner.robot.Robot or path
        With joint stiffness.
    setup : stability.setup.Setup or path
        With limits (speed range, depth range, ...).
    out_dir : path
        Where ``atlas.parquet`` is written.
    tool_model : oma.modal.ModalModel, optional
        Spindle/tool modes in series with the robot's.
    region : Region, optional
        Default :data:`DEMO_REGION` with 12 rotations.
    scheduler, n_workers, progress
        As :func:`planner.atlas.run_atlas` (default: serial).
    rpm_range : (float, float), optional
        Overrides the setup's speed range.

    Returns
    -------
    AtlasResult
    """
    from planner.robot import read_robot
    from stability.setup_io import read_setup

    if not hasattr(robot, "joint_stiffness_N_m_rad"):
        robot = read_robot(robot)
    if not hasattr(setup, "limits"):
        setup = read_setup(setup)
    region = region or Region(rotations_deg=default_rotations_deg(30.0), **DEMO_REGION)
    problem = build_problem(robot, setup, region, rpm_range=rpm_range, tool_model=tool_model)
    result = run_atlas(problem, region, scheduler=scheduler, n_workers=n_workers, progress=progress)
    table = write_table(Path(out_dir) / "atlas.parquet", result.columns,
                        metadata={"format": "robomill-atlas/1", **result.to_dict()})
    c, b = result.counts(), result.best
    s = report.section("Workspace atlas: where and at which tool rotation to cut")
    lo, hi = problem.rpm_grid[0], problem.rpm_grid[-1]
    s.text(f"{region.n_points} tool-tip positions ({region.shape[0]} x {region.shape[1]} x {region.shape[2]}, "
           f"{region.step_m:g} m step) x {region.rotations_deg.size} rotations about the tool axis: inverse "
           f"kinematics (the valid branch farthest from the joint limits), the robot's tool-tip modes"
           f"{' with the spindle/tool modes in series' if tool_model is not None else ''}, the ZOA lobes over "
           f"{lo:.0f}-{hi:.0f} rpm and the fastest stable cut under the setup's limits at each "
           f"({result.engine['wall_s']:.1f} s, {result.engine['scheduler']}, {result.engine['chunks']} chunks). "
           f"Table: {table.name} (Parquet, one row per position and rotation).")
    rows = [["rows (position x rotation)", c["rows"]], ["reachable", c["reachable"]],
            ["near a singularity", c["near_singularity"]], ["with a stable cut", c["stable_cut"]],
            ["positions with a stable cut at some rotation", c["positions_with_a_stable_cut"]]]
    mrr = result.per_point("mrr_m3_s") * 6e7
    if np.any(np.isfinite(mrr)):
        rows.append(["MRR at the best rotation, cm^3/min (min / max over positions)",
                     f"{np.nanmin(mrr):.0f} / {np.nanmax(mrr):.0f}"])
    s.table(["atlas", "value"], rows)
    if b is not None:
        s.table(["best placement", "value"], [
            ["tool tip (x, y, z), m", ", ".join(f"{v:.3f}" for v in b["position_m"])],
            ["rotation about the tool axis, deg", b["rotation_deg"]],
            ["joints, deg", ", ".join(f"{b[f'q{j}_deg']:.1f}" for j in range(1, 7))],
            ["lowest tool-tip mode, Hz", b["lowest_mode_hz"]], ["spindle speed, rpm", b["spindle_rpm"]],
            ["axial depth, mm", b["axial_depth_m"] * 1e3], ["MRR, cm^3/min", b["mrr_m3_s"] * 6e7],
            ["limited by", b["active_constraint"]], ["stability reserve (limit x margin / depth)",
                                                     b["stability_reserve"]]])
        if b["active_constraint"] in ("power", "torque", "depth_max", "force"):
            s.text(f"The best cut is limited by the {b['active_constraint']} bound, not by chatter: over this speed "
                   "range the spindle, not the arm, sets the removal rate wherever the arm reaches. Among equal rates "
                   "the atlas prefers the rotation with the largest stability reserve at the chosen speed, then the "
                   "largest limit over the whole speed range.")
    fig, _ = result.plot("mrr")
    s.figure(report.save_figure(fig, "atlas_mrr"), "Best stable MRR at each position's best tool rotation.")
    fig, _ = result.plot("rotation")
    s.figure(report.save_figure(fig, "atlas_rotation"), "Best rotation about the tool axis per position.")
    report.summary["atlas"] = {"points": region.n_points, "rotations": int(region.rotations_deg.size),
                               "table": str(table), "best": b, "counts": c, "wall_s": result.engine["wall_s"]}
    return result
