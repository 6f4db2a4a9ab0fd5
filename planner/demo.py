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


def _step_lobes(example: Example, report: Report, model=None, label: str = "planning model (truth + tool mode)") -> None:
    """Lobes by ZOA and SDM over the setup's speed range, and the paper's operating point."""
    from stability.lobes import lobe_diagram, predict_point
    from stability.plots import plot_lobes

    setup = example.setup
    model = example.planning_model if model is None else model
    coef = setup.material.cutting_coefficients
    rpm_range = setup.limits.spindle_rpm or (500.0, 24000.0)
    zoa = lobe_diagram(model, setup.tool, setup.cut, coef, rpm_range=rpm_range, method="zoa")
    sdm = lobe_diagram(model, setup.tool, setup.cut, coef, rpm_range=rpm_range, method="sdm", n_rpm=120)
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


def run_demo(output: Path, *, example_dir: Path = EXAMPLE_DIR, progress: bool = True) -> dict:
    """Run every step on the example and write ``report.html`` and ``summary.json`` under ``output``.

    Returns the JSON summary (with ``report``, the report's path).
    """
    t0 = time.perf_counter()
    example = load_example(example_dir)
    report = Report("robomill demo: KR500 milling acetal (simulated example cell)", output)
    steps = [_step_records, _step_lobes]
    for step in steps:
        log.info("demo: %s", step.__name__)
        step(example, report)
    report.summary["elapsed_s"] = time.perf_counter() - t0
    path = report.write()
    report.summary["report"] = str(path)
    return report.summary
