"""The ``robomill`` command line (cli.md): parse, call the library, print.

Exit codes: 0 done; 1 done with a negative answer; 2 bad input (one line on stderr, no traceback);
3 internal failure. With ``--json`` exactly one JSON object goes to standard output; everything else
(human text, progress, warnings) goes to standard error.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from oma.errors import InputError, ToolpathError
from planner.cli_common import (EXIT_INPUT, EXIT_INTERNAL, EXIT_NEGATIVE, EXIT_OK, Parser, UsageError,
                                add_json, add_model_options, check_outputs, coefficients, declare_outputs, emit,
                                finite, load_structure, naming_files, rpm_range, save_figure,
                                structure_from_args)

__all__ = ["main", "UsageError", "build_parser"]

# --------------------------------------------------------------------------------------- handlers
# Each handler returns an exit code. Library imports happen inside, so `robomill --help` is fast.


def _structure_for(args):
    """``lobes``/``predict``: the structure, and measured FRFs only with the ZOA (the SDM integrates
    the modes in time)."""
    from oma.modal import ModalModel

    structure = structure_from_args(args, frf=True)
    if args.method == "sdm" and not isinstance(structure, ModalModel):
        raise UsageError("--method", "zoa with measured FRFs (sdm needs a modal model)", "sdm")
    return structure


def _cmd_lobes(args) -> int:
    from stability.lobes import lobe_diagram
    from stability.setup_io import read_setup

    if args.n_rpm is not None and args.n_rpm < 2:
        raise UsageError("--n-rpm", "an integer >= 2", repr(args.n_rpm))
    setup = read_setup(args.setup)
    structure = _structure_for(args)
    from planner.learn.cli import posterior_lobes

    diagram = lobe_diagram(structure, setup.tool, setup.cut, coefficients(setup, args.setup),
                           rpm_range=rpm_range(args, setup), method=args.method, n_rpm=args.n_rpm)
    learned, tests = (posterior_lobes(args.model, setup, rpm_range(args, setup)) if args.model
                      else (None, None))  # x_posterior, and the test cuts its file carries
    if args.output:
        if learned is None:
            fig, _ = diagram.plot()
        else:  # with the test cuts, the stable marks the posterior doubts in grey
            fig, _ = learned.plot(cuts=getattr(tests, "cuts", None), mislabelled=getattr(tests, "mislabelled", None))
        save_figure(fig, args.output)
    payload = diagram.to_dict()
    if learned is not None:
        payload["probability_lobes"] = learned.to_dict()
    emit(args, payload, lambda p: (
        f"{p['method']} lobes, {len(p['rpm'])} speeds; smallest limit depth "
        f"{1e3 * diagram.min_depth_limit_m:.3f} mm" + (f"; figure: {args.output}" if args.output else "")))
    return EXIT_OK


def _cmd_predict(args) -> int:
    from planner.wall import wall_extremum
    from stability.lobes import predict_point
    from stability.setup_io import read_setup

    setup = read_setup(args.setup)
    structure = _structure_for(args)
    for option, value in (("--rpm", args.rpm), ("--depth", args.depth)):
        if not value > 0:
            raise UsageError(option, "a positive number", repr(value))
    point = predict_point(structure, setup.tool, setup.cut, coefficients(setup, args.setup),
                          spindle_rpm=args.rpm, axial_depth_m=args.depth, method=args.method)
    # formats.md's limit bounds |SLE| on the whole finished wall, not at the tip: where it is largest
    wall_m, wall_height_m = wall_extremum(point, setup.tool, setup.cut)
    payload = point.to_dict()
    payload.update(surface_error_max_m=wall_m, surface_error_max_height_m=wall_height_m)
    emit(args, payload, lambda p: "\n".join([
        f"{'stable' if p['stable'] else 'CHATTER'} at {args.rpm:.0f} rpm, depth {1e3 * args.depth:.3f} mm "
        f"(limit {1e3 * point.depth_limit_m:.3f} mm, {args.method})",
        f"surface location error {1e6 * point.surface_location_error_m:+.1f} um at the tool tip, "
        f"{1e6 * wall_m:+.1f} um on the wall at z = {1e3 * wall_height_m:.2f} mm (largest |SLE|)",
        f"peak force {point.peak_force_N:.0f} N, power {point.power_W:.0f} W, MRR {1e6 * point.mrr_m3_s:.2f} cm^3/s"]))
    return EXIT_OK


def _cmd_identify_output_only(args) -> int:
    """``identify --output-only``: modes from the motion channels, stiffness from the force model;
    with force channels in the records, also the force-based identification and the comparison."""
    from oma.identify import identify
    from oma.modal_io import write_modal_model
    from oma.output_only.identify import compare_models, identify_output_only
    from oma.record_io import read_record

    if not 0 <= args.coefficient_uncertainty < 1:
        raise UsageError("--coefficient-uncertainty", "a relative standard deviation in [0, 1)",
                         repr(args.coefficient_uncertainty))
    if args.reference:
        raise UsageError("--reference", "no --reference with --output-only (compare the written model instead)",
                         " ".join(args.reference))
    records = [read_record(path) for path in args.records]
    band = {}
    if args.band:
        if not 0 < args.band[0] < args.band[1]:
            raise UsageError("--band", "0 < LO < HI (Hz)", f"{args.band[0]:g} {args.band[1]:g}")
        band["band_hz"] = (float(args.band[0]), float(args.band[1]))
    result = identify_output_only(records, scaling=args.scale_with, coefficient_relative_sd=args.coefficient_uncertainty,
                                  **band)
    payload = result.to_dict()
    if all(r.has("force") for r in records) and result.model.n_modes:
        force_based = identify(records, method=args.method)
        comparison = compare_models(
            result.model, force_based.model, standard_errors=(result.modes.freq_se_hz, result.modes.damping_se),
            reference_standard_errors=force_based.standard_errors()[:2])
        ok = [c["stiffness_ratio"] for c, far in zip(comparison, result.stiffness.too_far if result.stiffness
                                                                  is not None else [True] * len(comparison))
              if c.get("stiffness_ratio") is not None and not far]
        # the stiffness scales with the coefficients one for one: their ratio is the coefficients' error
        fb = force_based.to_dict()
        payload["force_based"] = {"model": fb["model"], "trusted": bool(force_based.trusted),
                                  **{key: fb.get(key) for key in ("frf_fit_error", "noise_variance_N2",
                                                                  "min_noise_variance_N2", "excitation_sufficient")},
                                  "comparison": comparison,
                                  "coefficient_ratio": float(np.median(ok)) if ok else None}
    written = bool(args.output) and result.scaled
    if written:
        write_modal_model(result.model, args.output)
    elif args.output:
        payload["warnings"].append(f"no model written to {args.output}: the modes are not scaled")
    if args.plot:
        save_figure(result.plot()[0], args.plot)

    def human(p):
        m = result.model
        lines = [f"{m.n_modes} modes, output-only, scaling {p['scaling']} "
                 f"({'trusted' if result.trusted else 'NOT trusted'}):"]
        for mode in p["modes"]:
            su = mode["stiffness_uncertainty"]
            k = f"k {su['stiffness_N_m']:.3g} N/m +-{100 * su['relative_sd']:.0f} %" if su["stiffness_N_m"] else "k ?"
            if su.get("scaled_by") == "background":
                k += f" (background level, from the {(p.get('background_force') or {}).get('source', 'resonances')})"
            lines.append(f"  {mode['natural_frequency_hz']:7.2f} Hz [{mode['frequency_interval_hz'][0]:.2f}, "
                         f"{mode['frequency_interval_hz'][1]:.2f}]  zeta {100 * mode['damping_ratio']:5.2f} % "
                         f"[{100 * mode['damping_interval'][0]:.2f}, {100 * mode['damping_interval'][1]:.2f}]  {k}  "
                         f"direction {np.round(mode['direction'], 3).tolist()}")
        for c in p.get("force_based", {}).get("comparison", []):
            if c.get("reference_natural_frequency_hz") is not None:
                zs = "" if c.get("frequency_z") is None or c.get("damping_z") is None else \
                    f" (differences {c['frequency_z']:+.1f} and {c['damping_z']:+.1f} combined sds)"
                lines.append(f"  vs force-based {c['reference_natural_frequency_hz']:.2f} Hz: frequency x"
                             f"{c['frequency_ratio']:.3f}, damping x{c['damping_ratio_ratio']:.2f}, stiffness x"
                             + (f"{c['stiffness_ratio']:.2f}" if c["stiffness_ratio"] is not None else "?") + zs)
        ratio = p.get("force_based", {}).get("coefficient_ratio")
        if ratio is not None:
            lines.append(f"  the cutting coefficients look x{ratio:.2f} of what the force channels say "
                         "(output-only stiffness over force-based, scaled modes)")
        lines += [f"  warning: {w}" for w in p["warnings"]]
        if written:
            lines.append(f"model written to {args.output}")
        return "\n".join(lines)

    emit(args, payload, human)
    if args.output and not written:
        return EXIT_NEGATIVE
    return EXIT_NEGATIVE if (args.strict and not result.trusted) else EXIT_OK


def _cmd_identify(args) -> int:
    if args.output_only:
        return _cmd_identify_output_only(args)
    from oma.identify import ROBOT_BAND_HZ, identify
    from oma.modal_io import write_modal_model
    from oma.record_io import read_record

    records = [read_record(path) for path in args.records]
    reference = load_structure(args.reference, args.reference_axis, option="--reference",
                                axis_option="--reference-axis") if args.reference else None
    band = (float(args.band[0]), float(args.band[1])) if args.band else ROBOT_BAND_HZ
    if not 0 <= band[0] < band[1]:
        raise UsageError("--band", "0 <= LO < HI (Hz)", f"{band[0]:g} {band[1]:g}")
    if reference is not None:
        from oma.frf_table import FRFTable

        if not hasattr(reference, "freq_hz"):  # a modal model as the reference: its FRF on 0.1 Hz lines
            reference = FRFTable.from_model(reference, np.arange(max(band[0], 0.1), band[1] + 1e-9, 0.1))
        f_ref = np.asarray(reference.freq_hz)
        if not np.any((f_ref >= band[0]) & (f_ref <= band[1])):
            raise UsageError("--band", f"a band with lines of the reference ({f_ref.min():g}-{f_ref.max():g} Hz)",
                             f"{band[0]:g}-{band[1]:g} Hz")
    result = identify(records, method=args.method)
    payload = result.to_dict()
    if reference is not None:
        from oma.frf_estimate import frf_agreement

        agreement = frf_agreement(FRFTable.from_model(result.model, f_ref), reference, band)
        payload["reference_agreement"] = {"band_hz": list(band), **agreement}
    if args.output:
        write_modal_model(result.model, args.output)
    if args.plot:
        drawn = result.plot_frf(reference)
        fig = drawn[0] if isinstance(drawn, tuple) else drawn
        save_figure(fig, args.plot)
    sufficient = np.asarray(result.excitation_sufficient, dtype=bool)

    def human(p):
        m = result.model
        lines = [f"{m.n_modes} modes ({'trusted' if result.trusted else 'NOT trusted'}):"]
        unc = p["uncertainty"]

        def bars(mode):
            if not unc["available"]:
                return ""
            fi, zi = mode["frequency_interval_hz"], mode["damping_interval"]
            return (f"  ({100 * unc['level']:.0f} %: {fi[0]:.2f}-{fi[1]:.2f} Hz, zeta {100 * zi[0]:.2f}-"
                    f"{100 * zi[1]:.2f} %)")

        lines += [f"  {f:7.2f} Hz  zeta {100 * z:5.2f} %  k {k:.3g} N/m  direction {np.round(u, 3).tolist()}{bars(mu)}"
                  for f, z, k, u, mu in zip(m.natural_frequency_hz, m.damping_ratio, m.stiffness_N_m, m.directions,
                                            unc["modes"])]
        lines += [f"  warning: {w}" for w in result.warnings]
        if "reference_agreement" in p:
            ra = p["reference_agreement"]
            lines.append(f"agreement with the reference, {ra['band_hz'][0]:g}-{ra['band_hz'][1]:g} Hz (relative "
                         "2-norm error): " + ", ".join(f"{a} {100 * ra[a]:.1f} %" for a in "XYZ" if a in ra))
        if args.output:
            lines.append(f"model written to {args.output}")
        return "\n".join(lines)

    emit(args, payload, human)
    return EXIT_NEGATIVE if (args.strict and not sufficient.all()) else EXIT_OK


def _cmd_check(args) -> int:
    from oma.modal_io import read_modal_model
    from planner.check import check_toolpath
    from planner.toolpath_io import read_toolpath

    toolpath = read_toolpath(args.toolpath)
    if args.models and args.robot:
        raise UsageError("--robot", "either --models or --robot", "both")
    if args.models:
        if args.tool_model:
            raise UsageError("--tool-model", "used with --robot only (with --models, each model holds every mode)",
                             args.tool_model)
        if not toolpath.has_joints:
            raise ToolpathError(args.toolpath, "q1_deg..q6_deg", "joint angles at every point to check against "
                                "models at poses (or check it with --robot)", "points without them")
        models = [read_modal_model(path) for path in args.models]
        with naming_files(args.toolpath, args.models):
            result = check_toolpath(toolpath, models, method=args.method, progress=not args.json)
    else:
        from planner.robot.path import read_cell

        robot, tool_model = read_cell(toolpath, args.robot, args.tool_model, args.toolpath)
        result = check_toolpath(toolpath, robot=robot, tool_model=tool_model, method=args.method,
                                progress=not args.json)
    if args.output:
        fig, _ = result.plot()
        save_figure(fig, args.output)
    payload = result.to_dict()

    def human(p):
        counts = result.counts()
        lines = [f"{p['points']} points, {len(p['violations'])} violations"
                 + (": " + ", ".join(f"{k} {v}" for k, v in counts.items() if v) if p["violations"] else "")]
        lines += [f"  note: {n}" for n in result.notes]
        if args.output:
            lines.append(f"figure: {args.output}")
        return "\n".join(lines)

    emit(args, payload, human)
    return EXIT_OK if result.ok else EXIT_NEGATIVE


def _cmd_plan(args) -> int:
    from planner.optimize import plan
    from stability.setup_io import read_setup

    from planner.learn.cli import chance_constraint, report_support, verify_plan

    setup = read_setup(args.setup)
    model = structure_from_args(args)
    limit, learned, tests = (chance_constraint(args.model, setup, probability=args.probability) if args.model
                             else (None, None, None))  # a model with x_posterior: the chance constraint
    with naming_files(args.setup):
        result = plan(setup, model, method=args.method, stability_limit=limit)
    payload = result.to_dict()
    if learned is not None:
        if result.success:
            verify_plan(limit, learned, payload["spindle_rpm"], payload["axial_depth_m"])
            report_support(learned, tests, setup, model, payload, method=args.method)
        payload["learned"] = learned
    if args.output:
        fig, ax = result.plot(limit_label=None if learned is None else f"P(stable) >= {args.probability:g}")
        if learned is not None:  # where the chance limit holds, and what the test cuts prove beside it
            from planner.learn.plots import draw_best_backed, draw_test_cuts, shade_untabulated
            from planner.learn.support import doubt_level

            shade_untabulated(ax, learned["rpm_range"], setup.limits.spindle_rpm)
            if tests is not None:
                draw_test_cuts(ax, tests.cuts, setup.cut.radial_depth_m, setup.cut.milling,
                               mislabelled=tests.mislabelled, max_doubt=doubt_level(args.probability))
                draw_best_backed(ax, (learned.get("support") or {}).get("best_backed"))
            # beside the axes: inside, the longer legend hides test cuts
            w, h = fig.get_size_inches()
            fig.set_size_inches(w * 1.4, h)
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
            fig.tight_layout()
        save_figure(fig, args.output)

    def human(p):
        if not p["success"]:
            return f"no plan ({result.status}): {result.message}"
        height = p.get("surface_error_height_m")
        active = [f"surface_error (at z = {1e3 * height:.2f} mm on the wall)"
                  if a == "surface_error" and height is not None else a for a in p["active_constraints"]]
        text = (f"{p['spindle_rpm']:.0f} rpm, axial depth {1e3 * p['axial_depth_m']:.2f} mm, feed "
                f"{1e3 * p['feed_per_tooth_m']:.3f} mm/tooth: MRR {1e6 * p['mrr_m3_s']:.2f} cm^3/s; active: "
                + (", ".join(active) or "none"))
        learned_ = p.get("learned") or {}
        check = learned_.get("check")
        if check:
            text += (f"\nP(stable) of the planned cut, {check['samples']} posterior samples solved directly: "
                     f"{check['probability_stable']:.3f} +- {check['standard_error']:.3f} (the limit table: "
                     f"{check['table_probability_stable']:.3f})")
        support = learned_.get("support")
        if support:
            text += (f"\ntest cuts within {100 * support['speed_tolerance']:g} % of its speed: {support['status']}"
                     + (f" (cut {', '.join(map(str, support['backed_by']))})" if support["status"] == "backed" else ""))
            alt = support.get("best_backed")
            if alt:
                from planner.learn.support import describe_best_backed

                text += f"\nbest cut a stable test cut proves: {describe_best_backed(alt)}"
            elif support["status"] != "backed":
                text += ("\nno sure stable test cut (marks the posterior takes for wrong with P > "
                         f"{support.get('max_doubt', 0.5):g} left out) proves a cut at the plan's engagement within the "
                         "setup's limits")
        return "\n".join([text] + [f"warning: {w}" for w in learned_.get("warnings", [])])

    emit(args, payload, human)
    if result.success:
        return EXIT_OK
    return EXIT_NEGATIVE if result.status == "infeasible" else EXIT_INTERNAL


def _cmd_diagnose(args) -> int:
    from oma.modal_io import read_modal_model
    from oma.record_io import read_record
    from planner.diagnosis import diagnose

    records = [read_record(path) for path in args.records]
    model = read_modal_model(args.model)
    result = diagnose(records, model)
    if args.output:
        drawn = result.plot()
        save_figure(drawn[0] if isinstance(drawn, tuple) else drawn, args.output)
    payload = result.to_dict()

    def human(p):
        def num(x, fmt):  # a cause whose fit failed has no gain (JSON null)
            return "n/a" if x is None else format(x, fmt)

        lines = [f"cause: {p['cause']}" + (f"  parameters: {p['parameters']}" if p["parameters"] else ""),
                 f"validation error {num(p['error_before'], '.3g')} -> {num(p['error_after'], '.3g')} "
                 f"(gain {num(p['gain'], '.2f')})",
                 "ranking: " + ", ".join(f"{r['cause']} {num(r['gain'], '.2f')}" for r in p["ranking"])]
        return "\n".join(lines)

    emit(args, payload, human)
    return EXIT_OK


def _cmd_simulate(args) -> int:
    from stability.setup_io import read_setup
    from oma.record_io import write_record
    from stability.simulate import BackgroundForce, SensorModel, SimulationDiverged, simulate

    setup = read_setup(args.setup)
    model = structure_from_args(args)
    cutting = coefficients(setup, args.setup)
    for option, value in (("--rpm", args.rpm), ("--depth", args.depth), ("--duration", args.duration),
                          ("--sample-rate", args.sample_rate)):
        if not value > 0:
            raise UsageError(option, "a positive number", repr(value))
    background = None
    if args.background_variance is not None:
        if any(v < 0 for v in args.background_variance):
            raise UsageError("--background-variance", "three variances >= 0 (N^2)", repr(args.background_variance))
        background = BackgroundForce(variance_N2=tuple(args.background_variance), bandwidth_hz=args.background_bandwidth)
    cut = replace(setup.cut, spindle_rpm=args.rpm, axial_depth_m=args.depth)
    sensors = SensorModel(
        force_noise_variance_N2=args.force_noise_variance,
        displacement_resolution_m=args.displacement_resolution,
    )
    try:
        result = simulate(
            model, setup.tool, cut, cutting,
            duration_s=args.duration, sample_rate_hz=args.sample_rate, background=background,
            sensors=sensors, seed=args.seed, progress=not args.json,
        )
    except SimulationDiverged as exc:
        raise UsageError("--depth", exc.expected, exc.found) from None
    record = result.to_record(setup.tool, cut, material=setup.material, name=Path(args.output).name,
                              joints_deg=model.joints_deg)
    write_record(record, args.output)
    payload = {"record": str(Path(args.output))}
    emit(args, payload, lambda p: f"record written to {p['record']}")
    return EXIT_OK


def _cmd_demo(args) -> int:
    from planner.demo import run_demo

    kwargs = {} if args.example is None else {"example_dir": Path(args.example)}
    summary = run_demo(Path(args.output), progress=not args.json, **kwargs)
    emit(args, summary, lambda p: f"report: {p['report']}")
    return EXIT_OK


# ----------------------------------------------------------------------------------------- parser

#: Command groups that live in their own sub-package; each module has ``add_parsers(sub)``, which
#: adds its subcommands (with ``handler`` defaults) to the ``robomill`` subparsers.
COMMAND_GROUPS: tuple[str, ...] = ("planner.robot.cli", "planner.robot.posture_cli", "planner.atlas.cli",
                                   "planner.learn.cli")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="robomill", description="Robotic milling: identify, predict, plan, check.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log diagnostics to stderr")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    p = sub.add_parser("identify", help="OMA: the tool-tip modal model from milling records of one pose")
    p.add_argument("records", nargs="+", help="record directories (or their record.yaml)")
    p.add_argument("-o", "--output", default=None, help="modal model to write (robomill-modal/1 YAML)")
    p.add_argument("--method", choices=["default", "h1"], default="default",
                   help="default: time-domain fit refining the H1 fit; h1: the paper's estimator + fit")
    p.add_argument("--plot", default=None, help="figure file of the identified FRF (.png, .pdf, .svg)")
    p.add_argument("--strict", action="store_true", help="exit 1 when the excitation is insufficient")
    p.add_argument("--reference", nargs="+", default=None,
                   help="a hammer-test FRF (.csv, .uff, .frf) or a modal model (.yaml) to compare with")
    p.add_argument("--reference-axis", nargs="+", default=None, choices=["X", "Y", "Z"],
                   help="the axis of each .frf reference file, in order")
    p.add_argument("--band", nargs=2, type=finite, default=None, metavar=("LO", "HI"),
                   help="band of the comparison, Hz (default 5-40, the robot's structural modes); with "
                        "--output-only the band analysed (default 4-100)")
    p.add_argument("--output-only", action="store_true",
                   help="identify from the vibration channels alone, scaled by the cutting-force model")
    p.add_argument("--coefficient-uncertainty", type=finite, default=0.15,
                   help="with --output-only: relative sd of the cutting coefficients (default 0.15)")
    p.add_argument("--scale-with", choices=["force_model", "measured_force"], default="force_model",
                   help="with --output-only: the force lines that scale the modes (default: the cutting-force model)")
    add_json(p)
    declare_outputs(p, ("-o", "output", "file"), ("--plot", "plot", "figure"))
    p.set_defaults(handler=_cmd_identify)

    p = sub.add_parser("plan", help="recommended spindle speed, depth and feed")
    p.add_argument("setup")
    add_model_options(p, frf=False)
    p.add_argument("--method", choices=["auto", "zoa", "sdm"], default="auto",
                   help="stability limit: auto = SDM below ae/D 0.2 (flip lobes), else ZOA")
    p.add_argument("-o", "--output", default=None, help="figure of the lobes with the optimum")
    p.add_argument("--probability", type=finite, default=0.95,
                   help="with a learned posterior (x_posterior): plan for P(stable) >= this")
    add_json(p)
    declare_outputs(p, ("-o", "output", "figure"))
    p.set_defaults(handler=_cmd_plan)

    p = sub.add_parser("check", help="check a planned toolpath point by point")
    p.add_argument("toolpath")
    p.add_argument("--models", nargs="+", help="modal models at one or more robot poses")
    p.add_argument("--robot", default=None, help="a calibrated robomill-robot/1 file instead of --models "
                   "(default: the toolpath's robot)")
    p.add_argument("--tool-model", default=None, help="with --robot: spindle/tool modes, in series")
    p.add_argument("--method", choices=["zoa", "sdm"], default="zoa")
    p.add_argument("-o", "--output", default=None, help="figure of the path coloured by stability margin")
    add_json(p)
    declare_outputs(p, ("-o", "output", "figure"))
    p.set_defaults(handler=_cmd_check)

    p = sub.add_parser("diagnose", help="compare measurement with simulation, name the cause, measure the gain")
    p.add_argument("records", nargs="+")
    p.add_argument("--model", required=True)
    p.add_argument("-o", "--output", default=None, help="figure: residuals, FRF with/without the extension, evidence")
    add_json(p)
    declare_outputs(p, ("-o", "output", "figure"))
    p.set_defaults(handler=_cmd_diagnose)

    p = sub.add_parser("simulate", help="time-domain simulation of a cut, written as a record")
    p.add_argument("setup")
    add_model_options(p, frf=False)
    p.add_argument("--rpm", type=finite, required=True)
    p.add_argument("--depth", type=finite, required=True, help="axial depth of cut, m")
    p.add_argument("--duration", type=finite, required=True, help="s")
    p.add_argument("-o", "--output", required=True, help="record directory to write")
    p.add_argument("--sample-rate", type=finite, default=1000.0, help="record sample rate, Hz (default 1000)")
    p.add_argument("--seed", type=int, default=None, help="random seed (noise, background force)")
    p.add_argument("--background-variance", type=finite, nargs=3, metavar=("VX", "VY", "VZ"), default=None,
                   help="broadband background force variance per machine axis, N^2 (default none)")
    p.add_argument("--background-bandwidth", type=finite, default=200.0, help="Hz (default 200)")
    p.add_argument("--force-noise-variance", type=finite, default=0.56, help="force sensor noise, N^2 (default 0.56)")
    p.add_argument("--displacement-resolution", type=finite, default=1.5e-5,
                   help="displacement sensor resolution, m (default 1.5e-5, a laser tracker)")
    add_json(p)
    declare_outputs(p, ("-o", "output", "directory"))
    p.set_defaults(handler=_cmd_simulate)

    for name, help_text in (("lobes", "stability lobe diagram"), ("predict", "one operating point")):
        p = sub.add_parser(name, help=help_text)
        p.add_argument("setup")
        add_model_options(p, frf=True)
        p.add_argument("--method", choices=["zoa", "sdm"], default="zoa")
        if name == "lobes":
            p.add_argument("--rpm", type=finite, nargs=2, metavar=("MIN", "MAX"), default=None,
                           help="speed range (default: the setup's limits.spindle_rpm)")
            p.add_argument("--n-rpm", type=int, default=None, help="number of speeds (default: method's own)")
            p.add_argument("-o", "--output", default=None, help="figure file (.png, .pdf, .svg)")
            declare_outputs(p, ("-o", "output", "figure"))
            p.set_defaults(handler=_cmd_lobes)
        else:
            p.add_argument("--rpm", type=finite, required=True)
            p.add_argument("--depth", type=finite, required=True, help="axial depth of cut, m")
            p.set_defaults(handler=_cmd_predict)
        add_json(p)

    p = sub.add_parser("demo", help="the whole job on the bundled example")
    p.add_argument("-o", "--output", default="out", help="output directory (default out/)")
    p.add_argument("--example", default=None, help="example cell directory (default: the bundled one)")
    add_json(p)
    declare_outputs(p, ("-o", "output", "directory"))
    p.set_defaults(handler=_cmd_demo)
    for module in COMMAND_GROUPS:
        importlib.import_module(module).add_parsers(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (cli.md)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return int(exc.code or 0)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr,
                        format="robomill: %(message)s")
    # Warnings are for people: one line each on stderr, never on stdout.
    warnings.showwarning = lambda message, category, *a, **k: sys.stderr.write(f"robomill: warning: {message}\n")
    try:
        check_outputs(args)
        return int(args.handler(args))
    except InputError as exc:
        sys.stderr.write(f"robomill: {exc}\n")
        return EXIT_INPUT
    except KeyboardInterrupt:
        sys.stderr.write("robomill: interrupted\n")
        return EXIT_INTERNAL
    except Exception as exc:  # an internal failure: say what, without a traceback unless -v
        if args.verbose:
            logging.exception("internal failure")
        sys.stderr.write(f"robomill: internal error: {type(exc).__name__}: {exc}\n")
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
