"""``robomill learn``'s inputs and outputs at their edges (audit C): tables that are not UTF-8, blank
lines, repeated columns, records that are not their row's cut, depths in the wrong unit, the
setup's limits on suggested cuts, ``cause`` when nothing is free, the sample counts reported, and
suggested rows that read back as a cuts table.

Reading a table needs no learning; the command-line runs hold every parameter fixed (a prior sd of
0: the posterior is the prior, learned in a fraction of a second) unless the test is about what
the cuts teach.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from oma._fields import FileWarning
from planner.cli import main
from planner.learn.outcomes_io import CutsError, read_cuts
from planner.learn.posterior_io import read_posterior
from planner.learn.suggest import suggest_cuts
from stability.setup_io import read_setup
from test_learn_suggest import _lobes  # the lobe-peak limits of the suggest tests

# The bundled KR500 acetal example's setup and tool modes (examples/kr500_acetal), written out so
# that the tests do not depend on the example's files: 25.4 mm tool, depth 0.5-30 mm, 8 kW.
SETUP = """format: robomill-setup/1
tool: {teeth: 2, diameter_m: 0.0254, helix_deg: 30.0}
cut: {feed_per_tooth_m: 0.0005, radial_depth_m: 0.006, milling: down, feed_direction: [0.0, 1.0, 0.0],
      normal_direction: [-1.0, 0.0, 0.0]}
material:
  name: acetal
  cutting_coefficients: {Ktc_N_m2: 1.2e8, Krc_N_m2: 4.5e7, Kac_N_m2: 2.0e7, Kte_N_m: 2000.0, Kre_N_m: 3000.0,
                         Kae_N_m: 500.0}
limits:
  spindle_rpm: [500.0, 24000.0]
  axial_depth_m: [0.0005, 0.03]
  feed_per_tooth_m: [5.0e-05, 0.0006]
  spindle_power_W: 8000.0
  spindle_torque_N_m: 40.0
  max_force_N: 1500.0
  surface_location_error_m: 0.0003
  stability_margin: 0.8
"""
MODEL = """format: robomill-modal/1
modes:
- {natural_frequency_hz: 720.0, damping_ratio: 0.02, stiffness_N_m: 4.0e6, direction: [1.0, 0.0, 0.0]}
- {natural_frequency_hz: 735.0, damping_ratio: 0.02, stiffness_N_m: 4.4e6, direction: [0.0, 1.0, 0.0]}
"""
HEADER = "spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome"
# 12 cuts at 0.4-2x the SDM limit of the modes above (the session-14 audit's table, shipped with
# the example)
CUTS = (Path(__file__).resolve().parents[1] / "examples" / "kr500_acetal" / "cuts.csv").read_text()
FIXED = ["--prior-sd", "frequency=0", "stiffness=0", "damping=0", "coefficients=0"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    (d / "setup.yaml").write_text(SETUP)
    (d / "model.yaml").write_text(MODEL)
    (d / "cuts.csv").write_text(CUTS)
    return d


@pytest.fixture(scope="module")
def setup(files):
    return read_setup(files / "setup.yaml")


def _run(capsys, argv):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def _learn(d, cuts, *extra):
    return ["learn", str(d / "setup.yaml"), "--model", str(d / "model.yaml"), "--cuts", str(cuts), *extra]


# ------------------------------------------------------------------------ 5: not UTF-8 text
def test_a_table_in_another_encoding_is_named_with_the_encoding_expected(files, setup, tmp_path, capsys):
    """cp1252 (an operator "Jürgen" in an x_ column) and UTF-16 (byte-order mark): exit 2, one line
    naming the file and UTF-8; before, a UnicodeDecodeError (exit 3) that named no file."""
    cp1252 = tmp_path / "cp1252.csv"
    cp1252.write_bytes((HEADER + ",x_operator\n6000,0.002,0.006,down,stable,Jürgen\n").encode("cp1252"))
    utf16 = tmp_path / "utf16.csv"
    utf16.write_bytes(CUTS.encode("utf-16"))  # with its byte-order mark
    with pytest.raises(CutsError, match=r"cp1252\.csv: line 2: expected UTF-8 text"):
        read_cuts(cp1252, tool=setup.tool)
    with pytest.raises(CutsError, match=r"utf16\.csv: file: expected UTF-8 text .* found UTF-16 text"):
        read_cuts(utf16, tool=setup.tool)
    for path in (cp1252, utf16):
        code, out, err = _run(capsys, _learn(files, path, "-o", str(tmp_path / "p.yaml")))
        assert code == 2 and str(path) in err and "UTF-8" in err and err.count("\n") == 1, err
        assert out == "" and not (tmp_path / "p.yaml").exists()
    # a UTF-8 file with a BOM (Excel's "CSV UTF-8") is still read
    bom = tmp_path / "bom.csv"
    bom.write_bytes(CUTS.encode("utf-8-sig"))
    assert read_cuts(bom, tool=setup.tool).n_cuts == 12


# ------------------------------------------------------------------------ 6: physical lines
@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_errors_name_the_physical_line_when_the_table_has_blank_lines(setup, tmp_path, newline):
    body = [HEADER, "6000,0.002,0.006,down,stable", "", " , ", "7000,0.029,0.006,down,chatter",
            "8000,0.003,0.006,down,wobbly"]
    path = tmp_path / "blank.csv"
    path.write_bytes(newline.join(body).encode())
    with pytest.raises(CutsError, match="line 6: outcome: expected stable, chatter or uncertain"):
        read_cuts(path, tool=setup.tool)
    # a quoted field over two lines: the next row is still numbered by the file's lines
    path.write_text(HEADER + ',x_note\n6000,0.002,0.006,down,stable,"two\nlines"\n\n7000,-1,0.006,down,stable,\n')
    with pytest.raises(CutsError, match="line 5: axial_depth_m"):
        read_cuts(path, tool=setup.tool, outcomes_required=False)


# ------------------------------------------------------------------------ 7: what passed silently
def test_a_repeated_column_is_rejected(setup, tmp_path):
    path = tmp_path / "dup.csv"
    path.write_text(HEADER + ",outcome\n6000,0.002,0.006,down,stable,chatter\n7000,0.029,0.006,down,chatter,stable\n"
                    "8000,0.003,0.006,down,stable,chatter\n")
    with pytest.raises(CutsError, match="header: expected each column once, found 'outcome' 2 times"):
        read_cuts(path, tool=setup.tool)
    path.write_text(HEADER.replace(",outcome", "") + ",spindle_rpm\n6000,0.002,0.006,down,7000\n")
    with pytest.raises(CutsError, match="'spindle_rpm' 2 times"):
        read_cuts(path, tool=setup.tool, outcomes_required=False)


def _record(directory, *, rpm=9000.0, ap=0.002, ae=0.006, milling="down"):
    """A record of a clean tooth-passing vibration (stable, sure) of the cut given."""
    directory.mkdir()
    (directory / "record.yaml").write_text(f"""format: robomill-record/1
sample_rate_hz: 1000.0
signals:
  file: signals.csv
  columns:
    Fx: {{quantity: force, axis: X, unit: N}}
tool: {{teeth: 2, diameter_m: 0.0254, helix_deg: 30.0}}
cut: {{spindle_rpm: {rpm}, feed_per_tooth_m: 0.0005, radial_depth_m: {ae}, axial_depth_m: {ap}, milling: {milling},
      feed_direction: [0, 1, 0], normal_direction: [-1, 0, 0]}}
""")
    t = np.arange(2000) / 1000.0
    x = np.sin(2 * np.pi * 2 * rpm / 60.0 * t) + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    (directory / "signals.csv").write_text("Fx\n" + "\n".join(f"{v:.6g}" for v in x) + "\n")
    return directory


def test_a_record_whose_cut_is_not_the_row_is_rejected(setup, tmp_path):
    """The row says 15000 rpm, 20 mm, ae 12 mm, up; its record is a 9000 rpm / 2 mm / 6 mm down cut:
    before, the record's outcome was silently given to the row. Within 2 % (typed digits) it is
    the same cut."""
    _record(tmp_path / "rec")
    rows = ["6000,0.002,0.006,down,stable,", "{},,rec", "8000,0.003,0.006,down,stable,"]
    path = tmp_path / "c.csv"
    for row, match in [("15000,0.02,0.012,up", r"line 3: spindle_rpm: expected the cut of its record .*rec "
                                               r"\(spindle_rpm 9000, within 2%\), found 15000"),
                       ("9000,0.0025,0.006,down", r"line 3: axial_depth_m: .*\(axial_depth_m 0\.002, .*found 0\.0025"),
                       ("9000,0.002,0.006,up",
                        r"line 3: milling: expected the cut of its record .*\(down\), found 'up'")]:
        path.write_text("\n".join([HEADER + ",record", rows[0], rows[1].format(row), rows[2]]) + "\n")
        with pytest.raises(CutsError, match=match):
            read_cuts(path, tool=setup.tool)
    path.write_text("\n".join([HEADER + ",record", rows[0], rows[1].format("9050,0.00201,0.006,down"), rows[2]]))
    table = read_cuts(path, tool=setup.tool)
    assert table.detected.tolist() == [False, True, False] and table.outcome[1] == 0 and table.weight[1] == 1.0


def test_a_depth_in_mm_is_rejected_and_one_beyond_the_setup_warned(files, setup, tmp_path, capsys):
    """Deeper than 10 tool diameters (254 mm here) is a depth in mm in a column of m: exit 2, for
    --cuts and --predict alike. Deeper than the setup's 30 mm but plausible: kept (a test cut may
    go deeper than production), with a warning naming the line, in the JSON's warnings."""
    lines = CUTS.splitlines()
    mm = tmp_path / "mm.csv"
    mm.write_text("\n".join(lines[:4] + ["9000,10.35,0.006,down,chatter"] + lines[5:]) + "\n")
    with pytest.raises(CutsError, match=r"line 5: axial_depth_m: expected at most 10 tool diameters, 0\.254 m "
                                        r"\(a depth in mm in a column of m\?\), found 10\.35"):
        read_cuts(mm, tool=setup.tool)
    code, out, err = _run(capsys, _learn(files, mm, "-o", str(tmp_path / "p.yaml")))
    assert code == 2 and "10 tool diameters" in err and err.count("\n") == 1 and not (tmp_path / "p.yaml").exists()
    predict = tmp_path / "predict.csv"
    predict.write_text("spindle_rpm,axial_depth_m,radial_depth_m,milling\n8000,0.05,0.006,down\n8000,3,0.006,down\n")
    code, out, err = _run(capsys, _learn(files, files / "cuts.csv", "--predict", str(predict)))
    assert code == 2 and "predict.csv: line 3: axial_depth_m" in err and err.count("\n") == 1
    # a 50 mm cut (2 diameters) is a cut
    deep = tmp_path / "deep.csv"
    deep.write_text("\n".join(lines[:4] + ["9000,0.05,0.006,down,chatter"] + lines[5:]) + "\n")
    with pytest.warns(FileWarning, match=r"1 cut\(s\) deeper than the setup's largest axial depth 0\.03 m \(line 5\)"):
        table = read_cuts(deep, tool=setup.tool, max_depth_m=0.03)
    assert table.axial_depth_m[3] == 0.05
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_cuts(deep, tool=setup.tool)  # no limit given: nothing to say
    code, out, err = _run(capsys, _learn(files, deep, *FIXED, "--method", "zoa", "--samples", "100", "--json"))
    assert code == 0, err
    assert any("deeper than the setup's largest axial depth" in w for w in json.loads(out)["warnings"])


def test_an_outcome_word_in_a_table_to_predict_is_checked(setup, tmp_path):
    """--predict: the outcome is optional and may be empty, but 'wobbly' is not mapped to 'none'."""
    path = tmp_path / "p.csv"
    path.write_text(HEADER + "\n6000,0.002,0.006,down,wobbly\n")
    with pytest.raises(CutsError, match="line 2: outcome: expected stable, chatter, uncertain or empty, "
                                        "found 'wobbly'"):
        read_cuts(path, tool=setup.tool, outcomes_required=False)
    path.write_text(HEADER + "\n6000,0.002,0.006,down,\n7000,0.002,0.006,down,Chatter\n")
    assert read_cuts(path, tool=setup.tool, outcomes_required=False).outcome.tolist() == [-1, 1]


# ------------------------------------------------------------------------ 4: the setup's limits
@pytest.mark.parametrize("criterion", ["mrr", "boundary"])
def test_suggested_cuts_and_the_incumbent_stay_inside_the_allowed_depths(criterion):
    """Allowed: 10-18 krpm only, at most 4 mm below 14 krpm and 3.5 mm above (the peak's limit
    is ~6 mm): every suggestion and the best proven MRR lie inside; without limits the first
    suggestion sits on the peak, deeper than allowed."""
    lobes = _lobes(np.random.default_rng(0))
    free, _, best_free = suggest_cuts(lobes, 3, criterion=criterion)
    assert free.axial_depth_m.max() > 4e-3  # what the limits must prevent
    least = np.full(lobes.rpm.size, 1e-3)
    most = np.where(lobes.rpm < 14000, 4e-3, 3.5e-3)
    most[(lobes.rpm < 10000) | (lobes.rpm > 18000)] = -1.0  # speeds not allowed
    cuts, score, best = suggest_cuts(lobes, 3, criterion=criterion, allowed_depth_m=(least, most))
    assert cuts.n_cuts == 3 and score.size == 3
    j = np.searchsorted(lobes.rpm, cuts.spindle_rpm)
    assert np.all((cuts.spindle_rpm >= 10000) & (cuts.spindle_rpm <= 18000))
    assert np.all(cuts.axial_depth_m <= most[j] * (1 + 1e-12)) and np.all(cuts.axial_depth_m >= 1e-3)
    allowed = most > 0
    assert best <= np.max(most[allowed] * lobes.rpm[allowed]) * (1 + 1e-12) and best <= best_free
    # nothing allowed: no cuts, no incumbent
    none, s, b = suggest_cuts(lobes, 2, criterion=criterion, allowed_depth_m=(1e-3, 5e-4))
    assert none.n_cuts == 0 and s.size == 0 and b == 0.0


def test_allowed_depths_meet_the_setup_limits_as_predict_computes_them(setup, files):
    """At the largest allowed depth the binding limit holds with equality, by ``predict_point``'s
    own mean power, mean torque and peak force (another code path): the 30 mm depth bound below
    ~20.7 krpm here, the 8 kW above; outside 500-24000 rpm nothing is allowed."""
    from oma.modal_io import read_modal_model
    from planner.learn.suggest import allowed_depths
    from stability.lobes import predict_point

    model = read_modal_model(files / "model.yaml")
    rpm = np.array([300.0, 2000.0, 12000.0, 21631.0, 30000.0])
    least, most, names = allowed_depths(setup, rpm, model)
    assert names == ("spindle_rpm", "axial_depth_m", "spindle_power_W", "spindle_torque_N_m", "max_force_N")
    assert most[0] < least[0] and most[-1] < least[-1]  # speeds outside the setup's range
    assert np.all(least[1:4] == 5e-4) and np.all(most[1:3] == 0.03)
    point = [predict_point(model, setup.tool, setup.cut, setup.material.cutting_coefficients, spindle_rpm=n,
                           axial_depth_m=a, method="zoa") for n, a in zip(rpm[2:4], most[2:4])]
    assert point[0].power_W < 8000.0  # the depth bound binds at 12 krpm
    assert point[1].power_W == pytest.approx(8000.0, rel=1e-6)  # power at 21631 rpm: exact (linear in depth)
    assert all(p.mean_torque_N_m < 40.0 and p.peak_force_N < 1500.0 for p in point)
    assert most[3] < 0.03  # the audit's 88.6 mm suggestion at 21631 rpm took 24.6 kW


@pytest.mark.parametrize("limit,value,reported", [("spindle_torque_N_m", 2.0, "mean_torque_N_m"),
                                                   ("max_force_N", 400.0, "peak_force_N")])
def test_allowed_depths_for_torque_and_force_alone(setup, files, limit, value, reported):
    """Each of the other two limits alone: at the largest allowed depth ``predict_point`` reports the
    limit's value (torque: exact; peak force: to its angle grid's resolution)."""
    from dataclasses import replace

    from oma.modal_io import read_modal_model
    from planner.learn.suggest import allowed_depths
    from stability.lobes import predict_point
    from stability.setup import Limits

    model = read_modal_model(files / "model.yaml")
    one = replace(setup, limits=Limits(**{limit: value}))
    least, most, names = allowed_depths(one, np.array([6000.0, 18000.0]), model)
    assert names == (limit,) and np.all(least == 0) and most[0] == most[1] < 0.03
    pt = predict_point(model, one.tool, one.cut, one.material.cutting_coefficients, spindle_rpm=6000.0,
                       axial_depth_m=float(most[0]), method="zoa")
    assert getattr(pt, reported) == pytest.approx(value, rel=1e-3)


@pytest.fixture(scope="module")
def fixed_run(files, tmp_path_factory):
    """One ``learn --suggest 3 -o --json`` of the audit's table with every parameter held fixed
    and 600 samples (more than the file keeps): exit code, JSON, stderr, the posterior's path."""
    out_path = tmp_path_factory.mktemp("fixed") / "post.yaml"
    stdout, stderr = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        warnings.simplefilter("error")  # a warning becomes an internal error (exit 3)
        code = main(_learn(files, files / "cuts.csv", *FIXED, "--method", "zoa", "--samples", "600", "--suggest",
                           "3", "-o", str(out_path), "--json"))
    return code, (json.loads(stdout.getvalue()) if code == 0 else None), stderr.getvalue(), out_path


def test_suggestions_from_the_command_respect_the_setup(fixed_run, files, setup):
    """The audit's case: 21631 rpm / 94 mm and alike (24.6 kW) were suggested under an 8 kW, 30 mm
    setup, and the best proven MRR implied 34.5 mm. Now every suggestion is within the speed and
    depth ranges, and its power and peak force (``predict_point``) within the setup's."""
    from oma.modal_io import read_modal_model
    from planner.cut_model import CutModel
    from stability.lobes import predict_point

    code, res, err, _ = fixed_run
    assert code == 0, err
    assert res["suggested_within"] == ["spindle_rpm", "axial_depth_m", "spindle_power_W", "spindle_torque_N_m",
                                       "max_force_N"]
    rows = res["suggested"]
    assert len(rows) == 3
    model, coef = read_modal_model(files / "model.yaml"), setup.material.cutting_coefficients
    for r in rows:
        assert 500 <= r["spindle_rpm"] <= 24000 and 5e-4 <= r["axial_depth_m"] <= 0.03
        pt = predict_point(model, setup.tool, setup.cut, coef, spindle_rpm=r["spindle_rpm"],
                           axial_depth_m=r["axial_depth_m"], method="zoa")
        assert pt.power_W <= 8000.0 * (1 + 1e-6) and pt.mean_torque_N_m <= 40.0 and pt.peak_force_N <= 1500.0
    # the best proven MRR is at most what 8 kW removes at this engagement (power per MRR is the
    # same at every speed: the specific cutting energy, J/m^3)
    fz = setup.cut.feed_per_tooth_m
    per_depth = float(CutModel(model, setup.tool, setup.cut, coef).mean_torque(1.0, fz))
    energy = 2 * np.pi * per_depth / (setup.cut.radial_depth_m * fz * setup.tool.teeth)
    assert 0 < res["best_stable_mrr_m3_s"] <= 8000.0 / energy * (1 + 1e-9)


# ------------------------------------------------------------------------ 8: nothing free
def test_cause_is_none_when_every_parameter_is_fixed_and_no_warning(fixed_run):
    """Before: cause 'frequency' (the argmax over all -1) and a divide-by-zero RuntimeWarning from
    the sampler's step size with no free coordinate."""
    code, res, err, _ = fixed_run
    assert code == 0 and err == "", err
    assert res["cause"] == "none" and all(p["fixed"] for k, p in res["parameters"].items() if k != "mislabel_rate")


def test_sampler_with_no_free_coordinate_is_silent_and_cause_none(files, setup):
    from oma.modal_io import read_modal_model
    from planner.learn.posterior import Posterior, smc

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = smc(lambda x: np.zeros(x.shape[0]), np.zeros(0), rng=np.random.default_rng(0), n_particles=100)
    assert res.samples.shape == (100, 0) and res.betas[-1] == 1.0
    post = Posterior(reference=read_modal_model(files / "model.yaml"), coefficients=setup.material.cutting_coefficients,
                     prior_log_sd=np.zeros(5), samples=np.zeros((100, 5)))
    assert post.cause() == "none"
    moved = Posterior(reference=post.reference, coefficients=post.coefficients,
                      prior_log_sd=np.array([0.0, 0.2, 0.0, 0.0, 0.0]), samples=np.full((100, 5), 0.1))
    assert moved.cause() == "stiffness"  # the only free one, though frequency's mean moved as far


# ------------------------------------------------------------------------ 9: outputs that agree
def test_sample_counts_are_reported_as_used_and_as_written(fixed_run):
    """600 samples learned (what --predict uses), 500 written (thinned, the MAP first): both
    reported, the written count as the file holds; before, 'posterior_samples' said 600 only."""
    code, res, _, path = fixed_run
    assert code == 0
    assert res["posterior_samples"] == 600
    assert res["posterior_samples_written"] == 500 == read_posterior(path).samples.shape[0]


def test_a_suggested_row_is_a_row_of_a_cuts_table(fixed_run, setup, tmp_path):
    """The JSON's rows, saved as CSV with their outcome filled in, read back as cuts (the scores
    under the x_ prefix of extensions; before, 'expected_improvement_mrr_m3_s' was an unknown column)."""
    code, res, _, _ = fixed_run
    assert code == 0
    rows = res["suggested"]
    assert all("x_expected_improvement_mrr_m3_s" in r for r in rows)
    path = tmp_path / "next.csv"
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows([dict(r, outcome=word) for r, word in zip(rows, ("stable", "chatter", "uncertain"))])
    table = read_cuts(path, tool=setup.tool)
    np.testing.assert_allclose(table.spindle_rpm, [r["spindle_rpm"] for r in rows])
    np.testing.assert_allclose(table.axial_depth_m, [r["axial_depth_m"] for r in rows])
    assert table.outcome.tolist() == [0, 1, 2] and np.all(table.feed_per_tooth_m == setup.cut.feed_per_tooth_m)
