"""Hidden effects: records simulated with one effect the model lacks; robomill must name it.

For every cause of cli.md, records of the paper-like robot cell (planner.diagnosis.cases) are
simulated with the effect drawn from its realistic range, three seeds each, and diagnosed with the
model that lacks it. Robomill must (1) name the cause, (2) recover its main parameter within 20 %
(the issue's requirement), (3) predict the validation half at least 30 % better than the model
without it. Clean records (five seeds) must give ``none``: no false alarm.

The confusion matrix over more seeds is in benchmarks/bench_diagnosis.py.
"""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from planner.diagnosis import CAUSE_NAMES, diagnose
from planner.diagnosis.cases import CAUSES, MAIN_PARAMETER, hidden_effect_case, paper_like_cell

#: Relative accuracy of the main parameter the issue asks for.
PARAMETER_TOLERANCE = 0.20
#: Smallest validation gain of a named cause the issue asks for.
MIN_GAIN = 0.30

EFFECTS = [c for c in CAUSES if c != "none"]


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("cause", EFFECTS)
def test_hidden_effect_is_named_and_measured(cause, seed):
    case = hidden_effect_case(cause, seed)
    d = diagnose(case.records, case.model, plot_data=False)
    ranking = [(r.cause, round(r.gain, 3), round(r.significance, 1)) for r in d.ranking[:3]]
    assert d.cause == cause, f"named {d.cause}; ranking {ranking}"
    key = MAIN_PARAMETER[cause]
    truth = case.truth[key]
    found = d.parameters[key]
    assert abs(found - truth) <= PARAMETER_TOLERANCE * abs(truth), f"{key}: found {found}, truth {truth}"
    assert d.gain >= MIN_GAIN
    # the gain is the relative reduction of the named part's validation error
    assert d.gain == pytest.approx((d.error_before - d.error_after) / d.error_before)
    assert d.significance >= d.min_significance


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_clean_records_give_none(seed):
    case = hidden_effect_case("none", seed)
    d = diagnose(case.records, case.model, plot_data=False)
    ranking = [(r.cause, round(r.gain, 3), round(r.significance, 1)) for r in d.ranking[:3]]
    assert d.cause == "none", f"false alarm; ranking {ranking}"
    assert d.gain == 0.0 and d.error_after == d.error_before
    # and the comparison agrees with the model: no part is off by more than a few percent
    assert d.comparison.errors["force"] < 0.01
    assert d.comparison.errors["structure"] < 0.01


def test_clean_low_speed_record_gives_none():
    """At 900 rpm the averaged closed loop misses the notches by tens of percent and a 16 s record
    holds many noise lines: neither may be mistaken for a cause. (Seed 2 once had the unmodeled
    mode take 100 % of a structure error of 8e-5 with z = 3.2; the part must first disagree with
    the measurement beyond its noise.)"""
    cell = paper_like_cell()
    cell = replace(cell, cut=replace(cell.cut, spindle_rpm=900.0))
    case = hidden_effect_case("none", 2, cell=cell, duration_s=16.0)
    d = diagnose(case.records, case.model, plot_data=False)
    assert d.cause == "none", [(r.cause, r.gain, r.significance, r.disagreement) for r in d.ranking[:3]]


def test_to_dict_has_the_cli_keys_and_is_json():
    case = hidden_effect_case("channel_delay", 7)
    d = diagnose(case.records, case.model, plot_data=False)
    out = d.to_dict()
    for key in ("cause", "parameters", "error_before", "error_after", "gain", "ranking"):
        assert key in out
    assert out["cause"] in CAUSE_NAMES
    assert {r["cause"] for r in out["ranking"]} == set(CAUSE_NAMES) - {"none"}
    assert all(set(r) >= {"cause", "gain"} for r in out["ranking"])
    assert set(out["errors"]) == {"force", "structure", "stability"}
    assert "delay_s" in out["parameters"]
    # the named cause first, with its practical size above its floor; the re-fitted coefficients
    # (the baseline) reported beside it
    assert out["ranking"][0]["cause"] == out["cause"]
    top = out["ranking"][0]["practical"]
    assert top["passes"] and top["size"] >= top["floor"]
    assert set(out["baseline_coefficients"]["fitted"]) == {"Ktc_N_m2", "Krc_N_m2", "Kac_N_m2", "Kte_N_m", "Kre_N_m",
                                                           "Kae_N_m"}
    assert out["thresholds"]["practical_floors"]["nonlinear_cutting"] == 0.05
    json.dumps(out)
    rec = out["records"][0]
    assert rec["chatter"]["chatter"] is False and rec["predicted_stable"] is True


def test_restricting_the_candidates():
    """With the true cause withheld, no other candidate takes the blame: runout lives in the force
    harmonics, which the structure candidates cannot change."""
    case = hidden_effect_case("runout", 1)
    d = diagnose(case.records, case.model, causes=["channel_delay", "unmodeled_mode"], plot_data=False)
    assert d.cause == "none"
    assert [r.cause for r in d.ranking] != []
    with pytest.raises(ValueError, match="cause must be one of"):
        diagnose(case.records, case.model, causes=["gremlins"])


def test_nonlinear_cutting_from_records_at_two_feeds():
    """With records at 0.3 and 0.5 mm per tooth, the size effect's exponent is recovered (within
    20 %), and the coefficients fitted with it, which hold at the first record's chip (0.3 mm),
    are the simulator's at 0.5 mm scaled by the size effect ``(0.3 / 0.5)^-p``."""
    from stability.simulate import Effects, NonlinearCutting, simulate

    cell = paper_like_cell()
    records = []
    for i, fz in enumerate((0.0003, 0.0005)):
        cut = replace(cell.cut, feed_per_tooth_m=fz)
        sim = simulate(cell.model, cell.tool, cut, cell.material, duration_s=8.0,
                       effects=Effects(nonlinear_cutting=NonlinearCutting(0.3, 0.0005)), background=cell.background,
                       sensors=cell.sensors, seed=10 + i)
        rec = sim.to_record(cell.tool, cut, material=cell.material, name=f"fz {fz}")
        records.append(replace(rec, data=rec.data[:, 2000:], time_s=None))
    d = diagnose(records, cell.model, plot_data=False)
    assert d.cause == "nonlinear_cutting"
    assert d.parameters["exponent_p"] == pytest.approx(0.3, rel=PARAMETER_TOLERANCE)
    p = d.parameters["exponent_p"]
    assert d.parameters["reference_chip_m"] == 0.0003
    ktc = d.parameters["coefficients"]["Ktc_N_m2"] * (0.0003 / 0.0005) ** p
    assert ktc == pytest.approx(cell.material.cutting_coefficients.Ktc_N_m2, rel=0.05)
    assert d.gain >= MIN_GAIN
