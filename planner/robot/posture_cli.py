"""``robomill posture TOOLPATH --robot ROBOT [-o TOOLPATH_OUT]`` (cli.md): parse, call
:func:`planner.robot.posture.choose_posture`, write the toolpath with joints, print."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from planner.cli_common import EXIT_NEGATIVE, EXIT_OK, UsageError, add_json, declare_outputs, emit, save_figure

__all__ = ["add_parsers"]


def _cmd_posture(args) -> int:
    from planner.robot.path import read_cell
    from planner.robot.posture import choose_posture
    from planner.toolpath_io import read_toolpath, write_toolpath

    if args.rotations < 2:
        raise UsageError("--rotations", "an integer >= 2", repr(args.rotations))
    if args.stations is not None and args.stations < 2:
        raise UsageError("--stations", "an integer >= 2", repr(args.stations))
    if args.output and Path(args.output).resolve() == Path(args.toolpath).resolve():
        raise UsageError("-o", "a file other than the input toolpath", args.output)
    toolpath = read_toolpath(args.toolpath)
    robot, tool_model = read_cell(toolpath, args.robot, args.tool_model, args.toolpath)
    result = choose_posture(robot, toolpath, tool_model=tool_model, n_rotations=args.rotations,
                            stations=args.stations)
    written = None
    if args.output:
        # the output names its own points file after itself: keeping the input's name beside an
        # output in the same folder overwrote the input's points (the audit of session 14)
        out = replace(result.toolpath, points_file=Path(args.output).stem + ".csv")
        if args.robot:
            out = replace(out, robot_file=args.robot)
        written = str(write_toolpath(out, args.output))
    if args.figure:
        fig, _ = result.plot()
        save_figure(fig, args.figure)
    payload = result.to_dict()
    payload["toolpath"] = written

    def human(p):
        fmt = lambda x: "n/a" if x is None else f"{x:.3g}"  # noqa: E731
        lines = [f"{p['points']} points: smallest stability margin {fmt(p['min_margin_before'])} before, "
                 f"{fmt(p['min_margin_after'])} after (branch {p['branch']})"]
        if p["unreachable"]:
            lines.append(f"  unreachable: {len(p['unreachable'])} point(s), first {p['unreachable'][0]}")
        lines += [f"  note: {n}" for n in p["notes"]]
        if written:
            lines.append(f"toolpath written to {written}")
        return "\n".join(lines)

    emit(args, payload, human)
    return EXIT_NEGATIVE if result.unreachable else EXIT_OK


def add_parsers(sub) -> None:
    p = sub.add_parser("posture", help="choose the rotation about the tool axis (and the joints) along a toolpath")
    p.add_argument("toolpath")
    p.add_argument("--robot", default=None, help="a calibrated robomill-robot/1 file (default: the toolpath's)")
    p.add_argument("--tool-model", default=None, help="spindle/tool modes, in series with the robot's")
    p.add_argument("--rotations", type=int, default=36, help="rotation grid over a turn (default 36: 10 deg)")
    p.add_argument("--stations", type=int, default=64,
                   help="points the margins are computed at, the rest interpolated (default 64)")
    p.add_argument("-o", "--output", default=None, help="toolpath to write, with joints and tool_rotation_deg")
    p.add_argument("--figure", default=None, help="figure: the path coloured by margin before and after")
    add_json(p)
    declare_outputs(p, ("-o", "output", "file"), ("--figure", "figure", "figure"))
    p.set_defaults(handler=_cmd_posture)
