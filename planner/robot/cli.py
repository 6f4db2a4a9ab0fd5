"""``robomill robot calibrate`` and ``robomill robot model`` (cli.md), and the ``--robot ROBOT
--joints-deg Q1..Q6 [--tool-model MODEL]`` alternative to ``--model`` of lobes, predict, plan and
simulate. Parses, calls :mod:`planner.robot`, prints; no numerics here."""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from planner.cli_common import EXIT_OK, UsageError, add_json, declare_outputs, emit, finite

__all__ = ["add_parsers", "add_robot_options", "model_from_robot_args"]


def add_robot_options(p: argparse.ArgumentParser) -> None:
    """The ``--robot ROBOT --joints-deg Q1..Q6 [--tool-model MODEL]`` options (instead of ``--model``)."""
    p.add_argument("--robot", default=None, help="a calibrated robomill-robot/1 file (instead of --model)")
    p.add_argument("--joints-deg", type=finite, nargs=6, default=None, metavar="Q",
                   help="with --robot: the pose, URDF joint values in degrees")
    p.add_argument("--tool-model", default=None, help="with --robot: spindle/tool modes in series (modal model)")


def _pose_model(robot_path: str, joints_deg, tool_model_path: str | None):
    from oma.modal_io import read_modal_model

    from .calibrate import trust
    from .description import RobotError, read_robot
    from .dynamics import robot_modal_model

    robot = read_robot(robot_path)
    try:
        q = robot.check_joints(np.radians(joints_deg))
    except RobotError as exc:
        raise UsageError("--joints-deg", exc.expected, exc.found) from None
    if robot.joint_stiffness_N_m_rad is None:
        raise RobotError(robot.file, "joints.stiffness_N_m_rad", "joint stiffness (a calibrated robot: robomill "
                         "robot calibrate)", "none")
    tool = read_modal_model(tool_model_path) if tool_model_path else None
    model = robot_modal_model(robot, q, tool_model=tool)
    return model.with_modes(joints_deg=np.asarray(joints_deg, float)), trust(robot, q)


def model_from_robot_args(args):
    """The modal model at ``--joints-deg`` from ``--robot`` (and ``--tool-model``); warns on
    stderr when the pose is not trusted."""
    if args.joints_deg is None:
        raise UsageError("--joints-deg", "six joint angles (deg) with --robot", "nothing")
    model, verdict = _pose_model(args.robot, args.joints_deg, args.tool_model)
    for message in verdict.warnings:
        warnings.warn(f"--robot: {message} (trusted: false)", stacklevel=2)
    return model


def _cmd_model(args) -> int:
    from oma.modal_io import modal_model_to_dict, write_modal_model

    model, verdict = _pose_model(args.robot, args.joints_deg, args.tool_model)
    if args.output:
        write_modal_model(model, args.output)
    payload = {"model": modal_model_to_dict(model), "trusted": verdict.trusted,
               "frequency_sd": verdict.frequency_sd, "warnings": list(verdict.warnings)}
    if args.output:
        payload["path"] = args.output

    def human(p):
        lines = [f"tool-tip model at {np.round(args.joints_deg, 3).tolist()} deg "
                 f"({'trusted' if p['trusted'] else 'NOT trusted'}):"]
        lines += [f"  {f:7.2f} Hz  zeta {100 * z:5.2f} %  k {k:.3g} N/m  direction {np.round(u, 3).tolist()}"
                  for f, z, k, u in zip(model.natural_frequency_hz, model.damping_ratio, model.stiffness_N_m,
                                        model.directions)]
        lines += [f"  warning: {w}" for w in p["warnings"]]
        if args.output:
            lines.append(f"model written to {args.output}")
        return "\n".join(lines)

    emit(args, payload, human)
    return EXIT_OK


def _cmd_calibrate(args) -> int:
    from oma.modal_io import read_modal_model

    from .calibrate import calibrate
    from .description import read_robot, write_robot

    robot = read_robot(args.robot)
    models = [read_modal_model(path) for path in args.models]
    choice = {"auto": "auto", "on": True, "off": False}[args.correction]
    result = calibrate(robot, models, names=args.models, correction=choice)
    write_robot(result.robot, args.output)
    payload = {"robot": args.output, **result.to_dict()}

    def human(p):
        lines = ["joint stiffness (N m/rad): " + ", ".join(
            f"{k:.3g}{'' if ok else ' (?)'}" for k, ok in zip(p["joint_stiffness_N_m_rad"], p["identifiable"]))]
        lines.append("fit error per model: " + ", ".join(f"{100 * e:.1f} %" for e in p["fit_error"]))
        if p["leave_one_out"]:
            lines.append("leave-one-out frequency error: " + ", ".join(
                f"{100 * r['frequency_error']:.1f} %" for r in p["leave_one_out"]))
        lines.append(f"next pose to identify (deg): {np.round(p['next_pose_deg'], 1).tolist()}")
        lines += [f"  warning: {w}" for w in p["warnings"]]
        lines.append(f"robot written to {args.output}")
        return "\n".join(lines)

    emit(args, payload, human)
    return EXIT_OK


def add_parsers(sub) -> None:
    """Add ``robot calibrate`` and ``robot model`` to the ``robomill`` subparsers."""
    robot = sub.add_parser("robot", help="the robot as a physical model: calibrate, model at any pose")
    robot_sub = robot.add_subparsers(dest="robot_command", required=True, parser_class=type(robot))

    p = robot_sub.add_parser("calibrate", help="fit joint stiffness and damping to modal models at several poses")
    p.add_argument("robot", help="robomill-robot/1 file")
    p.add_argument("--models", nargs="+", required=True, help="modal models, each with pose.joints_deg")
    p.add_argument("-o", "--output", required=True, help="calibrated robot file to write")
    p.add_argument("--correction", choices=["auto", "on", "off"], default="auto",
                   help="the reach correction of the rigid-link model (auto: kept when it lowers the "
                        "leave-one-out error)")
    add_json(p)
    declare_outputs(p, ("-o", "output", "file"))
    p.set_defaults(handler=_cmd_calibrate)

    p = robot_sub.add_parser("model", help="the tool-tip modal model at any pose from a calibrated robot")
    p.add_argument("robot", help="calibrated robomill-robot/1 file")
    p.add_argument("--joints-deg", type=finite, nargs=6, required=True, metavar="Q",
                   help="URDF joint values, deg")
    p.add_argument("--tool-model", default=None, help="spindle/tool modes in series (modal model)")
    p.add_argument("-o", "--output", default=None, help="modal model to write (robomill-modal/1)")
    add_json(p)
    declare_outputs(p, ("-o", "output", "file"))
    p.set_defaults(handler=_cmd_model)
