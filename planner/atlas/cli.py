"""``robomill atlas ROBOT SETUP``: stability and stiffness over the robot's workspace (cli.md).

Parses, calls :mod:`planner.atlas`, writes, prints. Outputs go to ``-o DIR``: ``atlas.parquet``
(the table), ``atlas_mrr.png`` and ``atlas_rotation.png`` (the figures, unless ``--no-plots``),
each written under a temporary name and renamed. Nothing is written when the input is bad or the
run is interrupted.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from planner.cli_common import EXIT_OK, UsageError, add_json, emit, save_figure

__all__ = ["add_parsers", "DEFAULT_BOX_M"]

#: The default region: a 1.2 m x 1.6 m x 0.8 m box in front of the robot, machine frame.
DEFAULT_BOX_M = (1.4, -0.8, 0.2, 2.6, 0.8, 1.0)


def add_parsers(sub) -> None:
    p = sub.add_parser("atlas", help="stability and stiffness over the workspace (grid of positions x tool "
                                     "rotations) on a Dask cluster")
    p.add_argument("robot", help="robomill-robot/1 file (with joint stiffness)")
    p.add_argument("setup", help="robomill-setup/1 file (with limits: spindle_rpm, axial_depth_m, ...)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="tcp://HOST:PORT of a running Dask scheduler (default: a local cluster of processes; "
                        "'serial': no Dask)")
    p.add_argument("--workers", type=int, default=None, help="local cluster size (default: the cores)")
    p.add_argument("-o", "--output", default="atlas", metavar="DIR", help="output directory (default ./atlas)")
    p.add_argument("--box-m", type=float, nargs=6, default=list(DEFAULT_BOX_M),
                   metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="region in the workpiece frame, m (equal bounds on an axis: a plane); default "
                        + " ".join(f"{v:g}" for v in DEFAULT_BOX_M))
    p.add_argument("--step-m", type=float, default=0.1, help="grid step, m (default 0.1)")
    p.add_argument("--rotation-step-deg", type=float, default=30.0,
                   help="tool rotations -180 .. 180 every this many degrees (default 30: 12 rotations)")
    p.add_argument("--rotations-deg", type=float, nargs="+", default=None, help="explicit tool rotations, deg")
    p.add_argument("--origin-m", type=float, nargs=3, default=[0.0, 0.0, 0.0],
                   help="workpiece frame origin in the machine frame, m")
    p.add_argument("--rpy-deg", type=float, nargs=3, default=[0.0, 0.0, 0.0],
                   help="workpiece frame orientation (fixed-axis roll, pitch, yaw), deg")
    p.add_argument("--rpm", type=float, nargs=2, default=None, metavar=("MIN", "MAX"),
                   help="speed range (default: the setup's limits.spindle_rpm)")
    p.add_argument("--n-rpm", type=int, default=300, help="speeds of the log grid over the range (default 300)")
    p.add_argument("--n-freq", type=int, default=500, help="ZOA chatter frequencies per pose (default 500)")
    p.add_argument("--method", choices=["auto", "zoa", "sdm"], default="auto",
                   help="ZOA everywhere; 'sdm' (and 'auto' when ae/D < 0.2) also checks the best rows of the "
                        "--sdm-verify best positions by semi-discretization")
    p.add_argument("--sdm-verify", type=int, default=16, help="positions checked by SDM (default 16)")
    p.add_argument("--tool-model", default=None, help="spindle/tool modes (robomill-modal/1), in series")
    p.add_argument("--chunk-points", type=int, default=None, help="positions per task (default: ~1 s of work)")
    p.add_argument("--connect-timeout-s", type=float, default=5.0, help="time a --scheduler has to answer, s")
    p.add_argument("--no-plots", action="store_true", help="write the table only")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_json(p)
    p.set_defaults(handler=cmd_atlas)


def _human(d: dict) -> str:
    b = d["best"]
    lines = [f"atlas: {d['points']} positions x {d['rotations']} rotations -> {d['table']}",
             f"reachable rows: {d['counts']['reachable']} of {d['counts']['rows']}, "
             f"with a stable cut: {d['counts']['stable_cut']}"]
    if b is not None:
        line = (f"best: x {b['x_m']:.3f} y {b['y_m']:.3f} z {b['z_m']:.3f} m, rotation {b['rotation_deg']:.1f} deg, "
                f"{b['spindle_rpm']:.0f} rpm, ap {b['axial_depth_m'] * 1e3:.2f} mm, "
                f"MRR {b['mrr_m3_s'] * 6e7:.1f} cm^3/min ({b['active_constraint']})")
        if b["stability"] == "sdm":
            line += f"; SDM: limit {b['sdm_depth_limit_m'] * 1e3:.2f} mm, MRR {b['sdm_mrr_m3_s'] * 6e7:.1f} cm^3/min"
        lines.append(line)
    return "\n".join(lines)


def cmd_atlas(args: argparse.Namespace) -> int:
    from oma.io import atomic_write
    from planner.robot import read_robot
    from stability.setup_io import read_setup

    from .grid import Region, default_rotations_deg
    from .io import write_table
    from .problem import build_problem
    from .run import run_atlas

    if args.workers is not None and args.workers < 1:
        raise UsageError("--workers", "at least 1", str(args.workers))
    if args.chunk_points is not None and args.chunk_points < 1:
        raise UsageError("--chunk-points", "at least 1", str(args.chunk_points))
    if args.sdm_verify < 0:
        raise UsageError("--sdm-verify", "at least 0", str(args.sdm_verify))
    if args.rpm is not None and not 0 < args.rpm[0] < args.rpm[1]:
        raise UsageError("--rpm", "0 < MIN < MAX", f"{args.rpm[0]:g} {args.rpm[1]:g}")
    out_dir = Path(args.output)
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError("-o", "a directory", f"{args.output!r} (a file)")
    if not args.verbose and args.scheduler != "serial":
        # a local cluster's scheduler runs in this process: its INFO lines are noise on stderr. (Set
        # after importing distributed, whose import configures its loggers.)
        import distributed  # noqa: F401

        logging.getLogger("distributed").setLevel(logging.ERROR)
    robot = read_robot(args.robot)
    setup = read_setup(args.setup)
    rotations = args.rotations_deg if args.rotations_deg is not None else default_rotations_deg(args.rotation_step_deg)
    region = Region(args.box_m[:3], args.box_m[3:], args.step_m, rotations, origin_m=args.origin_m,
                    rpy_deg=args.rpy_deg)
    tool_model = None
    if args.tool_model is not None:
        from oma.modal_io import read_modal_model

        tool_model = read_modal_model(args.tool_model)
    problem = build_problem(robot, setup, region, setup_file=args.setup, rpm_range=args.rpm, n_rpm=args.n_rpm,
                            n_freq=args.n_freq, tool_model=tool_model)
    result = run_atlas(problem, region, scheduler=args.scheduler, n_workers=args.workers,
                       points_per_chunk=args.chunk_points, progress=not args.no_progress,
                       connect_timeout_s=args.connect_timeout_s, method=args.method, n_verify=args.sdm_verify)
    table = out_dir / "atlas.parquet"
    figures = {}
    if not args.no_plots:
        figures = {"mrr": str(out_dir / "atlas_mrr.png"), "rotation": str(out_dir / "atlas_rotation.png")}
    # every output is complete before any is put in place: the table last, once the figures exist
    with atomic_write(out_dir, directory=True, last=("atlas.parquet",)) as tmp:
        for which, path in figures.items():
            fig, _ = result.plot(which)
            save_figure(fig, str(tmp / Path(path).name))
        write_table(tmp / "atlas.parquet", result.columns,
                    metadata={"format": "robomill-atlas/1", **result.to_dict(), "robot": str(args.robot),
                              "setup": str(args.setup)})
    payload = {**result.to_dict(), "table": str(table), "figures": figures}
    emit(args, payload, _human)
    return EXIT_OK
