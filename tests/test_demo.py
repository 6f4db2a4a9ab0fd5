"""The README's quick start: the whole job on the bundled example writes one report (``make demo``)."""

import json

import matplotlib

matplotlib.use("Agg")

from planner.demo import run_demo  # noqa: E402


def test_demo_runs_the_whole_job_and_writes_its_report(tmp_path):
    summary = run_demo(tmp_path / "out", progress=False)
    report = tmp_path / "out" / "report.html"
    assert summary["report"] == str(report) and report.stat().st_size > 10_000
    on_disk = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert set(on_disk) >= {"records", "identification", "lobes", "plan", "check"}
    # the 20 s record identified by the default method is trusted and close to the hammer test
    long = on_disk["identification"]["cut_long/default"]
    assert long["trusted"] and max(long["hammer_agreement"].values()) < 0.10
    # the 1.1 s record: the paper's estimator is flagged untrusted (it cannot resolve the modes)
    assert on_disk["identification"]["cut_short/h1"]["trusted"] is False
    # the plan is verified and lies inside the setup's bounds (8 kW, 500-24000 rpm, 0.5-30 mm)
    plan = on_disk["plan"]
    assert plan["success"] and 500 <= plan["spindle_rpm"] <= 24000 and 5e-4 <= plan["axial_depth_m"] <= 0.03
    assert plan["predicted"]["power_W"] <= 8000 * (1 + 1e-6)
    assert on_disk["check"]["points"] == 240
    assert (tmp_path / "out" / "figures").is_dir()
    # the robot step: calibrated on the poses, the path checked with it (no pose_out_of_range, which
    # the interpolated pose models flag beyond the identified span), every point reachable, and
    # the posture never lowers the smallest margin
    robot = on_disk["robot"]
    assert robot["pose_out_of_range_with_models"] > 0 and "pose_out_of_range" not in robot["check_counts"]
    assert robot["check_counts"]["unreachable"] == 0 and robot["unreachable"] == []
    assert robot["min_margin_after"] >= robot["min_margin_before"] * (1 - 1e-9)
    assert max(robot["leave_one_out_frequency_error"]) < 0.05
