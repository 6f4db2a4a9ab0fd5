"""``plan`` and ``lobes`` given a model written by ``learn``: the chance constraint."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from learn_cases import slotting_posterior

from oma.modal_io import write_modal_model
from planner.cli import main
from planner.learn.posterior import Posterior, PriorSD
from planner.learn.posterior_io import read_posterior, write_posterior_model
from planner.learn.outcomes_io import CutTable
from planner.learn.predictive import ChanceLimit, depth_at_probability, predict_cuts
from planner.learn.tables import reference_limits, scaled_coefficients, scaled_model
from stability.setup_io import write_setup


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """A posterior whose samples are drawn around the prior (frequency and stiffness free), the
    setup slotting (ZOA learned) in a 9-12 krpm window."""
    d = tmp_path_factory.mktemp("plan")
    problem, setup, post = slotting_posterior(stability_margin=0.5)
    write_setup(setup, d / "setup.yaml")
    write_posterior_model(post, d / "post.yaml")
    write_modal_model(problem.prior, d / "prior.yaml")
    return d, setup, post


def _direct(post, setup, u, rpm):
    """The limits (m) of the samples ``u`` at the speeds ``rpm``, each solved by ZOA from its own
    scaled model and coefficients (independently of ``direct_log_limits``), (n_samples, n_rpm)."""
    return np.array([reference_limits(scaled_model(post.reference, log_f=x[0], log_k=x[1], log_zeta=x[2]),
                                      setup.tool, setup.cut, scaled_coefficients(post.coefficients, log_kt=x[3],
                                                                                 log_kr=x[4]),
                                      np.asarray(rpm, dtype=float), method="zoa") for x in u])


def test_chance_limit_is_where_the_predictive_probability_of_direct_limits_falls_to_the_level(case):
    """The 95 % chance depth at a speed is where P(stable), computed from the samples' own limits
    solved directly and the soft boundary, is 0.95 (table interpolation error: 3 %, see
    test_learn_posterior); it lies below the samples' 5 % quantile (the soft boundary widens)."""
    _, setup, post = case
    limit = ChanceLimit(post, setup, setup.limits.spindle_rpm, probability=0.95, max_samples=60)
    rpm = np.array([9500.0, 11000.0])
    direct = _direct(post, setup, post.thinned(60).samples, rpm)  # the same 60 samples as the chance limit's
    a = limit(rpm)
    s = post.likelihood.scale()
    p_direct = np.mean(1.0 / (1.0 + np.exp(-(np.log(direct) - np.log(a)[None, :]) / s)), axis=0)
    np.testing.assert_allclose(p_direct, 0.95, atol=0.03)
    assert np.all(a < np.quantile(direct, 0.05, axis=0))
    with pytest.raises(ValueError, match="probability"):
        ChanceLimit(post, setup, setup.limits.spindle_rpm, probability=1.0)


def test_the_chance_depth_is_where_predict_gives_the_level(case):
    """``plan``'s chance constraint and ``learn --predict`` state one probability: a cut at the
    90 % depth is predicted stable with 0.90, with the table's error in the soft boundary."""
    _, setup, post = case
    post = replace(post, likelihood=replace(post.likelihood, model_error=0.05))
    rpm = np.array([9300.0, 10400.0, 11800.0])
    depth = ChanceLimit(post, setup, setup.limits.spindle_rpm, probability=0.9)(rpm)
    cuts = CutTable(rpm, depth, np.full(3, setup.cut.radial_depth_m), np.full(3, setup.cut.milling == "down"),
                    np.full(3, -1), np.ones(3), np.full(3, np.nan), np.zeros(3, bool))
    np.testing.assert_allclose(predict_cuts(post, setup, cuts), 0.9, atol=0.01)
    narrow = ChanceLimit(replace(post, likelihood=replace(post.likelihood, model_error=0.0)), setup,
                         setup.limits.spindle_rpm, probability=0.9)(rpm)
    assert np.all(depth < narrow)  # the table's error lowers the chance depth


@pytest.mark.parametrize("kernel", ["logistic", "normal"])
def test_depth_at_probability_against_monte_carlo(kernel):
    """The bisection against draws of the definition: a sample's limit times the kernel's noise."""
    rng = np.random.default_rng(3)
    log_b = np.log(2e-3) + np.c_[0.2 * rng.standard_normal(300), 0.05 * rng.standard_normal(300) + 0.3]
    s = 0.04
    a = depth_at_probability(log_b, 0.9, s, kernel=kernel)
    noise = rng.logistic(size=(200, 300, 1)) if kernel == "logistic" else rng.standard_normal((200, 300, 1))
    p = np.mean(log_b[None] + s * noise > np.log(a), axis=(0, 1))
    np.testing.assert_allclose(p, 0.9, atol=0.005)
    np.testing.assert_allclose(depth_at_probability(log_b, 0.9, 0.0), np.exp(np.quantile(log_b, 0.1, axis=0)))


def test_plan_with_a_posterior_uses_the_chance_constraint(case, capsys):
    d, setup, post = case
    code = main(["plan", str(d / "setup.yaml"), "--model", str(d / "post.yaml"), "--probability", "0.9", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert out["learned"]["probability"] == 0.9 and "cause" in out["learned"]
    check = out["learned"]["check"]  # the planned cut, solved directly
    assert check["samples"] == 64 and check["spindle_rpm"] == out["spindle_rpm"] and check["holds"]
    limit = ChanceLimit(read_posterior(d / "post.yaml"), setup, setup.limits.spindle_rpm, probability=0.9)
    lim = float(limit(np.array([out["spindle_rpm"]]))[0])
    # the plan respects the 90 % depth and not the (halving) margin factor
    assert out["axial_depth_m"] <= lim * (1 + 1e-3)
    if "stability" in out["active_constraints"]:
        assert out["axial_depth_m"] > 0.9 * lim
    code = main(["plan", str(d / "setup.yaml"), "--model", str(d / "post.yaml"), "--probability", "0.9"])
    text = capsys.readouterr().out
    assert code == 0 and f"64 posterior samples solved directly: {check['probability_stable']:.3f}" in text
    code = main(["plan", str(d / "setup.yaml"), "--model", str(d / "post.yaml"), "--probability", "1.5"])
    assert code == 2 and "--probability" in capsys.readouterr().err


def test_lobes_with_a_posterior(case, capsys):
    d, _, _ = case
    code = main(["lobes", str(d / "setup.yaml"), "--model", str(d / "post.yaml"), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    q = out["probability_lobes"]["depth_at_probability_m"]
    assert np.all(np.array(q["0.95"]) <= np.array(q["0.5"])) and np.all(np.array(q["0.5"]) <= np.array(q["0.05"]))
    lobes = out["probability_lobes"]  # the larger of the table's checked error and the training cuts' is carried
    assert lobes["table_error"] > 0 and lobes["boundary_width"] >= max(lobes["table_error"], lobes["model_error"])


def test_a_posterior_of_several_modes_keeps_its_mode_spread_through_its_file(tmp_path):
    """The modes' own deviations (``mode_spread``, learn's ``mode_correlation`` below 1) are written
    beside the samples and read back; each mode's reported sd includes them; a malformed one is a
    one-line model error."""
    from oma.errors import ModelError
    from planner.learn.synthetic import two_mode_problem

    pb = two_mode_problem()
    rng = np.random.default_rng(0)
    sd = PriorSD().log_sds()
    post = Posterior(reference=pb.prior, coefficients=pb.setup.material.cutting_coefficients, prior_log_sd=sd,
                     samples=0.1 * rng.standard_normal((40, 5)), mode_spread=np.array([0.05, 0.2, 0.3]))
    write_posterior_model(post, tmp_path / "p.yaml")
    back = read_posterior(tmp_path / "p.yaml")
    np.testing.assert_allclose(back.mode_spread, [0.05, 0.2, 0.3])
    together = replace(post, mode_spread=np.zeros(3))
    for r in (0, 1):
        key = f"stiffness_N_m[{r}]"
        assert post.parameters()[key]["sd"] > 1.5 * together.parameters()[key]["sd"]
    text = (tmp_path / "p.yaml").read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("mode_spread:", "mode_spread: [1, 2]\n  old_mode_spread:"))
    with pytest.raises(ModelError, match="mode_spread"):
        read_posterior(bad)


def test_the_chance_limit_checks_its_own_table_and_widens_by_the_larger_error(case):
    """The planned engagement's table is checked against direct limits (its RMS log error,
    ``table_error``, recomputed here on the same samples and speeds) and the soft boundary is
    widened by the larger of it and the training cuts' error."""
    _, setup, post = case
    limit = ChanceLimit(post, setup, setup.limits.spindle_rpm, probability=0.95, check=4, check_speeds=5)
    thin = post.thinned(400)
    u = thin.samples[np.random.default_rng(0).permutation(thin.samples.shape[0])[:4]]
    r = np.geomspace(*setup.limits.spindle_rpm, 5)
    direct = _direct(post, setup, u, r)
    table = np.log(limit.samples(r))[np.r_[[np.flatnonzero(np.all(thin.samples == x, axis=1))[0] for x in u]]]
    np.testing.assert_allclose(limit.table_error, np.sqrt(np.mean((table - np.log(direct)) ** 2)), rtol=0.05,
                               atol=2e-3)
    lk = post.likelihood
    assert limit.boundary_width == pytest.approx(float(np.hypot(lk.boundary_scale, max(lk.model_error,
                                                                                        limit.table_error))))
    big = replace(post, likelihood=replace(lk, model_error=limit.table_error + 0.1))
    wide = ChanceLimit(big, setup, setup.limits.spindle_rpm, probability=0.95, check=4, check_speeds=5)
    assert wide.boundary_width == pytest.approx(float(np.hypot(lk.boundary_scale, limit.table_error + 0.1)))
    assert np.all(wide(r) < limit(r))
    unchecked = ChanceLimit(post, setup, setup.limits.spindle_rpm, probability=0.95, check=0)
    assert unchecked.table_error == 0.0


def test_the_planned_cut_is_verified_by_directly_solved_samples(case):
    """``verify``: P(stable) of a cut from posterior samples solved directly at its speed (the
    same samples recomputed here, the soft boundary without table error); at the chance depth it
    agrees with the level within its stated standard error; 30 % deeper it does not hold, and
    ``plan``'s report carries a warning."""
    from scipy.special import expit

    from planner.learn.cli import verify_plan

    _, setup, post = case
    limit = ChanceLimit(post, setup, setup.limits.spindle_rpm, probability=0.9)
    rpm = 10300.0
    a = float(limit([rpm])[0])
    check = limit.verify(rpm, a, samples=40)
    thin = post.thinned(400)
    u = thin.samples[np.random.default_rng(1).permutation(thin.samples.shape[0])[:40]]
    direct = _direct(post, setup, u, [rpm])[:, 0]
    p = expit((np.log(direct) - np.log(a)) / post.likelihood.scale())
    assert check["probability_stable"] == pytest.approx(p.mean(), abs=2e-3)
    assert check["standard_error"] == pytest.approx(p.std(ddof=1) / np.sqrt(40), rel=0.05)
    assert check["table_probability_stable"] == pytest.approx(0.9, abs=1e-3)
    assert check["holds"] and abs(check["probability_stable"] - 0.9) < 3 * check["standard_error"] + 0.02
    learned = {}
    verify_plan(limit, learned, rpm, 1.3 * a)
    assert not learned["check"]["holds"] and learned["check"]["probability_stable"] < 0.8
    assert "below the level 0.9" in learned["warnings"][0]


@pytest.fixture(scope="module")
def wide(case, tmp_path_factory):
    """The case over 2-14 krpm, where the bound leaves the low speeds out: the posterior with the
    training cuts' error at 0.05, above the table checks' (about 0.01 here), so that the soft
    boundary does not depend on the speeds checked and the whole table's plan is the reference."""
    d = tmp_path_factory.mktemp("wide")
    _, setup, post = case
    post = replace(post, likelihood=replace(post.likelihood, model_error=0.05))
    setup = replace(setup, limits=replace(setup.limits, spindle_rpm=(2000.0, 14000.0)))
    write_setup(setup, d / "setup.yaml")
    write_posterior_model(post, d / "post.yaml")
    return d, setup, read_posterior(d / "post.yaml")


def test_plan_tabulates_only_the_speeds_where_a_cut_could_beat_it(wide, capsys):
    """``plan`` builds the chance limit's table from the top speed down, only as far as a cut
    could beat the plan found: its answer is the plan on the table over the whole range, the
    removal-rate bound (largest depth and feed) below the tabulated range is under it, the best
    plan down there (whole table) is worse, and the JSON says which speeds and why."""
    from oma.modal_io import read_modal_model
    from planner.optimize import plan

    d, setup, post = wide
    code = main(["plan", str(d / "setup.yaml"), "--model", str(d / "post.yaml"), "--probability", "0.9", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["success"]
    learned = out["learned"]
    lo = learned["rpm_range"][0]
    # the first table spans the top octave (7-14 krpm); on this case it was extended below it
    assert 2000.0 < lo < 7000.0 and learned["rpm_range"][1] == 14000.0 and learned["rpm_range_plans"] >= 1
    assert learned["rpm_range_note"].startswith(f"speeds below {lo:.0f} rpm not tabulated")
    assert set(learned["timings_s"]) == {"tables", "checks", "plans"}
    # the plan on the table over the whole range: the same cut (to the optimiser's tolerance)
    model = read_modal_model(d / "post.yaml")
    whole = ChanceLimit(post, setup, setup.limits.spindle_rpm, probability=0.9)
    assert whole.boundary_width == pytest.approx(learned["boundary_width"], rel=1e-12)
    ref = plan(setup, model, stability_limit=whole)
    assert "stability" in out["active_constraints"] and ref.success
    for key in ("spindle_rpm", "axial_depth_m", "feed_per_tooth_m", "mrr_m3_s"):
        assert out[key] == pytest.approx(getattr(ref, key), rel=1e-6), key
    # no cut below the tabulated range could beat it: the bound, evaluated ...
    lim = setup.limits
    bound = lim.axial_depth_m[1] * setup.cut.radial_depth_m * lim.feed_per_tooth_m[1] * setup.tool.teeth * lo / 60
    assert learned["rpm_range_below_mrr_m3_s"] == pytest.approx(bound, rel=1e-12)
    assert bound < out["mrr_m3_s"]
    # ... and the best plan down there, on the whole table, removes less still
    below = plan(replace(setup, limits=replace(lim, spindle_rpm=(2000.0, lo))), model, stability_limit=whole)
    assert below.mrr_m3_s < bound


def test_the_chance_depth_is_none_outside_the_tabulated_speeds(wide):
    """Outside its range a chance limit certifies no depth (1 nm: ``plan`` finds no cut there)."""
    from planner.learn.predictive import UNTABULATED_DEPTH_M
    from planner.learn.speed_range import chance_limit_for_plan
    from oma.modal_io import read_modal_model

    d, setup, post = wide
    limit, speeds = chance_limit_for_plan(post, read_modal_model(d / "post.yaml"), setup, probability=0.9)
    lo, hi = limit.rpm_range
    assert speeds.restricted and speeds.rpm_range == limit.rpm_range and hi == 14000.0
    depth = limit([0.9 * lo, lo, hi, 1.01 * hi])
    assert depth[0] == UNTABULATED_DEPTH_M == depth[3] and np.all(depth[1:3] > 1e-4)
    # a narrow range is tabulated whole at once
    narrow = replace(setup, limits=replace(setup.limits, spindle_rpm=(9000.0, 12000.0)))
    limit, speeds = chance_limit_for_plan(post, read_modal_model(d / "post.yaml"), narrow, probability=0.9)
    assert limit.rpm_range == (9000.0, 12000.0) and not speeds.restricted and speeds.plans == 0
    assert speeds.note() == "the whole speed range tabulated"


def test_a_table_extended_downward_solves_only_its_new_speeds(case, monkeypatch):
    """``build_table(..., known=)`` copies the lattice points the known table holds and solves the
    rest: the values equal a table built at once (ZOA: each speed's limit alone), and no known
    speed is solved again. A table of other nodes is refused."""
    from planner.learn import tables
    from planner.learn.predictive import predictive_grid

    _, setup, post = case
    grid = predictive_grid(post)
    base = (post.reference, setup.tool, setup.cut, post.coefficients)

    def cuts(lo, hi):
        r = np.geomspace(lo, hi, 30)
        return r, np.full(r.size, setup.cut.radial_depth_m), np.ones(r.size, bool)

    top = tables.build_table(*base, *cuts(9000.0, 12000.0), grid, method="zoa", workers=1)
    solved, job = [], tables._log_limits_job
    monkeypatch.setattr(tables, "_log_limits_job", lambda j: solved.append(j[5]) or job(j))
    grown = tables.build_table(*base, *cuts(6000.0, 12000.0), grid, method="zoa", workers=1, known=top)
    monkeypatch.undo()
    once = tables.build_table(*base, *cuts(6000.0, 12000.0), grid, method="zoa", workers=1)
    np.testing.assert_array_equal(grown.lattice[0], once.lattice[0])
    np.testing.assert_allclose(grown.values[0], once.values[0], rtol=1e-9)
    new = np.round(np.log(np.concatenate(solved)) / grid.log_speed_step).astype(np.int64)
    assert not np.isin(new, top.lattice[0]).any()
    assert np.unique(new).size == once.lattice[0].size - top.lattice[0].size
    coarse = replace(grid, log_speed_step=2 * grid.log_speed_step)
    with pytest.raises(ValueError, match="known must be a table of the same lattice step"):
        tables.build_table(*base, *cuts(6000.0, 12000.0), coarse, method="zoa", workers=1, known=top)
