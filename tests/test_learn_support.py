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
from planner.learn.posterior_io import read_posterior_cuts, write_posterior_model
from planner.learn.support import SPEED_TOLERANCE, plan_support
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


def _plan(capsys, d, model):
    code = main(["plan", str(d / "setup.yaml"), "--model", str(d / model), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)


def test_plan_says_whether_the_test_cuts_back_its_cut(planned, capsys):
    d, post, far = planned
    out = _plan(capsys, d, "far.yaml")
    n, ap = out["spindle_rpm"], out["axial_depth_m"]
    support = out["learned"]["support"]
    assert support["status"] == "extrapolated" and support["nearby"] == 0
    assert any("extrapolation from the cuts" in w and "none was cut there" in w for w in out["learned"]["warnings"])
    # the plan cut as a test and found stable: backed, the warning gone; the same plan (the cuts
    # change nothing but the support)
    write_posterior_model(post, d / "backed.yaml", cuts=far.concat(_cuts([(round(n, -1), ap * 1.001, D, True, STABLE)])))
    out = _plan(capsys, d, "backed.yaml")
    assert (out["spindle_rpm"], out["axial_depth_m"]) == (n, ap)
    assert out["learned"]["support"]["status"] == "backed" and out["learned"]["support"]["backed_by"] == [3]
    assert not any("test cut" in w for w in out["learned"].get("warnings", []))
    # ... and found chattering a little shallower: contradicted, with a warning naming the cut
    write_posterior_model(post, d / "chatter.yaml", cuts=far.concat(_cuts([(n, 0.9 * ap, D, True, CHATTER)])))
    out = _plan(capsys, d, "chatter.yaml")
    assert out["learned"]["support"]["status"] == "contradicted"
    assert any("cut 3 (" in w and "chatters" in w for w in out["learned"]["warnings"])
    main(["plan", str(d / "setup.yaml"), "--model", str(d / "chatter.yaml")])
    assert "test cuts within 1 % of its speed: contradicted" in capsys.readouterr().out
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
