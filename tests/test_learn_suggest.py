"""``--suggest``: expected improvement of the best stable MRR, on hand-made probability lobes."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

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
