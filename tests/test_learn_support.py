"""What the test cuts say about a planned cut (``plan`` with a posterior): backed, contradicted or
extrapolated (:mod:`planner.learn.support`)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from learn_cases import slotting_posterior

from oma.errors import ModelError
from oma.modal_io import write_modal_model
from planner.cli import main
from planner.learn.likelihood import CHATTER, STABLE, UNCERTAIN
from planner.learn.outcomes_io import CutTable
from planner.learn.posterior_io import read_posterior, read_posterior_cuts, write_posterior_model
from planner.learn.support import SPEED_TOLERANCE, best_backed, plan_support
from planner.learn.synthetic import tool_problem, true_limits
from stability.setup_io import write_setup

D = 0.0127


def _cuts(rows, weight=None):
    """``rows`` of (rpm, ap, ae, down, outcome)."""
    a = np.array([r[:3] for r in rows], dtype=float)
    n = len(rows)
    return CutTable(a[:, 0], a[:, 1], a[:, 2], np.array([r[3] for r in rows]), np.array([r[4] for r in rows]),
                    np.ones(n) if weight is None else np.asarray(weight, float), np.full(n, np.nan),
                    np.zeros(n, bool))


def test_a_cut_backs_a_plan_only_at_its_speed_width_and_milling_and_at_least_its_depth():
    plan = dict(spindle_rpm=20000.0, axial_depth_m=0.010, radial_depth_m=0.5 * D, down=True)
    off = 1 + 1.5 * SPEED_TOLERANCE
    one = {  # each alone: does it back the plan?
        "deeper, 0.5 % off in speed, 1 % in width": ((20100.0, 0.011, 0.505 * D, True, STABLE), True),
        "the plan itself": ((20000.0, 0.010, 0.5 * D, True, STABLE), True),
        "outside the speed tolerance": ((20000.0 * off, 0.011, 0.5 * D, True, STABLE), False),
        "shallower": ((20000.0, 0.009, 0.5 * D, True, STABLE), False),
        "narrower": ((20000.0, 0.012, 0.4 * D, True, STABLE), False),
        "wider": ((20000.0, 0.012, 0.6 * D, True, STABLE), False),
        "up milling": ((20000.0, 0.012, 0.5 * D, False, STABLE), False),
        "uncertain": ((20000.0, 0.012, 0.5 * D, True, UNCERTAIN), False),
    }
    for name, (row, backs) in one.items():
        s = plan_support(_cuts([row]), **plan)
        assert s["status"] == ("backed" if backs else "extrapolated"), name
    # a detection less sure than not neither backs nor contradicts
    s = plan_support(_cuts([(20000.0, 0.012, 0.5 * D, True, STABLE)], weight=[0.3]), **plan)
    assert s["status"] == "extrapolated" and s["nearby"] == 0
    # the deepest stable cut nearby is reported
    s = plan_support(_cuts([(20050.0, 0.008, 0.5 * D, True, STABLE), (19950.0, 0.006, 0.5 * D, True, STABLE),
                            (20000.0, 0.009, 0.3 * D, True, STABLE)]), **plan)
    assert s["status"] == "extrapolated" and s["deepest_stable_nearby_m"] == 0.008 and s["nearby"] == 2


def test_a_stable_mark_the_posterior_takes_for_wrong_backs_nothing_while_a_doubted_chatter_mark_still_contradicts():
    plan = dict(spindle_rpm=20000.0, axial_depth_m=0.010, radial_depth_m=0.5 * D, down=True)
    rows = [(20000.0, 0.030, 0.5 * D, True, STABLE), (20000.0, 0.012, 0.5 * D, True, STABLE)]
    # the deep mark looks wrong to the posterior (a flipped chatter), the other does not
    s = plan_support(_cuts(rows), **plan, mislabelled=[0.9, 0.1])
    assert s["status"] == "backed" and s["backed_by"] == [1] and s["doubted"] == [0]
    s = plan_support(_cuts(rows[:1]), **plan, mislabelled=[0.9])
    assert s["status"] == "extrapolated" and s["doubted"] == [0] and s["deepest_stable_nearby_m"] is None
    # not known (NaN, or a file written before the probabilities were): taken as sure
    assert plan_support(_cuts(rows[:1]), **plan, mislabelled=[np.nan])["status"] == "backed"
    assert plan_support(_cuts(rows[:1]), **plan)["status"] == "backed"
    chatter = _cuts([(20000.0, 0.009, 0.5 * D, True, CHATTER)])
    assert plan_support(chatter, **plan, mislabelled=[0.95])["status"] == "contradicted"


def _slot_mrr(setup, rpm, ap, fz):
    return rpm / 60.0 * setup.tool.teeth * fz * ap * setup.cut.radial_depth_m


def test_the_best_backed_cut_is_the_largest_removal_rate_the_sure_stable_cuts_prove_under_the_setups_limits():
    """:func:`best_backed` on the slotting setup (9-12 krpm, feed up to 0.1 mm/tooth): each stable
    cut at the engagement proves its speed up to its depth; the answer is the best of those by the
    removal rate's closed form, and honours the other limits (a spindle power limit checked against
    the mean cutting power of a full slot in closed form)."""
    from dataclasses import replace

    problem, setup, _ = slotting_posterior()
    rows = [(10000.0, 3.0e-3, D, True, STABLE),    # 30 000 rpm mm: the best plain candidate
            (11800.0, 2.4e-3, D, True, STABLE),    # 28 320
            (9500.0, 8.0e-3, D, False, STABLE),    # up milling: another limit
            (11000.0, 20e-3, D, True, STABLE),     # looks wrong to the posterior (below)
            (12500.0, 10e-3, D, True, STABLE),     # outside the setup's speed range
            (9200.0, 30e-3, 0.5 * D, True, STABLE)]  # another width
    doubt = [0.01, 0.02, 0.01, 0.9, 0.01, 0.01]
    fz = setup.limits.feed_per_tooth_m[1]
    best = best_backed(setup, problem.prior, _cuts(rows), mislabelled=doubt)
    assert best["backed_by"] == 0 and abs(best["spindle_rpm"] / 10000.0 - 1) < 2e-4
    assert best["axial_depth_m"] == pytest.approx(3.0e-3, rel=1e-6) and best["feed_per_tooth_m"] == pytest.approx(fz)
    assert best["mrr_m3_s"] == pytest.approx(_slot_mrr(setup, 10000.0, 3.0e-3, fz), rel=2e-4)
    # a chatter mark at 10 000 rpm under 3 mm contradicts that cut's plan: the next one
    contradicted = _cuts(rows + [(10000.0, 2.9e-3, D, True, CHATTER)])
    best = best_backed(setup, problem.prior, contradicted, mislabelled=doubt + [0.9])
    assert best["backed_by"] == 1 and best["mrr_m3_s"] == pytest.approx(_slot_mrr(setup, 11800.0, 2.4e-3, fz), rel=2e-4)
    # without the posterior's doubt the 20 mm mark would be taken at face value
    assert best_backed(setup, problem.prior, _cuts(rows))["backed_by"] == 3
    # a cut at either end of the setup's speed range is planned inside it
    for n in setup.limits.spindle_rpm:
        best = best_backed(setup, problem.prior, _cuts([(n, 3e-3, D, True, STABLE)]))
        assert setup.limits.spindle_rpm[0] <= best["spindle_rpm"] <= setup.limits.spindle_rpm[1]
        assert abs(best["spindle_rpm"] / n - 1) <= 2e-4
    # a power limit binds. The mean cutting power of a full slot, z teeth: the mean tangential force
    # z a (2 Ktc fz + pi Kte) / (2 pi) times the edge speed pi D n / 60 (the helix does not change
    # the mean). At a fixed power the removal rate n a fz grows with fz (the edge term costs power
    # per depth, not per feed), so each candidate's best is the largest feed at the depth the
    # power allows, capped by the cut's depth
    c = replace(setup.material.cutting_coefficients, Kte_N_m=5e3)  # an edge force, so that the feed matters
    z = setup.tool.teeth

    def power(n, ap, f):
        return z * ap * (2 * c.Ktc_N_m2 * f + np.pi * c.Kte_N_m) / (2 * np.pi) * np.pi * D * n / 60.0

    limit = power(10000.0, 3.0e-3, 0.6 * fz)
    limited = replace(setup, material=replace(setup.material, cutting_coefficients=c),
                      limits=replace(setup.limits, spindle_power_W=limit))
    best = best_backed(limited, problem.prior, _cuts(rows), mislabelled=doubt)
    expected = {i: _slot_mrr(setup, n, min(a, a * limit / power(n, a, fz)), fz)
                for i, (n, a, *_) in enumerate(rows[:2])}
    assert "power" in best["active_constraints"] and best["feed_per_tooth_m"] == pytest.approx(fz, rel=1e-3)
    assert best["mrr_m3_s"] == pytest.approx(max(expected.values()), rel=0.01)
    assert power(best["spindle_rpm"], best["axial_depth_m"], best["feed_per_tooth_m"]) == pytest.approx(limit, rel=0.01)


def test_a_chatter_cut_at_or_below_the_plan_contradicts_it_even_where_another_backs_it():
    plan = dict(spindle_rpm=20000.0, axial_depth_m=0.010, radial_depth_m=0.5 * D, down=True)
    backing = (20000.0, 0.012, 0.5 * D, True, STABLE)
    for row, contradicts in [((20080.0, 0.009, 0.5 * D, True, CHATTER), True),
                             ((20000.0, 0.010, 0.5 * D, True, CHATTER), True),
                             ((20000.0, 0.011, 0.5 * D, True, CHATTER), False),   # deeper: says nothing
                             ((20000.0, 0.009, 0.25 * D, True, CHATTER), False),  # another width
                             ((20000.0, 0.009, 0.5 * D, False, CHATTER), False)]:  # up milling
        s = plan_support(_cuts([backing, row]), **plan)
        assert s["status"] == ("contradicted" if contradicts else "backed")
        assert s["contradicted_by"] == ([1] if contradicts else []) and s["backed_by"] == [0]


def test_the_rule_holds_on_cuts_labelled_by_the_truth_and_needs_the_plans_own_width():
    """At 20 speeds, the benchmark tool's SDM limit at 0.5 D down: a plan at 0.9 of it is never
    contradicted by cuts at its speed and width from 0.5 to 1.5 times the limit labelled by the
    truth (the one at 0.95 backs it); a plan at 1.1 of it is contradicted.
    And why the width must match: at one speed the limit is not monotone in the radial depth (at
    some speeds the 0.5 D limit is above the 0.25 D one by half again or more), so a cut that
    chattered at 0.25 D says nothing about a plan at 0.5 D."""
    problem = tool_problem()
    rpm = np.geomspace(6000.0, 24000.0, 20)
    lim = {w: true_limits(problem, rpm, np.full(rpm.size, w * D), np.ones(rpm.size, bool), converged=False)
           for w in (0.25, 0.5)}
    assert np.any(lim[0.5] > 1.5 * lim[0.25]) and np.any(lim[0.5] < lim[0.25])
    for j, n in enumerate(rpm):
        rows = [(n, f * lim[0.5][j], 0.5 * D, True, CHATTER if f >= 1 else STABLE) for f in (0.5, 0.8, 0.95, 1.05, 1.2, 1.5)]
        safe = plan_support(_cuts(rows), n, 0.9 * lim[0.5][j], 0.5 * D, True)
        assert safe["status"] == "backed" and safe["deepest_stable_nearby_m"] < lim[0.5][j]
        unsafe = plan_support(_cuts(rows), n, 1.1 * lim[0.5][j], 0.5 * D, True)
        assert unsafe["status"] == "contradicted"


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """A posterior around the prior (ZOA, slotting, 9-12 krpm) written with far-off cuts, and the
    cut ``plan`` makes of it."""
    d = tmp_path_factory.mktemp("support")
    problem, setup, post = slotting_posterior()
    write_setup(setup, d / "setup.yaml")
    write_modal_model(problem.prior, d / "prior.yaml")
    far = _cuts([(6000.0, 1e-3, D, True, STABLE), (6500.0, 9e-3, D, True, CHATTER), (7000.0, 2e-3, D, False, STABLE)])
    write_posterior_model(post, d / "far.yaml", cuts=far)
    return d, post, far


def _plan(capsys, d, model, *extra):
    code = main(["plan", str(d / "setup.yaml"), "--model", str(d / model), "--json", *extra])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)


def test_plan_says_whether_the_test_cuts_back_its_cut(planned, capsys, tmp_path, monkeypatch):
    import planner.cli as cli

    d, post, far = planned
    out = _plan(capsys, d, "far.yaml")
    n, ap = out["spindle_rpm"], out["axial_depth_m"]
    support = out["learned"]["support"]
    assert support["status"] == "extrapolated" and support["nearby"] == 0
    assert any("extrapolation from the cuts" in w and "none was cut there" in w for w in out["learned"]["warnings"])
    # no stable cut at the setup's engagement within its speed range (9-12 krpm) proves anything
    assert support["best_backed"] is None
    main(["plan", str(d / "setup.yaml"), "--model", str(d / "far.yaml")])
    assert "no sure stable test cut (marks the posterior takes for wrong with P > 0.05 left out)" in capsys.readouterr().out
    # the plan cut as a test and found stable: backed, the warning gone; the same plan (the cuts
    # change nothing but the support)
    write_posterior_model(post, d / "backed.yaml", cuts=far.concat(_cuts([(round(n, -1), ap * 1.001, D, True, STABLE)])))
    out = _plan(capsys, d, "backed.yaml")
    assert (out["spindle_rpm"], out["axial_depth_m"]) == (n, ap)
    assert out["learned"]["support"]["status"] == "backed" and out["learned"]["support"]["backed_by"] == [3]
    assert not any("test cut" in w for w in out["learned"].get("warnings", []))
    # ... and found chattering a little shallower: contradicted, with a warning naming the cut
    # (and a shallow stable cut at 10 000 rpm: the best cut the cuts prove, which the plan's removal rate beats)
    write_posterior_model(post, d / "chatter.yaml", cuts=far.concat(_cuts([(n, 0.9 * ap, D, True, CHATTER),
                                                                           (10000.0, 1e-3, D, True, STABLE)])))
    drawn = {}
    monkeypatch.setattr(cli, "save_figure", lambda fig, path: drawn.update(fig=fig))
    out = _plan(capsys, d, "chatter.yaml", "-o", str(tmp_path / "plan.png"))
    support = out["learned"]["support"]
    assert support["status"] == "contradicted"
    assert any("cut 3 (" in w and "chatters" in w for w in out["learned"]["warnings"])
    alt = support["best_backed"]
    assert alt["backed_by"] == 4 and alt["axial_depth_m"] == pytest.approx(1e-3, rel=1e-6)
    assert alt["share_of_plan"] == pytest.approx(alt["mrr_m3_s"] / out["mrr_m3_s"]) and alt["share_of_plan"] < 1
    # the figure: the plan's lobes with the test cuts at its engagement and the best backed cut
    ax = drawn["fig"].axes[0]
    lines, labels = ax.get_legend_handles_labels()
    assert "test cut: chatter" in labels and "test cut: stable" in labels
    diamond = lines[next(i for i, t in enumerate(labels) if t.startswith("best cut a test proves"))]
    assert np.allclose(np.ravel(diamond.get_xydata()), [alt["spindle_rpm"], 1e3 * alt["axial_depth_m"]])
    assert alt["probability_mislabelled"] is None  # not in the file: counted
    # a deep stable mark at 11 000 rpm doubted at 0.1 counts only where the plan's level allows a
    # mark that doubt (max_doubt = 1 - P): not at the default P >= 0.95, at P >= 0.8; it then proves
    # more than the plan removes, which is warned about (the posterior doubts it)
    write_posterior_model(post, d / "doubted.yaml",
                          cuts=far.concat(_cuts([(n, 0.9 * ap, D, True, CHATTER), (10000.0, 1e-3, D, True, STABLE),
                                                 (11000.0, 40e-3, D, True, STABLE)])),
                          mislabelled=[0.0, 0.0, 0.0, 0.0, 0.01, 0.1])
    learned = _plan(capsys, d, "doubted.yaml")["learned"]
    support = learned["support"]
    assert support["max_doubt"] == 0.05 and support["best_backed"]["backed_by"] == 4
    assert support["best_backed"]["probability_mislabelled"] == 0.01
    assert not any("rests on cut" in w for w in learned["warnings"])
    out = _plan(capsys, d, "doubted.yaml", "--probability", "0.8")
    alt = out["learned"]["support"]["best_backed"]
    assert out["learned"]["support"]["max_doubt"] == 0.2 and alt["backed_by"] == 5 and alt["share_of_plan"] > 1
    assert any("rests on cut 5's mark alone" in w for w in out["learned"]["warnings"])
    main(["plan", str(d / "setup.yaml"), "--model", str(d / "chatter.yaml")])
    text = capsys.readouterr().out
    assert "test cuts within 1 % of its speed: contradicted" in text
    assert "best cut a stable test cut proves: 10000 rpm, axial depth 1.00 mm" in text
    # a posterior written without its cuts: not known, said so
    write_posterior_model(post, d / "old.yaml")
    out = _plan(capsys, d, "old.yaml")
    assert out["learned"]["support"] is None and any("does not carry the test cuts" in w
                                                     for w in out["learned"]["warnings"])


def test_malformed_cuts_in_a_posterior_file_are_a_one_line_error_and_nothing_is_written(planned, capsys, tmp_path):
    d, _, _ = planned
    text = (d / "far.yaml").read_text()
    assert read_posterior_cuts(d / "far.yaml").n_cuts == 3
    bad = d / "bad.yaml"
    bad.write_text(text.replace("outcome: chatter", "outcome: wobbly"))
    with pytest.raises(ModelError, match=r"x_posterior.cuts\[1\].outcome"):
        read_posterior_cuts(bad)
    bad.write_text(text.replace("milling: up", "milling: sideways"))
    with pytest.raises(ModelError, match=r"x_posterior.cuts\[2\].milling"):
        read_posterior_cuts(bad)
    for p in ("1.5", "wrong", "true"):  # a probability of being wrong must be one
        odd = d / "odd.yaml"
        write_posterior_model(read_posterior(d / "far.yaml"), odd, cuts=read_posterior_cuts(d / "far.yaml").cuts,
                              mislabelled=[0.01, 0.02, 0.03])
        odd.write_text(odd.read_text().replace("probability_mislabelled: 0.02", f"probability_mislabelled: {p}"))
        with pytest.raises(ModelError, match=r"x_posterior.cuts\[1\].probability_mislabelled"):
            read_posterior_cuts(odd)
    code = main(["plan", str(d / "setup.yaml"), "--model", str(bad), "-o", str(tmp_path / "plan.png")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "x_posterior.cuts[2].milling" in err
    assert not (tmp_path / "plan.png").exists()


def test_lobes_of_a_posterior_draw_its_test_cuts_at_the_setups_engagement(planned, capsys, tmp_path, monkeypatch):
    """``lobes --model POSTERIOR -o FIG``: the probability lobes with the test cuts the file carries,
    those at the setup's engagement only (here slotting, down milling: two of the three)."""
    import planner.cli as cli

    d, _, _ = planned
    drawn = {}
    monkeypatch.setattr(cli, "save_figure", lambda fig, path: drawn.update(fig=fig, path=path))
    code = main(["lobes", str(d / "setup.yaml"), "--model", str(d / "far.yaml"), "-o", str(tmp_path / "l.png"),
                 "--rpm", "6000", "12000", "--json"])
    capsys.readouterr()
    assert code == 0
    ax = drawn["fig"].axes[0]
    labels = ax.get_legend_handles_labels()[1]
    assert "test cut: stable" in labels and "test cut: chatter" in labels
    from matplotlib.collections import PathCollection

    points = np.vstack([c.get_offsets() for c in ax.collections if isinstance(c, PathCollection)])
    assert sorted(map(tuple, np.round(points, 3))) == [(6000.0, 1.0), (6500.0, 9.0)]


def test_the_figures_grey_the_stable_marks_the_posterior_takes_for_wrong():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PathCollection

    from planner.learn.plots import draw_test_cuts

    cuts = _cuts([(10000.0, 3e-3, D, True, STABLE), (11000.0, 20e-3, D, True, STABLE),
                  (12000.0, 5e-3, D, True, CHATTER), (9000.0, 4e-3, 1.01 * D, True, STABLE),  # within 2 %
                  (9500.0, 4e-3, 0.5 * D, True, STABLE)])                                    # another width
    fig, ax = plt.subplots()
    draw_test_cuts(ax, cuts, D, "down", mislabelled=[0.1, 0.9, 0.95, np.nan, 0.0])
    drawn = {c.get_label(): np.round(c.get_offsets(), 3).tolist() for c in ax.collections
             if isinstance(c, PathCollection)}
    plt.close(fig)
    assert drawn == {"test cut: stable": [[10000.0, 3.0], [9000.0, 4.0]],
                     "test cut: stable, taken for wrong": [[11000.0, 20.0]],
                     "test cut: chatter": [[12000.0, 5.0]]}


def test_the_plan_figure_greys_the_speeds_where_the_chance_limit_was_not_tabulated():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from planner.learn.plots import shade_untabulated

    fig, ax = plt.subplots()
    shade_untabulated(ax, (5000.0, 20000.0), (500.0, 24000.0))  # both ends not tabulated
    shade_untabulated(ax, (500.0, 24000.0), (500.0, 24000.0))   # the whole range: nothing
    spans = [p.get_x() for p in ax.patches], [p.get_x() + p.get_width() for p in ax.patches]
    labels = [p.get_label() for p in ax.patches if not p.get_label().startswith("_")]
    plt.close(fig)
    assert spans == ([500.0, 20000.0], [5000.0, 24000.0]) and len(labels) == 1
