"""The README's quick start: the whole job on the bundled example writes one report (``make demo``)."""

import json

import matplotlib

matplotlib.use("Agg")

from planner.demo import EXAMPLE_DIR, run_demo  # noqa: E402
from planner.learn.likelihood import STABLE  # noqa: E402
from planner.learn.outcomes_io import read_cuts  # noqa: E402
from planner.learn.posterior_io import read_posterior  # noqa: E402
from stability.setup_io import read_setup  # noqa: E402


def test_demo_runs_the_whole_job_and_writes_its_report(tmp_path):
    summary = run_demo(tmp_path / "out", progress=False)
    report = tmp_path / "out" / "report.html"
    assert summary["report"] == str(report) and report.stat().st_size > 10_000
    on_disk = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert set(on_disk) >= {"records", "identification", "lobes", "plan", "learn", "check"}
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
    # learning from the example's test cuts: the posterior kept beside the report, the plan with it
    # verified and within the setup's bounds, and the best cut the cuts prove backed by a stable
    # mark of the example's cuts.csv at its speed, at least as deep, and under the plan's removal rate
    learn = on_disk["learn"]
    assert learn["plan"]["success"] and 5e-4 <= learn["plan"]["axial_depth_m"] <= 0.03
    assert read_posterior(learn["posterior"]) is not None
    alt = learn["support"]["best_backed"]
    if learn["support"]["status"] != "backed":
        cuts = read_cuts(EXAMPLE_DIR / "cuts.csv", tool=read_setup(EXAMPLE_DIR / "setup.yaml").tool)
        i = alt["backed_by"]
        assert cuts.outcome[i] == STABLE and abs(cuts.spindle_rpm[i] / alt["spindle_rpm"] - 1) < 2e-4
        assert alt["axial_depth_m"] <= cuts.axial_depth_m[i] * (1 + 1e-9) and 0 < alt["share_of_plan"] < 1
    assert (tmp_path / "out" / "figures" / "plan_learned.png").stat().st_size > 10_000
