"""Diagnosis on records in forms robomill's fits were not written for, with nuisance on every record.

The nuisance (planner.diagnosis.cases, ``nuisance=True``): cutting coefficients off by up to 20 %
each, another background level and band, a helix up to 5 deg off; the record states the nominal
values. The forms: runout as unequal tooth radii, a delay on the force channel, a pose drift in a
step, a size effect of a saturating law. Seeds here are below 100; the benchmark
(benchmarks/bench_diagnosis.py) uses 100 and up.
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from planner.diagnosis import diagnose
from planner.diagnosis.cases import (COEFFICIENT_FLOOR, MAIN_PARAMETER, coefficient_changes, expected_cause,
                                     hidden_effect_case, paper_like_cell)
from planner.diagnosis.floors import FLOORS, practical_size
from planner.diagnosis.forcemodel import ToothRadiiRunout
from stability.simulate import Effects, NonlinearCutting, Runout, simulate

#: Relative accuracy of the main parameter the issue asks for.
PARAMETER_TOLERANCE = 0.20


@pytest.mark.parametrize("cause, form", [("runout", "tooth_radii"), ("channel_delay", "force"),
                                         ("pose_drift", "step"), ("nonlinear_cutting", "saturating")])
def test_effect_in_another_form_with_nuisance_is_named_and_measured(cause, form):
    case = hidden_effect_case(cause, 0, form=form, nuisance=True)
    d = diagnose(case.records, case.model, plot_data=False)
    ranking = [(r.cause, round(r.gain, 3), round(r.significance, 1)) for r in d.ranking[:3]]
    assert d.cause == cause, f"named {d.cause}; ranking {ranking}"
    key = MAIN_PARAMETER[cause]
    truth, found = case.truth[key], d.parameters[key]
    # the sign too: a delay on the force channel is a negative delay of the displacement
    assert abs(found - truth) <= PARAMETER_TOLERANCE * abs(truth), f"{key}: found {found}, truth {truth}"
    named = d.ranking[0]
    assert named.practical["passes"] and named.practical["size"] >= FLOORS[cause][0]


@pytest.mark.parametrize("seed", [0, 1])
def test_clean_records_with_nuisance_raise_no_false_alarm(seed):
    """Nothing but the nuisance: no effect may be named; the coefficients are named exactly when
    they are off by more than the floor (10 %, away from the fence), and the fitted change of Ktc
    is the true one within 0.05 (the helix up to 5 deg off and the edge coefficients off
    independently bias it by up to 0.04 on seeds 0, 1 and 200, measured)."""
    case = hidden_effect_case("none", seed, nuisance=True)
    d = diagnose(case.records, case.model, plot_data=False)
    assert d.cause in ("none", "cutting_coefficients"), [(r.cause, r.gain, r.practical) for r in d.ranking[:3]]
    truth = case.nuisance["coefficients"]
    size = max(abs(truth["Ktc_relative_change"]), abs(truth["ratio_relative_change"]))
    if abs(size - COEFFICIENT_FLOOR) > 0.2 * COEFFICIENT_FLOOR:  # not on the fence
        assert d.cause == expected_cause(case)
    fit = d.coefficient_fit.parameters
    assert fit["Ktc_relative_change"] == pytest.approx(truth["Ktc_relative_change"], abs=0.05)


def test_refitted_coefficients_are_the_baseline_runout_must_beat():
    """The issue's second miss: runout whose gain against the nominal coefficients stayed small
    because most of the force error was the coefficients'. Against the re-fitted ones it explains
    nearly all that is left, and the coefficients alone do not take the blame."""
    cell = paper_like_cell()
    true_coef = replace(cell.material.cutting_coefficients, Ktc_N_m2=1.2e8 * 1.18, Krc_N_m2=4.5e7 * 0.9)
    sim = simulate(cell.model, cell.tool, cell.cut, true_coef, duration_s=10.0,
                   effects=Effects(runout=Runout(15e-6)), background=cell.background, sensors=cell.sensors, seed=5)
    rec = sim.to_record(cell.tool, cell.cut, material=cell.material, name="runout 15 um, coefficients off")
    rec = replace(rec, data=rec.data[:, 2000:], time_s=None)
    nominal = diagnose([rec], cell.model, refit_coefficients=False, plot_data=False)
    refit = diagnose([rec], cell.model, plot_data=False)
    g_nominal = next(r.gain for r in nominal.ranking if r.cause == "runout")
    assert refit.cause == "runout"
    assert refit.parameters["runout_amplitude_m"] == pytest.approx(15e-6, rel=PARAMETER_TOLERANCE)
    assert refit.gain > 0.9 > g_nominal
    c = refit.coefficient_fit.parameters
    assert c["Ktc_relative_change"] == pytest.approx(0.18, abs=0.03)
    assert c["Krc_relative_change"] == pytest.approx(-0.10, abs=0.03)


def test_a_significant_but_tiny_size_effect_is_not_named():
    """The issue's first miss: an exponent of a few thousandths is significant on a long record and
    changes nothing an engineer does; the floor (|p| >= 0.05) keeps it out."""
    cell = paper_like_cell()
    sim = simulate(cell.model, cell.tool, cell.cut, cell.material, duration_s=10.0,
                   effects=Effects(nonlinear_cutting=NonlinearCutting(0.02)), background=cell.background,
                   sensors=cell.sensors, seed=11)
    rec = sim.to_record(cell.tool, cell.cut, material=cell.material, name="p = 0.02")
    rec = replace(rec, data=rec.data[:, 2000:], time_s=None)
    d = diagnose([rec], cell.model, plot_data=False)
    nl = next(r for r in d.ranking if r.cause == "nonlinear_cutting")
    assert nl.parameters["exponent_p"] == pytest.approx(0.02, abs=0.015)
    assert not nl.practical["passes"] and nl.practical["size"] < FLOORS["nonlinear_cutting"][0]
    assert d.cause == "none"


def test_practical_floors_follow_their_physical_measure():
    model = paper_like_cell().model  # highest mode 24.8 Hz
    parts = SimpleNamespace(model=model, views=[])
    # a delay's phase at the highest mode: 5 deg at 24.8 Hz is 0.56 ms
    tau5 = 5.0 / (360.0 * 24.8)
    assert practical_size("channel_delay", {"delay_s": 0.9 * tau5}, parts, None)["passes"] is False
    assert practical_size("channel_delay", {"delay_s": -1.1 * tau5}, parts, None)["passes"] is True
    # ... and more than twice its own standard error
    assert practical_size("channel_delay", {"delay_s": 2 * tau5, "delay_s_sigma": 1.5 * tau5}, parts,
                          None)["passes"] is False
    # an unmodeled mode as compliant at its peak as 10 % of the model's most compliant mode
    peak = np.max(1.0 / (2 * model.damping_ratio * model.stiffness_N_m))
    k = 1.0 / (2 * 0.03 * 0.1 * peak)
    s = practical_size("unmodeled_mode", {"damping_ratio": 0.03, "stiffness_N_m": k}, parts, None)
    assert s["size"] == pytest.approx(0.1)
    assert practical_size("pose_drift", {"relative_change": -0.02}, parts, None)["passes"] is False
    assert practical_size("cutting_coefficients", {"Ktc_relative_change": 0.04, "ratio_relative_change": -0.12},
                          parts, None)["size"] == pytest.approx(0.12)


def test_tooth_radii_runout_of_two_teeth_is_an_eccentric_axis():
    """For two teeth unequal radii (2 A cos(phase), 0) give the chips of an eccentric axis A at
    ``phase`` (only ``rho_0 - rho_1`` acts)."""
    a, phase = 12e-6, 0.6
    ecc = Runout(a, phase).chip_increments(2)
    radii = ToothRadiiRunout(0.0, 0.0, (2 * a * math.cos(phase), 0.0)).chip_increments(2)
    np.testing.assert_allclose(radii, ecc, atol=1e-15)


def test_coefficient_changes_and_bad_forms():
    k = paper_like_cell().material.cutting_coefficients
    ch = coefficient_changes(k, replace(k, Ktc_N_m2=1.1 * k.Ktc_N_m2, Krc_N_m2=1.21 * k.Krc_N_m2))
    assert ch["Ktc_relative_change"] == pytest.approx(0.1)
    assert ch["ratio_relative_change"] == pytest.approx(0.1)
    with pytest.raises(ValueError, match="form of runout must be one of eccentric_axis, tooth_radii"):
        hidden_effect_case("runout", 0, form="bent_shank")
    with pytest.raises(ValueError, match="cause must be one of"):
        hidden_effect_case("gremlins", 0)
