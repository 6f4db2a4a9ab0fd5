"""``robomill learn`` end to end (in-process), and every bad input: exit 2, one line, nothing written."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from oma.modal_io import read_modal_model, write_modal_model
from planner.cli import main
from planner.learn.outcomes_io import CutTable, CutsError, detect_outcome, read_cuts, record_outcome
from planner.learn.likelihood import UNCERTAIN, Likelihood
from planner.learn.posterior_io import read_posterior, read_posterior_cuts
from planner.learn.synthetic import label, random_cuts, record_labels, tool_problem, true_limits
from stability.setup_io import write_setup


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("learn")
    problem = tool_problem(u_prior=(0.05, -0.3, 0.2, 0.1, 0.0))
    write_setup(problem.setup, d / "setup.yaml")
    write_modal_model(problem.prior, d / "prior.yaml")
    rng = np.random.default_rng(4)
    cuts = random_cuts(problem, 10, rng, immersions=(0.5, 1.0), depth_range=(1e-3, 15e-3))
    cuts = label(cuts, true_limits(problem, cuts.spindle_rpm, cuts.radial_depth_m, cuts.down, converged=False),
                 rng, flip=0.0)
    words = {0: "stable", 1: "chatter"}
    lines = ["spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome,x_operator"]
    for i in range(cuts.n_cuts):
        lines.append(f"{cuts.spindle_rpm[i]},{cuts.axial_depth_m[i]},{cuts.radial_depth_m[i]},"
                     f"{'down' if cuts.down[i] else 'up'},{words[int(cuts.outcome[i])]},ann")
    lines.append(f"12000,0.002,{0.5 * 0.0127},down,uncertain,bob")
    (d / "cuts.csv").write_text("\n".join(lines) + "\n")
    (d / "predict.csv").write_text("spindle_rpm,axial_depth_m,radial_depth_m,milling\n"
                                   f"10000,0.0005,{0.0127},down\n10000,0.05,{0.0127},down\n")
    return d, problem


def _run(capsys, argv):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("suggest_for", ["mrr", "boundary"])
def test_learn_writes_a_posterior_that_reads_back(files, capsys, suggest_for):
    d, problem = files
    code, out, err = _run(capsys, ["learn", str(d / "setup.yaml"), "--model", str(d / "prior.yaml"), "--cuts",
                                   str(d / "cuts.csv"), "--method", "zoa", "--samples", "400", "--predict",
                                   str(d / "predict.csv"), "--suggest", "2", "--suggest-for", suggest_for,
                                   "-o", str(d / "post.yaml"), "--plot", str(d / "lobes.png"), "--rpm", "8000", "20000",
                                   "--json"])
    assert code == 0, err
    res = json.loads(out)
    for key in ("parameters", "map_model", "accuracy_before", "accuracy_after", "cause", "predictions",
                "suggested", "warnings"):
        assert key in res
    assert res["predictions_table_error"] >= 0  # the predictions' table checked against direct limits
    assert res["n_cuts"] == len((d / "cuts.csv").read_text().strip().splitlines()) - 1  # every row but the header
    assert res["map_model"]["format"] == "robomill-modal/1"
    assert res["cause"] in ("frequency", "stiffness", "damping", "Ktc", "Krc")
    # a shallow cut is surely stable, a 50 mm slot surely chatters
    p = [x["probability_stable"] for x in res["predictions"]]
    assert p[0] > 0.95 and p[1] < 0.05
    assert len(res["suggested"]) == 2 and all(s["outcome"] == "" for s in res["suggested"])
    assert res["suggested_outcomes"] == "marked"  # the table holds marks: the next cuts are judged alike
    score = {"mrr": "x_expected_improvement_mrr_m3_s", "boundary": "x_expected_variance_reduction"}[suggest_for]
    assert all(s[score] >= 0 for s in res["suggested"])
    # the share of wrong marks is reported with the rest (fixed and learned averaged by default, with
    # the learned one's probability), and the suspect marks listed
    rate = res["parameters"]["mislabel_rate"]
    assert not rate["fixed"] and 0 <= rate["learned_probability"] <= 1 and isinstance(res["suspect_labels"], list)
    # the posterior file is an ordinary modal model for every reader (x_posterior ignored) ...
    model = read_modal_model(d / "post.yaml")
    assert model.n_modes == 1
    # ... and its samples read back
    post = read_posterior(d / "post.yaml")
    assert post is not None and post.samples.shape[1] == 5
    np.testing.assert_allclose(post.reference.natural_frequency_hz, problem.prior.natural_frequency_hz)
    np.testing.assert_allclose(post.model_at(post.samples[0])[0].natural_frequency_hz, model.natural_frequency_hz)
    assert read_posterior(d / "prior.yaml") is None
    # ... with the cuts it was learned from, in the table's order (``plan`` compares its cut with them)
    back = read_posterior_cuts(d / "post.yaml")
    table = read_cuts(d / "cuts.csv", tool=problem.setup.tool)
    assert back.n_cuts == table.n_cuts == 11 and back.cuts.outcome[-1] == UNCERTAIN
    for k in ("spindle_rpm", "axial_depth_m", "radial_depth_m", "down", "outcome", "weight"):
        np.testing.assert_array_equal(getattr(back.cuts, k), getattr(table, k))
    # ... each mark with the posterior's probability that it is wrong, the suspect marks above 0.5
    # (the uncertain last one has none)
    wrong = back.mislabelled
    assert np.all((wrong[:-1] >= 0) & (wrong[:-1] <= 1)) and np.isnan(wrong[-1])
    assert sorted(s["index"] for s in res["suspect_labels"]) == list(np.flatnonzero(wrong > 0.5))
    assert read_posterior_cuts(d / "prior.yaml") is None
    assert (d / "lobes.png").stat().st_size > 1000


def _bad(d, name, text):
    p = d / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("body,match", [
    ("spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome\n1e4,1e-3,5e-3,down,stable\n"
     "1e4,2e-3,5e-3,down,wobbly\n1e4,3e-3,5e-3,down,chatter\n", "outcome: expected stable, chatter or uncertain"),
    ("spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome\n1e4,1e-3,5e-3,down,stable\n"
     "1e4,2e-3,0.02,down,stable\n1e4,3e-3,5e-3,down,chatter\n", "radial_depth_m: expected at most the tool diameter"),
    ("spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome\n1e4,1e-3,5e-3,down,stable\n"
     "1e4,-2e-3,5e-3,down,stable\n1e4,3e-3,5e-3,down,chatter\n", "axial_depth_m: expected a finite number > 0"),
    ("spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome\n1e4,1e-3,5e-3,down,stable\n"
     "1e4,3e-3,5e-3,down,chatter\n", "rows: expected at least 3 cuts"),
    ("spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome\n1e4,1e-3,5e-3,side,stable\n"
     "1e4,2e-3,5e-3,down,stable\n1e4,3e-3,5e-3,down,chatter\n", "milling: expected 'up' or 'down'"),
    ("spindle_rpm,axial_depth_m,radial_depth_m,milling\n1e4,1e-3,5e-3,down\n", "header: expected a column 'outcome'"),
])
def test_bad_cuts_exit_2_nothing_written(files, capsys, tmp_path, body, match):
    d, _ = files
    cuts = _bad(tmp_path, "cuts.csv", body)
    out = tmp_path / "post.yaml"
    code, stdout, err = _run(capsys, ["learn", str(d / "setup.yaml"), "--model", str(d / "prior.yaml"), "--cuts",
                                      str(cuts), "-o", str(out)])
    assert code == 2
    assert match in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists() and stdout == ""


def test_deeper_than_the_flutes_and_no_coefficients(files, capsys, tmp_path):
    d, problem = files
    code, _, err = _run(capsys, ["learn", str(d / "setup.yaml"), "--model", str(d / "prior.yaml"), "--cuts",
                                 str(d / "cuts.csv"), "--flute-length", "0.003", "-o", str(tmp_path / "p.yaml")])
    assert code == 2 and "at most the flute length" in err and not (tmp_path / "p.yaml").exists()
    text = (d / "setup.yaml").read_text()
    start = text.index("  cutting_coefficients")
    rest = text[start:].split("\n")
    keep = [rest[0]] + [ln for ln in rest[1:] if not ln.startswith("    ")]
    no_coef = tmp_path / "setup.yaml"
    no_coef.write_text(text[:start] + "\n".join(keep[1:]))
    code, _, err = _run(capsys, ["learn", str(no_coef), "--model", str(d / "prior.yaml"), "--cuts",
                                 str(d / "cuts.csv"), "-o", str(tmp_path / "p.yaml")])
    assert code == 2 and "cutting" in err and err.count("\n") == 1 and not (tmp_path / "p.yaml").exists()


def test_prior_sd_option(files, capsys, tmp_path):
    d, _ = files
    code, _, err = _run(capsys, ["learn", str(d / "setup.yaml"), "--model", str(d / "prior.yaml"), "--cuts",
                                 str(d / "cuts.csv"), "--prior-sd", "stifness=0.2"])
    assert code == 2 and "--prior-sd" in err


@pytest.mark.parametrize("option,value", [("--mislabel", "0.5"), ("--mislabel", "-0.1"), ("--mislabel-sd", "-1"),
                                          ("--noisy-mislabel", "0"), ("--noisy-mislabel", "0.5"),
                                          ("--detection-lag", "-0.1"), ("--detection-scale", "0"),
                                          ("--mode-correlation", "1.2"), ("--mode-correlation", "-0.5")])
def test_mislabel_options(files, capsys, tmp_path, option, value):
    d, _ = files
    code, _, err = _run(capsys, ["learn", str(d / "setup.yaml"), "--model", str(d / "prior.yaml"), "--cuts",
                                 str(d / "cuts.csv"), option, value, "-o", str(tmp_path / "p.yaml")])
    assert code == 2 and option in err and err.count("\n") == 1 and not (tmp_path / "p.yaml").exists()


def test_mislabel_model_needs_a_rate_to_learn(files, capsys, tmp_path):
    d, _ = files
    code, _, err = _run(capsys, ["learn", str(d / "setup.yaml"), "--model", str(d / "prior.yaml"), "--cuts",
                                 str(d / "cuts.csv"), "--mislabel", "0", "--mislabel-model", "average",
                                 "-o", str(tmp_path / "p.yaml")])
    assert code == 2 and "--mislabel-model" in err and err.count("\n") == 1 and not (tmp_path / "p.yaml").exists()


@pytest.mark.parametrize("argv,mode", [([], "average"), (["--mislabel-sd", "0"], "fixed"),
                                       (["--mislabel-sd", "1.5"], "learned"), (["--mislabel", "0"], "fixed"),
                                       (["--mislabel-model", "fixed"], "fixed")])
def test_mislabel_options_choose_the_model_of_the_share(argv, mode):
    """The default averages; --mislabel-sd alone keeps its old meaning (> 0 learned, 0 fixed)."""
    from planner.cli import build_parser
    from planner.learn.cli import _likelihood

    args = build_parser().parse_args(["learn", "s.yaml", "--model", "m.yaml", "--cuts", "c.csv", *argv])
    lk = _likelihood(args)
    got = "average" if lk.averages_mislabel else "learned" if lk.learns_mislabel else "fixed"
    assert got == mode


def test_detection_options_set_the_boundary_of_detected_outcomes():
    from planner.cli import build_parser
    from planner.learn.cli import _likelihood
    from planner.learn.likelihood import DETECTION_LAG, DETECTION_SCALE

    base = ["learn", "s.yaml", "--model", "m.yaml", "--cuts", "c.csv"]
    lk = _likelihood(build_parser().parse_args(base))
    assert (lk.detection_lag, lk.detection_scale) == (DETECTION_LAG, DETECTION_SCALE)
    lk = _likelihood(build_parser().parse_args(base + ["--detection-lag", "0", "--detection-scale", "0.03"]))
    assert (lk.detection_lag, lk.detection_scale) == (0.0, 0.03)


def test_averaged_mislabel_rate_is_reported_and_read_back(files, capsys, tmp_path):
    """``--mislabel-model average``: the posterior probability of the learned rate in the JSON, the
    averaged rate's prior (half of it at 5 %) and the setting kept in the posterior file."""
    d, _ = files
    code, out, err = _run(capsys, ["learn", str(d / "setup.yaml"), "--model", str(d / "prior.yaml"), "--cuts",
                                   str(d / "cuts.csv"), "--method", "zoa", "--samples", "400", "--mislabel-model",
                                   "average", "-o", str(tmp_path / "p.yaml"), "--json"])
    assert code == 0, err
    rate = json.loads(out)["parameters"]["mislabel_rate"]
    assert not rate["fixed"] and 0.0 <= rate["learned_probability"] <= 1.0
    slab = Likelihood(mislabel=0.15, mislabel_sd=1.2).mislabel_prior()[0]  # the learned share's prior alone
    assert rate["prior"] == pytest.approx(0.5 * 0.05 + 0.5 * slab)
    post = read_posterior(tmp_path / "p.yaml")
    assert post.likelihood.averages_mislabel and post.likelihood.mislabel_sd == 1.2
    assert post.likelihood.noisy_mislabel == 0.15
    # a file written before session 12 (no noisy_mislabel): its slab was centred on the spike
    doc = yaml.safe_load((tmp_path / "p.yaml").read_text())
    del doc["x_posterior"]["likelihood"]["noisy_mislabel"]
    (tmp_path / "old.yaml").write_text(yaml.safe_dump(doc))
    assert read_posterior(tmp_path / "old.yaml").likelihood.noisy_mislabel == 0.05


def test_read_cuts_detects_outcome_from_record(tmp_path):
    """A row with a record and no mark: the detector's outcome and confidence become the label."""
    (tmp_path / "c.csv").write_text("spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome,record\n"
                                    "1e4,1e-3,5e-3,down,stable,\n1e4,2e-3,5e-3,up,,rec1\n1e4,3e-3,5e-3,down,chatter,\n")
    seen = []

    def detect(path, row):
        seen.append(path.name)
        return 1, 0.4

    tool = tool_problem().setup.tool
    t = read_cuts(tmp_path / "c.csv", tool=tool, detect=detect)
    assert seen == ["rec1"] and t.outcome.tolist() == [0, 1, 1] and t.weight.tolist() == [1.0, 0.4, 1.0]
    assert t.detected.tolist() == [False, True, False]
    with pytest.raises(CutsError, match="unknown column"):
        (tmp_path / "d.csv").write_text("spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome,colour\n")
        read_cuts(tmp_path / "d.csv", tool=tool)


def test_outcomes_detected_from_simulated_records_match_the_limit(tmp_path):
    """Item 5 end to end, without a stand-in detector: cuts at half and at 1.6-2x the converged SDM
    limit (slotting and a quarter immersion, up and down), simulated in the time domain from rest
    for 2 s with a weak background force, judged by the chatter detection. Below the limit: stable,
    sure (confidence 1); above: chatter, or diverged past the tool's diameter (also chatter). The
    same verdict from the record written to disk and read back (``detect_outcome``)."""
    from dataclasses import replace

    from oma.record_io import write_record
    from stability.simulate import simulate

    problem = tool_problem()
    d = problem.setup.tool.diameter_m
    rpm = np.array([9000.0, 9000.0, 17000.0, 17000.0, 13000.0, 13000.0])
    ae = np.array([1.0, 1.0, 0.25, 0.25, 0.5, 0.5]) * d
    down = np.array([True, True, False, False, True, True])
    lim = true_limits(problem, rpm, ae, down)
    ap = lim * np.array([0.5, 1.6, 0.5, 2.0, 0.5, 1.8])
    n = rpm.size
    cuts = CutTable(rpm, ap, ae, down, np.full(n, -1), np.ones(n), np.full(n, np.nan), np.zeros(n, bool))
    labelled, diverged = record_labels(problem, cuts, seed=3)
    assert labelled.outcome.tolist() == [0, 1, 0, 1, 0, 1]
    assert np.all(labelled.weight[::2] == 1.0) and np.all(labelled.weight[1::2] >= 0.3)
    assert labelled.detected.all()
    cut = replace(problem.setup.cut, radial_depth_m=float(ae[1]), spindle_rpm=float(rpm[1]), axial_depth_m=float(ap[1]))
    if not diverged[1]:  # the chattering slot's record, written and read back
        sim = simulate(problem.truth, problem.setup.tool, cut, problem.truth_coefficients, duration_s=2.0,
                       sample_rate_hz=10_000.0, seed=7)
        write_record(sim.to_record(problem.setup.tool, cut), tmp_path / "rec")
        assert detect_outcome(tmp_path / "rec", {"spindle_rpm": rpm[1]}) == record_outcome(
            sim.to_record(problem.setup.tool, cut))
    cut = replace(cut, axial_depth_m=float(ap[0]))
    sim = simulate(problem.truth, problem.setup.tool, cut, problem.truth_coefficients, duration_s=2.0,
                   sample_rate_hz=10_000.0, seed=7)
    write_record(sim.to_record(problem.setup.tool, cut), tmp_path / "rec0")
    assert detect_outcome(tmp_path / "rec0", {"spindle_rpm": rpm[0]}) == (0, 1.0)
