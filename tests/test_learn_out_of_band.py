"""Detected outcomes whose record cannot show the chatter: a cut chattering at a 740 Hz tool mode,
recorded at 1 kHz (the detection searches up to 450 Hz, the anti-alias filter removed the line),
reads "stable". Given the prior model, ``read_cuts`` tells the detection where the chatter would
be (the ZOA's frequency at the cut, as ``diagnose`` does), so such a "stable" weighs 0.1 and the
rows are named; the same cuts recorded at 10 kHz (chatter in band) read as before.

Ground truth: a one-mode tool (720 Hz, 3 %, 5e6 N/m; the prior is the truth), four cuts at
8000 rpm at 1.5 and 2 times the converged SDM limit (slotting down, half immersion up), simulated
in the time domain for 2 s; ten marks labelled from the converged SDM limits.
"""

from __future__ import annotations

import functools
import json
import warnings
from dataclasses import replace

import numpy as np
import pytest

from oma._fields import FileWarning
from oma.modal_io import write_modal_model
from oma.record_io import write_record
from planner.cli import main
from planner.diagnosis.chatter import OUT_OF_BAND_CONFIDENCE
from planner.learn.likelihood import CHATTER, STABLE
from planner.learn.outcomes_io import expected_chatter_frequency, read_cuts
from planner.learn.posterior import PARAMETERS, PriorSD
from planner.learn.synthetic import label, random_cuts, tool_problem, true_limits
from planner.learn.tables import Grid, build_table
from planner.learn.update import learn
from stability.setup_io import write_setup

FN_HZ = 720.0
#: The detected cuts: speed, immersion (ae/D), milling, depth over the converged SDM limit. All
#: chatter; at 1 kHz each reads "stable" (confidence 0.25-0.87 without the model), at 10 kHz "chatter".
DETECTED = ((8000.0, 1.0, "down", 1.5), (8000.0, 1.0, "down", 2.0), (8000.0, 0.5, "up", 1.5), (8000.0, 0.5, "up", 2.0))
N_MARKS = 10
#: The detected rows' physical lines in the tables (header on line 1, the marks on 2-11).
LINES = "12, 13, 14, 15"


def _table_text(marks, detected_rows) -> str:
    words = {STABLE: "stable", CHATTER: "chatter"}
    lines = ["spindle_rpm,axial_depth_m,radial_depth_m,milling,outcome,record"]
    for i in range(marks.n_cuts):
        rpm, ap, ae = (float(x[i]) for x in (marks.spindle_rpm, marks.axial_depth_m, marks.radial_depth_m))
        lines.append(f"{rpm!r},{ap!r},{ae!r},{'down' if marks.down[i] else 'up'},{words[int(marks.outcome[i])]},")
    lines += [f"{rpm!r},{ap!r},{ae!r},{milling},,{rec}" for rpm, ap, ae, milling, rec in detected_rows]
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Setup, prior, and two cut tables (the same ten marks; the detected cuts' records at 1 kHz
    in ``low.csv``, at 10 kHz in ``high.csv``)."""
    from stability.simulate import simulate

    d = tmp_path_factory.mktemp("out_of_band")
    problem = tool_problem(fn_hz=FN_HZ, stiffness_N_m=5e6)
    setup, tool = problem.setup, problem.setup.tool
    write_setup(setup, d / "setup.yaml")
    write_modal_model(problem.prior, d / "prior.yaml")
    rng = np.random.default_rng(1)
    marks = random_cuts(problem, N_MARKS, rng, immersions=(0.5, 1.0), depth_range=(1e-3, 20e-3))
    marks = label(marks, true_limits(problem, marks.spindle_rpm, marks.radial_depth_m, marks.down), rng, flip=0.0)
    rows = {1000.0: [], 10_000.0: []}
    for k, (rpm, immersion, milling, factor) in enumerate(DETECTED):
        ae = immersion * tool.diameter_m
        limit = float(true_limits(problem, [rpm], [ae], [milling == "down"])[0])
        cut = replace(setup.cut, radial_depth_m=ae, milling=milling, spindle_rpm=rpm, axial_depth_m=factor * limit)
        for fs, row in rows.items():
            sim = simulate(problem.truth, tool, cut, problem.truth_coefficients, duration_s=2.0, sample_rate_hz=fs)
            name = f"rec{k}_{fs:.0f}"
            write_record(sim.to_record(tool, cut), d / name)
            row.append((rpm, float(factor * limit), float(ae), milling, name))
    (d / "low.csv").write_text(_table_text(marks, rows[1000.0]))
    (d / "high.csv").write_text(_table_text(marks, rows[10_000.0]))
    return d, problem


def _read(path, problem, *, with_model: bool):
    """The table and the FileWarnings of reading it, with or without the prior model's chatter
    frequency (without: as before the fix)."""
    fc = functools.partial(expected_chatter_frequency, problem.prior, problem.setup) if with_model else None
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", FileWarning)
        table = read_cuts(path, tool=problem.setup.tool, chatter_frequency=fc)
    return table, [str(w.message) for w in seen if issubclass(w.category, FileWarning)]


def test_the_expected_chatter_frequency_lies_above_the_mode(files):
    """The prior's ZOA chatter frequency at the detected cuts: a one-mode tool chatters just above
    its natural frequency, where the real part of its receptance is negative (within 15 %), and
    above the 1 kHz records' band (0.45 fs) but inside the 10 kHz ones'."""
    _, problem = files
    for rpm, immersion, milling, _ in DETECTED:
        fc = expected_chatter_frequency(problem.prior, problem.setup, spindle_rpm=rpm, axial_depth_m=5e-3,
                                        radial_depth_m=immersion * problem.setup.tool.diameter_m, milling=milling)
        assert FN_HZ < fc < 1.15 * FN_HZ and 450.0 < fc < 4500.0


def test_a_stable_read_that_cannot_see_the_chatter_weighs_little(files):
    """1 kHz records of chattering cuts read 'stable'. Without the model (the old reading) with
    the detection's confidence, up to 0.87; with it, weight 0.1 (``OUT_OF_BAND_CONFIDENCE``), and a
    warning names the rows. The marks are untouched."""
    d, problem = files
    old, old_warnings = _read(d / "low.csv", problem, with_model=False)
    new, new_warnings = _read(d / "low.csv", problem, with_model=True)
    det = slice(N_MARKS, None)
    assert new.detected[det].all() and not new.detected[:N_MARKS].any()
    assert np.all(old.outcome[det] == STABLE) and np.all(new.outcome[det] == STABLE)
    assert old.weight[det].max() > 0.5  # the old reading: a fairly sure "stable" where the cut chatters
    np.testing.assert_array_equal(new.weight[det], OUT_OF_BAND_CONFIDENCE)
    np.testing.assert_array_equal(new.weight[:N_MARKS], old.weight[:N_MARKS])
    np.testing.assert_array_equal(new.outcome, old.outcome)
    assert not old_warnings
    assert len(new_warnings) == 1 and f"line {LINES}:" in new_warnings[0] and "1000 Hz" in new_warnings[0]


def test_a_record_that_shows_the_chatter_reads_as_before(files):
    """Control: the same cuts recorded at 10 kHz (the expected chatter in band): read 'chatter'
    with the same confidence whether the model is given or not, and no warning."""
    d, problem = files
    old, _ = _read(d / "high.csv", problem, with_model=False)
    new, new_warnings = _read(d / "high.csv", problem, with_model=True)
    assert np.all(new.outcome[N_MARKS:] == CHATTER)
    np.testing.assert_array_equal(new.weight, old.weight)
    np.testing.assert_array_equal(new.outcome, old.outcome)
    assert not new_warnings


def test_the_posterior_is_not_pulled_to_stable_by_reads_that_cannot_see(files):
    """Learning from the ten marks and the 1 kHz reads: with the old weights the posterior calls
    the slot at 1.5x the limit stable (P > 0.5, the reads pulled it there); with the fix it stays
    on the chatter side, and the pull of the four reads on P(stable) at their cuts, against the
    marks alone, is less than half the old one's (weight 0.1 is weak evidence, not none)."""
    d, problem = files
    old, _ = _read(d / "low.csv", problem, with_model=False)
    new, _ = _read(d / "low.csv", problem, with_model=True)
    marks_only = replace(new, outcome=np.r_[new.outcome[:N_MARKS], np.full(len(DETECTED), -1)])
    setup = problem.setup
    free = ("frequency", "stiffness")
    sd = np.where([p in free for p in PARAMETERS], PriorSD().log_sds(), 0.0)
    grid = Grid.around(sd[0], 0.0, 0.0, span=4.5)
    table = build_table(problem.prior, setup.tool, setup.cut, setup.material.cutting_coefficients, new.spindle_rpm,
                        new.radial_depth_m, new.down, grid)
    p = {}
    for name, cuts in (("old", old), ("new", new), ("marks", marks_only)):
        res = learn(setup, problem.prior, cuts, free=free, table=table, n_particles=1000, seed=0, validate=0)
        p[name] = res.posterior.probability_stable(table, new.axial_depth_m)[N_MARKS:]
    assert p["old"][0] > 0.5 > p["new"][0], p
    pull_old, pull_new = np.mean(p["old"] - p["marks"]), np.mean(p["new"] - p["marks"])
    assert pull_old > 0.15 and pull_new < 0.5 * pull_old, p


@pytest.mark.parametrize("json_out", [True, False])
def test_learn_names_the_rows_that_could_not_see_the_chatter(files, capsys, json_out):
    """``robomill learn`` passes the prior's chatter frequency: its report warns, naming the rows
    (JSON ``warnings``; a ``warning:`` line of the human text). Every group held fixed: nothing to
    learn, only the reading of the table is under test."""
    d, _ = files
    argv = ["learn", str(d / "setup.yaml"), "--model", str(d / "prior.yaml"), "--cuts", str(d / "low.csv"),
            "--method", "zoa", "--samples", "100", "--prior-sd", "frequency=0", "stiffness=0", "damping=0",
            "coefficients=0"] + (["--json"] if json_out else [])
    assert main(argv) == 0
    captured = capsys.readouterr()
    if json_out:
        said = [w for w in json.loads(captured.out)["warnings"] if f"line {LINES}:" in w]
    else:
        said = [line for line in (captured.out + captured.err).splitlines()
                if line.startswith("warning:") and f"line {LINES}:" in line]
    assert len(said) == 1 and f"weight {OUT_OF_BAND_CONFIDENCE:g}" in said[0]
