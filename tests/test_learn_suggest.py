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
