"""``--suggest``: expected improvement of the best stable MRR, on hand-made probability lobes."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from test_learn_plan import case  # noqa: F401  (a fixture: the small test tool's posterior, 9-12 krpm)

from planner.learn.predictive import ProbabilityLobes
from planner.learn.suggest import suggest_cuts


def _lobes(rng):
    """Limits with a lobe peak at 15 krpm (about 3x the floor) and 10 % log-normal scatter."""
    rpm = np.linspace(8000, 20000, 121)
    base = 2e-3 * (1 + 2 * np.exp(-0.5 * ((rpm - 15000) / 600) ** 2))
    lim = base[None, :] * np.exp(0.1 * rng.standard_normal((400, 1)))
    q = {p: np.quantile(lim, 1 - p, axis=0) for p in (0.05, 0.5, 0.95)}
    return ProbabilityLobes(rpm=rpm, limits=lim, levels=(0.05, 0.5, 0.95), quantiles=q, radial_depth_m=5e-3,
                            milling="down")


def test_suggests_beyond_the_proven_best_on_the_lobe_peak():
    lobes = _lobes(np.random.default_rng(0))
    cuts, gain, incumbent = suggest_cuts(lobes, 3)
    assert cuts.n_cuts == 3 and np.all(gain > 0)
    mrr = cuts.spindle_rpm * cuts.axial_depth_m
    assert np.all(mrr > incumbent)  # each would improve on what the posterior already guarantees
    p = np.array([lobes.probability_stable([a])[0][np.argmin(np.abs(lobes.rpm - r))]
                  for r, a in zip(cuts.spindle_rpm, cuts.axial_depth_m)])
    assert np.all((p > 0.05) & (p < 0.95))  # not yet known: worth a test
    assert abs(cuts.spindle_rpm[0] - 15000) < 1000  # the first is on the peak
    gaps = np.abs(cuts.spindle_rpm[:, None] / cuts.spindle_rpm[None, :] - 1) + np.eye(3)
    assert np.all(gaps >= 0.03)
    with pytest.raises(ValueError, match="n must be"):
        suggest_cuts(lobes, 0)


def test_computation_modules_do_not_import_matplotlib():
    code = ("import sys, planner.learn.update, planner.learn.predictive, planner.learn.suggest, "
            "planner.learn.cli; print('matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _two_factor_lobes(rng, n=400):
    """Limits whose low-speed half and high-speed half are scaled by two independent factors
    (20 % log-sd each): what a cut teaches about one half says nothing about the other."""
    rpm = np.geomspace(6000, 24000, 81)
    base = 2e-3 * (1 + 0.5 * np.sin(rpm / 1500.0))
    side = 1 / (1 + np.exp(-(np.log(rpm) - np.log(12000)) / 0.05))  # 0 below 12 krpm, 1 above
    a, b = 0.2 * rng.standard_normal((2, n, 1))
    lim = base[None, :] * np.exp(a * (1 - side)[None, :] + b * side[None, :])
    q = {p: np.quantile(lim, 1 - p, axis=0) for p in (0.05, 0.5, 0.95)}
    return ProbabilityLobes(rpm=rpm, limits=lim, levels=(0.05, 0.5, 0.95), quantiles=q, radial_depth_m=5e-3,
                            milling="down"), side


def test_boundary_cuts_reduce_the_variance_as_brute_force_reweighting_says_and_spread():
    from scipy.special import expit

    from planner.learn.likelihood import Likelihood

    lobes, side = _two_factor_lobes(np.random.default_rng(1))
    like = Likelihood()
    cuts, share, _ = suggest_cuts(lobes, 2, criterion="boundary", likelihood=like, n_depth=40)
    assert cuts.n_cuts == 2 and np.all(np.diff(share) < 0) and share[0] > 0
    # the first pick's expected reduction, by brute force: reweight the samples by each outcome
    log_lim = np.log(lobes.limits)
    j = int(np.argmin(np.abs(lobes.rpm - cuts.spindle_rpm[0])))
    q = like.mislabel + (1 - 2 * like.mislabel) * expit((np.log(cuts.axial_depth_m[0]) - log_lim[:, j])
                                                         / like.scale())
    v0 = np.sum(np.var(log_lim, axis=0))
    after = 0.0
    for wy in (q, 1 - q):
        m = wy @ log_lim / wy.sum()
        after += wy.mean() * np.sum(wy @ log_lim ** 2 / wy.sum() - m ** 2)
    assert np.isclose(share[0], (v0 - after) / v0, rtol=1e-9)
    # an informative cut (near the boundary there), and the second on the other half of the speeds
    p = lobes.probability_stable([cuts.axial_depth_m[0]])[0][j]
    assert 0.2 < p < 0.8
    halves = [side[int(np.argmin(np.abs(lobes.rpm - r)))] > 0.5 for r in cuts.spindle_rpm]
    assert halves[0] != halves[1]
    with pytest.raises(ValueError, match="criterion"):
        suggest_cuts(lobes, 1, criterion="information")


def test_boundary_cuts_judged_from_records_teach_less_and_sit_deeper():
    """Outcomes detected from records have the detector's lagged, wider boundary: the best cut for
    the boundary is then deeper (by about the lag: there the detection is a coin toss) and its
    expected variance reduction smaller than that of a marked cut, and equal to brute-force
    reweighting with the detector's outcome model."""
    from scipy.special import expit

    from planner.learn.likelihood import Likelihood

    lobes, _ = _two_factor_lobes(np.random.default_rng(1))
    like = Likelihood()
    marked, share_m, _ = suggest_cuts(lobes, 1, criterion="boundary", likelihood=like, n_depth=80)
    found, share_d, _ = suggest_cuts(lobes, 1, criterion="boundary", likelihood=like, n_depth=80, detected=True)
    assert share_d[0] < share_m[0]
    j = int(np.argmin(np.abs(lobes.rpm - found.spindle_rpm[0])))
    log_lim = np.log(lobes.limits[:, j])
    x = np.log(found.axial_depth_m[0]) - log_lim
    q = like.mislabel + (1 - 2 * like.mislabel) * expit((x - like.detection_lag) / like.scale(width=like.detection_scale))
    assert 0.3 < q.mean() < 0.7  # the detector's coin toss ...
    assert np.median(x) > 0.5 * like.detection_lag  # ... above the median limit, by about the lag
    log_all = np.log(lobes.limits)
    v0 = np.sum(np.var(log_all, axis=0))
    after = sum(wy.mean() * np.sum(wy @ log_all ** 2 / wy.sum() - (wy @ log_all / wy.sum()) ** 2) for wy in (q, 1 - q))
    assert np.isclose(share_d[0], (v0 - after) / v0, rtol=1e-9)


def test_mrr_lobes_cover_the_speeds_where_a_cut_could_beat_the_incumbent(case):
    """``lobes_for_improvement``: the lobes of ``probability_lobes`` (same speeds and values) from
    the lowest speed whose largest allowed cut could beat the incumbent up; below, no allowed cut
    does (its expected improvement is 0), so with the same depths considered the suggestions and
    their scores are those from the whole range."""
    from planner.learn.predictive import probability_lobes
    from planner.learn.speed_range import lobes_for_improvement
    from planner.learn.suggest import allowed_depths, best_proven_mrr

    _, setup, post = case
    setup = replace(setup, limits=replace(setup.limits, spindle_rpm=(2000.0, 14000.0)))
    rng = setup.limits.spindle_rpm
    lobes, speeds = lobes_for_improvement(post, setup, rng, n_rpm=80)
    whole = probability_lobes(post, setup, rng, n_rpm=80, check=0)  # both without a check of their table
    k = whole.rpm >= speeds.rpm_range[0]
    assert speeds.restricted and 0 < k.sum() < k.size and speeds.rpm_range == (float(whole.rpm[k][0]), 14000.0)
    np.testing.assert_array_equal(lobes.rpm, whole.rpm[k])
    np.testing.assert_allclose(lobes.limits, whole.limits[:, k], rtol=1e-9)
    least, most, _ = allowed_depths(setup, whole.rpm, post.reference)
    incumbent = best_proven_mrr(lobes, allowed_depth_m=(least[k], most[k]))
    assert np.all(most[~k] * whole.rpm[~k] <= incumbent) and np.any(most[k] * whole.rpm[k] > incumbent)
    scale = setup.cut.radial_depth_m * setup.cut.feed_per_tooth_m * setup.tool.teeth / 60.0
    assert speeds.below_mrr_m3_s == pytest.approx(np.max(most[~k] * whole.rpm[~k]) * scale)
    considered = (0.5 * np.min(whole.quantiles[0.95]), 2.0 * np.max(whole.quantiles[0.05]))
    a = suggest_cuts(whole, 3, allowed_depth_m=(least, most), depth_range_m=considered)
    b = suggest_cuts(lobes, 3, allowed_depth_m=(least[k], most[k]), depth_range_m=considered)
    np.testing.assert_array_equal(a[0].spindle_rpm, b[0].spindle_rpm)
    np.testing.assert_array_equal(a[0].axial_depth_m, b[0].axial_depth_m)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-9)
    assert a[2] == pytest.approx(b[2], rel=1e-12) and np.all(b[1] > 0)


def test_learn_suggest_reports_the_speeds_of_its_lobes_and_their_time(case, tmp_path, capsys):
    """``learn --suggest`` (``mrr``, no plot) says which speeds its lobes covered and why, and its
    ``timings_s`` include the lobes and the suggestion (``total``: the whole command)."""
    import json

    from oma.modal_io import write_modal_model
    from planner.cli import main
    from planner.learn.synthetic import label, random_cuts, tool_problem, true_limits
    from stability.setup_io import write_setup

    _, setup, _ = case
    problem = tool_problem()
    setup = replace(setup, limits=replace(setup.limits, spindle_rpm=(2000.0, 14000.0)))
    rng = np.random.default_rng(5)
    cuts = random_cuts(replace(problem, setup=setup), 8, rng, immersions=(1.0,), depth_range=(1e-3, 8e-3))
    cuts = label(cuts, true_limits(problem, cuts.spindle_rpm, cuts.radial_depth_m, cuts.down, converged=False),
                 rng, flip=0.0)
    lines = ["spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome"]
    lines += [f"{cuts.spindle_rpm[i]},{cuts.axial_depth_m[i]},{cuts.radial_depth_m[i]},down,"
              f"{'chatter' if cuts.outcome[i] else 'stable'}" for i in range(cuts.n_cuts)]
    (tmp_path / "cuts.csv").write_text("\n".join(lines) + "\n")
    write_setup(setup, tmp_path / "setup.yaml")
    write_modal_model(problem.prior, tmp_path / "prior.yaml")
    code = main(["learn", str(tmp_path / "setup.yaml"), "--model", str(tmp_path / "prior.yaml"), "--cuts",
                 str(tmp_path / "cuts.csv"), "--method", "zoa", "--samples", "200", "--suggest", "2", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and len(out["suggested"]) == 2
    lo = out["suggested_rpm_range"][0]
    assert 2000.0 < lo < 14000.0 and all(s["spindle_rpm"] >= lo for s in out["suggested"])
    assert out["suggested_rpm_range_note"].startswith(f"speeds below {lo:.0f} rpm not tabulated")
    t = out["timings_s"]
    assert t["lobes"] > 0 and t["suggest"] >= 0 and t["total"] >= t["learn"] + t["lobes"] + t["suggest"]
