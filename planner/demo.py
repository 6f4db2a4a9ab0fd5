"""``robomill demo``: the whole job on the bundled example cell, one report.

Steps (each a function that adds a section to the report and keys to the JSON summary):
read and validate the example's files, look at the records.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from oma.modal_io import read_modal_model
from oma.record_io import read_record
from planner.report import Report
from planner.toolpath_io import read_toolpath
from stability.setup_io import read_setup

__all__ = ["run_demo", "EXAMPLE_DIR"]

log = logging.getLogger(__name__)

EXAMPLE_DIR = Path(__file__).resolve().parent.parent / "examples" / "kr500_acetal"


@dataclass
class Example:
    """The example cell's files, read and validated."""

    directory: Path
    records: dict
    references: dict
    setup: object
    planning_model: object
    tool_mode: object
    truth: object
    poses: list
    toolpath: object
    planning_label: str = "models/planning_model.yaml (truth + tool mode)"


def load_example(directory: Path = EXAMPLE_DIR) -> Example:
    from oma.frf_io import read_frf

    records, references = {}, {}
    for rec_dir in sorted((directory / "records").iterdir()):
        records[rec_dir.name] = read_record(rec_dir)
        ref = rec_dir / "reference_frf.csv"
        if ref.exists():
            references[rec_dir.name] = read_frf(ref)
    return Example(
        directory=directory,
        records=records,
        references=references,
        setup=read_setup(directory / "setup.yaml"),
        planning_model=read_modal_model(directory / "models" / "planning_model.yaml"),
        tool_mode=read_modal_model(directory / "models" / "tool_mode.yaml"),
        truth=read_modal_model(directory / "truth" / "robot_at_cut.yaml"),
        poses=[read_modal_model(p) for p in sorted((directory / "poses").glob("pose_*.yaml"))],
        toolpath=read_toolpath(directory / "toolpath.yaml"),
    )


def _step_records(example: Example, report: Report) -> None:
    from planner import plots

    sec = report.section("The example cell and its records")
    sec.text(
        "All example data are <b>simulated</b> by robomill's time-domain simulator to reproduce the "
        "experiment of Nguyen &amp; Melkote (2020): KR500-like robot modes, acetal, 2700 rpm, 2 flutes, "
        "fz 0.5 mm, ae 6 mm, ap 6 mm, force sensor and laser tracker at 1 kHz. See "
        "<code>examples/kr500_acetal/make_example.py</code> for every parameter."
    )
    rows, summary = [], {}
    for name, rec in example.records.items():
        force = rec.force
        disp = rec.displacement
        stats = {
            "duration_s": rec.duration_s,
            "mean_force_N": np.nanmean(force, axis=1),
            "force_std_N": np.nanstd(force, axis=1),
            "displacement_peak_to_valley_m": np.nanmax(disp, axis=1) - np.nanmin(disp, axis=1),
        }
        summary[name] = stats
        rows.append([name, rec.duration_s, *stats["mean_force_N"], *stats["force_std_N"],
                     *(1e6 * stats["displacement_peak_to_valley_m"])])
        fig = plots.plot_record(rec)
        sec.figure(report.save_figure(fig, f"record_{name}"), f"Record {name}: forces and tool-tip displacement")
    sec.table(["record", "duration s", "mean Fx N", "mean Fy N", "mean Fz N", "std Fx N", "std Fy N", "std Fz N",
               "p-v x um", "p-v y um", "p-v z um"], rows)
    report.summary["records"] = summary


from oma.identify import ROBOT_BAND_HZ as AGREEMENT_BAND_HZ  # noqa: E402 (the band of the robot modes)


def _step_identify(example: Example, report: Report) -> None:
    """OMA on each record (the paper's H1 and robomill's default), compared with the hammer test and
    with the simulation truth; the planning model is the identified robot plus the tool mode."""
    from oma.frf_estimate import frf_agreement
    from oma.frf_table import FRFTable
    from oma.identify import identify
    from oma.modal import in_series

    sec = report.section("Identification (OMA) from the milling records")
    sec.text("Harmonics of the spindle and tooth frequencies are located and kept out of the FRF; the "
             "background force variance is measured with them removed; the detectability check "
             "(the paper's Fig. 7, generalised) says whether the background force is enough for the "
             "tracker to see the modes. <i>h1</i> is the paper's estimator with a modal fit; "
             "<i>default</i> is robomill's time-domain fit. Agreement with the hammer test is the "
             f"relative 2-norm error of the direct FRFs in {AGREEMENT_BAND_HZ[0]:.0f}-"
             f"{AGREEMENT_BAND_HZ[1]:.0f} Hz.")
    truth = example.truth
    rows, summary, chosen = [], {}, None
    for name, rec in example.records.items():
        reference = example.references.get(name)
        for method in ("h1", "default"):
            result = identify([rec], method=method)
            model = result.model
            agreement = (frf_agreement(FRFTable.from_model(model, reference.freq_hz), reference, AGREEMENT_BAND_HZ)
                         if reference is not None else {})
            dominant = [int(np.argmax(np.abs(model.directions[:, i]) / model.stiffness_N_m)) for i in range(3)]
            for i, axis in enumerate("XYZ"):
                j = dominant[i]
                t = int(np.argmax(np.abs(truth.directions[:, i])))
                rows.append([name, method, axis, model.natural_frequency_hz[j], truth.natural_frequency_hz[t],
                             100 * model.damping_ratio[j], 100 * truth.damping_ratio[t],
                             model.stiffness_N_m[j] / 1e6, truth.stiffness_N_m[t] / 1e6,
                             result.noise_variance_N2[i], result.min_noise_variance_N2[i],
                             "yes" if result.excitation_sufficient[i] else "NO", agreement.get(axis, float("nan"))])
            summary[f"{name}/{method}"] = {
                "trusted": result.trusted, "frf_fit_error": result.frf_fit_error,
                "noise_variance_N2": result.noise_variance_N2,
                "min_noise_variance_N2": result.min_noise_variance_N2,
                "excitation_sufficient": result.excitation_sufficient,
                "hammer_agreement": agreement, "warnings": list(result.warnings),
                "model": {"natural_frequency_hz": model.natural_frequency_hz, "damping_ratio": model.damping_ratio,
                          "stiffness_N_m": model.stiffness_N_m},
            }
            if method == "default":
                drawn = result.plot_frf(reference)
                fig = drawn[0] if isinstance(drawn, tuple) else drawn
                sec.figure(report.save_figure(fig, f"frf_{name}"),
                           f"{name}: identified FRF (model and H1) versus the hammer test, with coherence")
                if name == "cut_long" or chosen is None:
                    chosen = (name, result)
        for w in summary[f"{name}/default"]["warnings"]:
            sec.text(f"<span class='warn'>{name}: {w}</span>")
    sec.table(["record", "method", "axis", "fn Hz", "true fn", "zeta %", "true zeta", "k MN/m", "true k",
               "noise var N2", "min var N2", "enough?", "hammer error"], rows)
    name, result = chosen
    drawn = result.plot_force_spectrum()
    sec.figure(report.save_figure(drawn[0] if isinstance(drawn, tuple) else drawn, "force_spectrum"),
               f"{name}: force spectrum with the milling harmonics marked")
    drawn = result.plot_detectability()
    sec.figure(report.save_figure(drawn[0] if isinstance(drawn, tuple) else drawn, "detectability"),
               f"{name}: peak-to-valley response versus background variance, and the tracker's resolution")
    report.summary["identification"] = summary
    # the planner's model: the identified robot (longest record, robomill's default) + the tool mode
    example.planning_model = in_series(result.model, example.tool_mode,
                                       source={"method": f"identified from {name} + tool mode"})
    example.planning_label = f"identified from {name} (default method) + tool mode"


def _step_shortcuts(example: Example, report: Report) -> None:
    """What the paper's own model gets wrong: harmonics left in, and the force sensor's dynamics ignored."""
    from planner.diagnosis.shortcuts import paper_shortcuts

    result = paper_shortcuts(records=[example.records["cut_short"]], truth=example.truth)
    sec = report.section("What the paper's shortcuts cost")
    sec.text("Two simplifications of Nguyen &amp; Melkote (2020), each measured on the example cut: "
             "identifying with the milling harmonics left in the spectra, and ignoring the force sensor's "
             "own resonance (the paper inverse-filters it; here a 200 Hz, 5 % sensor resonance is simulated).")
    rows = [[r["shortcut"], r["quantity"], r["with_shortcut"], r["without_shortcut"], r.get("truth", "")]
            for r in result.rows()]
    sec.table(["shortcut", "quantity", "with the shortcut", "without", "truth"], rows)
    report.summary["paper_shortcuts"] = result.rows()


def _step_lobes(example: Example, report: Report) -> None:
    """Lobes by ZOA and SDM over the setup's speed range, and the paper's operating point."""
    from stability.lobes import lobe_diagram, predict_point
    from stability.plots import plot_lobes

    setup = example.setup
    model, label = example.planning_model, example.planning_label
    coef = setup.material.cutting_coefficients
    rpm_range = setup.limits.spindle_rpm or (500.0, 24000.0)
    zoa = lobe_diagram(model, setup.tool, setup.cut, coef, rpm_range=rpm_range, method="zoa")
    sdm = lobe_diagram(model, setup.tool, setup.cut, coef, rpm_range=rpm_range, method="sdm", n_rpm=60)
    fig, ax = plot_lobes(zoa, sdm)
    paper = example.records["cut_short"].cut if "cut_short" in example.records else None
    sec = report.section("Stability lobes")
    sec.text(f"Model: {label}. Cut: {setup.tool.teeth} teeth, D = {1e3 * setup.tool.diameter_m:.1f} mm, "
             f"ae = {1e3 * setup.cut.radial_depth_m:.1f} mm, {setup.cut.milling} milling. ZOA: Altintas &amp; "
             "Budak (1995); SDM: Insperger &amp; Stepan (2004), step count chosen for 1 % accuracy.")
    rows = [["ZOA", len(zoa.rpm), 1e3 * zoa.min_depth_limit_m, zoa.elapsed_s],
            ["SDM", len(sdm.rpm), 1e3 * sdm.min_depth_limit_m, sdm.elapsed_s]]
    sec.table(["method", "speeds", "smallest limit depth mm", "time s"], rows)
    summary = {"zoa_min_depth_limit_m": zoa.min_depth_limit_m, "sdm_min_depth_limit_m": sdm.min_depth_limit_m,
               "zoa_time_s": zoa.elapsed_s, "sdm_time_s": sdm.elapsed_s}
    if paper is not None:
        ax.plot([paper.spindle_rpm], [1e3 * paper.axial_depth_m], "r*", ms=12, label="the paper's cut")
        ax.legend(loc="upper left", fontsize=8)
        point = predict_point(model, setup.tool, paper, coef, spindle_rpm=paper.spindle_rpm,
                              axial_depth_m=paper.axial_depth_m, method="sdm")
        sec.text(f"The paper's cut ({paper.spindle_rpm:.0f} rpm, ap {1e3 * paper.axial_depth_m:.1f} mm): "
                 f"{'stable' if point.stable else 'chatter'}, limit {1e3 * point.depth_limit_m:.2f} mm (SDM), "
                 f"surface location error {1e6 * point.surface_location_error_m:+.1f} um, peak force "
                 f"{point.peak_force_N:.0f} N, power {point.power_W:.0f} W.")
        summary["paper_cut"] = {k: v for k, v in point.to_dict().items()
                                if k in ("stable", "depth_limit_m", "surface_location_error_m", "peak_force_N",
                                         "power_W", "mrr_m3_s")}
    sec.figure(report.save_figure(fig, "lobes"), "Stability lobes: ZOA and SDM (flip and Hopf marked)")
    report.summary["lobes"] = summary


def _step_plan(example: Example, report: Report) -> None:
    """Recommended parameters for the setup with the planning model (CasADi/IPOPT per pocket)."""
    from planner.optimize import plan

    result = plan(example.setup, example.planning_model)
    sec = report.section("Recommended cutting parameters")
    if result.success:
        sec.text(f"<b>{result.spindle_rpm:.0f} rpm, axial depth {1e3 * result.axial_depth_m:.2f} mm, feed "
                 f"{1e3 * result.feed_per_tooth_m:.3f} mm/tooth</b>: material removal "
                 f"{1e6 * result.mrr_m3_s:.2f} cm^3/s; active constraints: "
                 f"{', '.join(result.active_constraints) or 'none'}. Model: {example.planning_label}.")
        point = result.point
        from planner.wall import wall_error

        wall, height = wall_error(point, example.setup.tool, example.setup.cut)
        sec.table(["quantity", "value", "limit"], [
            ["depth / stability limit", result.axial_depth_m / point.depth_limit_m, example.setup.limits.stability_margin],
            [f"largest |surface location error| on the wall um (at z = {1e3 * height:.1f} mm; the limit's)", 1e6 * wall,
             1e6 * (example.setup.limits.surface_location_error_m or float("nan"))],
            ["surface location error at the tool tip um (reported, cli.md)", 1e6 * point.surface_location_error_m,
             float("nan")],
            ["peak force N", point.peak_force_N, example.setup.limits.max_force_N],
            ["power W", point.power_W, example.setup.limits.spindle_power_W],
            ["mean torque N m", point.mean_torque_N_m, example.setup.limits.spindle_torque_N_m],
            ["peak torque N m (shown only; the limit bounds the mean)", point.peak_torque_N_m, float("nan")]])
    else:
        sec.text(f"<span class='warn'>No feasible plan ({result.status}): {result.message}</span>")
    fig, _ = result.plot()
    sec.figure(report.save_figure(fig, "plan"), "Lobes with the planning bound, pocket optima and the recommendation")
    report.summary["plan"] = result.to_dict()


def _robomill_json(argv: list[str]) -> dict:
    """``robomill ARGV --json`` run in-process, its JSON (a failure raises with its stderr)."""
    import contextlib
    import io
    import json

    from planner.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([*argv, "--json"])
    if code != 0:
        raise RuntimeError(f"robomill {' '.join(argv)} exited {code}: {err.getvalue().strip()}")
    return json.loads(out.getvalue())


def _step_learn(example: Example, report: Report) -> None:
    """The example's 12 test cuts learned (``robomill learn -o``), and the plan at P(stable) >= 0.95
    with that posterior (``robomill plan --model``): what the cuts themselves back, and the best cut
    they prove. The commands a user would type, run in-process; the posterior is kept beside the
    report for them."""
    from planner.learn.support import describe_best_backed

    d = example.directory
    posterior = report.directory / "posterior.yaml"
    learned = _robomill_json(["learn", str(d / "setup.yaml"), "--model", str(d / "models" / "planning_model.yaml"),
                              "--cuts", str(d / "cuts.csv"), "-o", str(posterior)])
    figure = report.figure_dir / "plan_learned.png"
    planned = _robomill_json(["plan", str(d / "setup.yaml"), "--model", str(posterior), "-o", str(figure)])
    sec = report.section("Learning from test cuts")
    sec.text(f"<code>robomill learn</code> on the example's {learned['n_cuts']} test cuts "
             "(cuts.csv) with the planning model as the prior: cross-validated accuracy "
             f"{learned['accuracy_before']:.2f} before, {learned['accuracy_after']:.2f} after; the parameter the "
             f"cuts moved most against its prior: {learned['cause']}. The posterior is written to posterior.yaml.")
    info = planned.get("learned") or {}
    support = info.get("support") or {}
    if planned["success"]:
        check = info.get("check") or {}
        sec.text(f"<code>robomill plan --model posterior.yaml</code> (P(stable) >= {info.get('probability', 0.95):g}): "
                 f"<b>{planned['spindle_rpm']:.0f} rpm, axial depth {1e3 * planned['axial_depth_m']:.2f} mm, feed "
                 f"{1e3 * planned['feed_per_tooth_m']:.3f} mm/tooth</b>: {1e6 * planned['mrr_m3_s']:.2f} cm^3/s; "
                 f"P(stable) from {check.get('samples', 0)} posterior samples solved directly "
                 f"{check.get('probability_stable', float('nan')):.3f}. Test cuts at its speed: "
                 f"{support.get('status', 'not known')}.")
        alt = support.get("best_backed")
        if alt:
            sec.text(f"Best cut a stable test cut proves: {describe_best_backed(alt)}.")
    else:
        sec.text(f"<span class='warn'>No plan with the posterior ({planned['status']}): {planned['message']}</span>")
    for w in learned["warnings"] + info.get("warnings", []):
        sec.text(f"<span class='warn'>warning: {w}</span>")
    if figure.exists():
        sec.figure(f"figures/{figure.name}", "The plan at P(stable) >= 0.95 with the test cuts at its engagement "
                   "and the best cut they prove")
    report.summary["learn"] = {"accuracy_before": learned["accuracy_before"], "accuracy_after": learned["accuracy_after"],
                               "cause": learned["cause"], "posterior": str(posterior),
                               "plan": {k: planned.get(k) for k in ("success", "spindle_rpm", "axial_depth_m",
                                                                    "feed_per_tooth_m", "mrr_m3_s")},
                               "support": support or None}


def _step_check(example: Example, report: Report) -> None:
    """The toolpath across the six identified poses, point by point."""
    from planner.check import check_toolpath

    result = check_toolpath(example.toolpath, example.poses, progress=False)
    counts = result.counts()
    sec = report.section("Toolpath check")
    sec.text(f"{result.n_points} points checked against the setup's limits with the pose models interpolated "
             f"between the {len(example.poses)} identified poses: "
             + ", ".join(f"{v} {k}" for k, v in counts.items() if v) + ".")
    chatter = [v for v in result.violations if v["kind"] == "chatter"]
    if chatter:
        v = chatter[0]
        sec.text(f"First chatter point: index {v['index']}, planned depth {1e3 * v['value']:.1f} mm, allowed "
                 f"{1e3 * v['limit']:.1f} mm; nearest stable spindle speed {v.get('nearest_stable_rpm', float('nan')):.0f} rpm.")
    for note in result.notes:
        sec.text(f"<span class='warn'>{note}</span>")
    fig, _ = result.plot()
    sec.figure(report.save_figure(fig, "toolpath_check"), "Toolpath coloured by stability margin, violations marked")
    report.summary["check"] = {"points": result.n_points, "violations_by_kind": counts,
                               "first_chatter": chatter[0] if chatter else None}


#: Modes above this are the spindle/tool's (pose-independent, given separately): left out of the
#: pose models before the robot is calibrated on them.
_ROBOT_BAND_HZ = 200.0


def _step_robot(example: Example, report: Report):
    """The robot as the model: calibrate it on the six identified poses, check the path with it,
    choose the posture, and map the lowest tool-tip mode over the working region. Returns the
    calibrated robot."""
    from oma.modal import ModalModel
    from planner.check import check_toolpath
    from planner.robot import read_robot
    from planner.robot.calibrate import calibrate
    from planner.robot.path import lowest_mode_map
    from planner.robot.posture import choose_posture
    from planner.robot.posture_plots import plot_mode_map

    robot_file = example.toolpath.robot_file
    robot = read_robot(robot_file)
    robot_only = []
    for m in example.poses:
        keep = m.natural_frequency_hz < _ROBOT_BAND_HZ
        robot_only.append(ModalModel(m.natural_frequency_hz[keep], m.damping_ratio[keep], m.stiffness_N_m[keep],
                                     m.directions[keep], joints_deg=m.joints_deg))
    names = [f"pose_{i + 1}" for i in range(len(robot_only))]
    cal = calibrate(robot, robot_only, names=names)
    robot = cal.robot
    sec = report.section("The robot as the model")
    sec.text(f"The cell's robot ({robot.name}) calibrated on the {len(robot_only)} identified poses (their modes "
             f"below {_ROBOT_BAND_HZ:g} Hz; the spindle/tool modes are pose-independent and added in series).")
    sec.table(["joint", "stiffness N m/rad", "identifiable"],
              [[j + 1, float(k), bool(i)] for j, (k, i) in enumerate(zip(robot.joint_stiffness_N_m_rad, cal.identifiable))])
    loo = [float(v["frequency_error"]) for v in cal.leave_one_out]
    sec.text(f"Fit error per pose (relative): {', '.join(f'{e:.3f}' for e in cal.fit_error)}; leave-one-pose-out "
             f"frequency error: median {np.median(loo):.3f}, max {np.max(loo):.3f}.")
    for w in cal.warnings:
        sec.text(f"<span class='warn'>{w}</span>")

    before_models = check_toolpath(example.toolpath, example.poses, progress=False)
    result = check_toolpath(example.toolpath, robot=robot, tool_model=example.tool_mode, progress=False)
    counts = result.counts()
    sec.text(f"Toolpath check with the calibrated robot ({result.n_points} points, joints as given in the "
             f"toolpath): " + (", ".join(f"{v} {k}" for k, v in counts.items() if v) or "no violations")
             + f" (with the identified poses interpolated: {before_models.counts()['pose_out_of_range']} "
             "pose_out_of_range, which the robot model does not need).")
    posture = choose_posture(robot, example.toolpath, tool_model=example.tool_mode, stations=32)
    sec.text(f"Posture (rotation about the tool axis, one IK branch, smooth, within limits and away from "
             f"singularities): smallest stability margin {posture.min_margin_before:.3f} before, "
             f"{posture.min_margin_after:.3f} after; flange angle {np.nanmin(posture.flange_angle_deg):.0f} to "
             f"{np.nanmax(posture.flange_angle_deg):.0f} deg" + (f"; unreachable: {len(posture.unreachable)} points"
                                                                   if posture.unreachable else "") + ".")
    after = check_toolpath(posture.toolpath, robot=robot, tool_model=example.tool_mode, progress=False)
    sm = np.where(np.isfinite(posture.station_margin), posture.station_margin, np.nan)
    spread = np.nanmax(sm, axis=1) / np.nanmin(sm, axis=1) - 1.0  # per station, over the feasible rotations
    worst = int(np.nanargmin(np.nanmin(sm, axis=1)))
    sec.text(f"At the worst station the margin changes by {100 * spread[worst]:.2g} % over the feasible rotations "
             f"(median over stations {100 * np.nanmedian(spread):.2g} %): "
             + ("at this spindle speed the stability limit is set by the pose-independent spindle/tool modes, so "
                "no posture can raise it; " if spread[worst] < 1e-3 else "")
             + "the check after the posture: " + (", ".join(f"{v} {k}" for k, v in after.counts().items() if v)
                                                   or "no violations") + ".")
    fig, _ = posture.plot()
    sec.figure(report.save_figure(fig, "posture"), "Path (part frame) coloured by stability margin: toolpath's "
               "rotation (left) and after the posture choice (right)")
    machine = example.toolpath.in_machine_frame()
    xs = np.linspace(0.9, 1.9, 41)
    ys = np.linspace(-0.6, 0.6, 49)
    z = float(np.mean(machine.positions_m[:, 2]))
    freq, _ = lowest_mode_map(robot, xs, ys, z, tool_axis=np.asarray(machine.tool_axis, float), feed=(0.0, 1.0, 0.0))
    from planner.robot import forward_kinematics

    poses_xy = forward_kinematics(robot, np.radians([m.joints_deg for m in example.poses]))[:, :2, 3]
    fig, _ = plot_mode_map(xs, ys, freq, path_xy_m=machine.positions_m[:, :2], poses_xy_m=poses_xy)
    sec.figure(report.save_figure(fig, "mode_map"), f"Lowest tool-tip mode of the calibrated robot at z = {z:.2f} m "
               "(tool axis +Z, flange x along +Y), the toolpath and the identified poses")
    finite = freq[np.isfinite(freq)]
    report.summary["robot"] = {
        "joint_stiffness_N_m_rad": robot.joint_stiffness_N_m_rad.tolist(), "identifiable": cal.identifiable.tolist(),
        "leave_one_out_frequency_error": loo, "check_counts": counts,
        "pose_out_of_range_with_models": before_models.counts()["pose_out_of_range"],
        "min_margin_before": posture.min_margin_before, "min_margin_after": posture.min_margin_after,
        "check_after_posture_counts": after.counts(), "unreachable": list(posture.unreachable),
        "lowest_mode_hz_range": [float(finite.min()), float(finite.max())] if finite.size else None,
    }
    return robot


#: The atlas of the demo sweeps the low speeds, where a robot's own modes limit the cut (DOMAIN.md:
#: at the top of the example's range the 8 kW spindle, not chatter, sets the removal rate anywhere).
_ATLAS_RPM = (1000.0, 6000.0)


def _step_atlas(example: Example, report: Report, robot) -> None:
    """Where in the cell, and at which rotation about the tool axis, to cut: a small atlas of the
    calibrated robot (serial; ``robomill atlas`` runs the same on a Dask cluster)."""
    from planner.atlas import demo_section

    demo_section(report, robot, example.setup, report.directory, tool_model=example.tool_mode, rpm_range=_ATLAS_RPM)


def run_demo(output: Path, *, example_dir: Path = EXAMPLE_DIR, progress: bool = True) -> dict:
    """Run every step on the example and write ``report.html`` and ``summary.json`` under ``output``.

    Returns the JSON summary (with ``report``, the report's path).
    """
    t0 = time.perf_counter()
    example = load_example(example_dir)
    report = Report("robomill demo: KR500 milling acetal (simulated example cell)", output)
    steps = [_step_records, _step_identify, _step_shortcuts, _step_lobes, _step_plan, _step_learn, _step_check]
    for step in steps:
        log.info("demo: %s", step.__name__)
        step(example, report)
    log.info("demo: _step_robot, _step_atlas")
    _step_atlas(example, report, _step_robot(example, report))
    report.summary["elapsed_s"] = time.perf_counter() - t0
    path = report.write()
    report.summary["report"] = str(path)
    return report.summary
