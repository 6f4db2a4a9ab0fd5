"""The fast probability lobes (``lobes --model``, ``learn --plot``, ``--suggest-for boundary``):
limit tables solved only where the posterior's samples read them, their searches started from the
ZOA limit, and the SDM's multipliers found without forming the monodromy (``tests/test_sdm.py``)
give the reference's values.

The tolerances are those of the numerics, far below the tables' own interpolation error (RMS
0.06-0.07 in log against direct limits, the training cuts' ``model_error`` 0.055 on the kr500
example): the multipliers agree to rounding (where 20 Arnoldi vectors do not converge, to the
residual test's 1e-9 against LAPACK), and the limits of the same searches with them. Searches
started from the ZOA limit (not 1 mm) agree to their bracket's tolerance (2e-3), except where a
thin island of instability lies under the boundary (none in these cases; 10 of the kr500
example's 4561 table entries): either start may end on either side of it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from oma.modal_io import read_modal_model
from planner.learn import tables
from planner.learn.posterior import Posterior
from planner.learn.outcomes_io import CutTable
from planner.learn.predictive import checked_predictions, lobes_from_table, probability_lobes
from planner.learn.tables import Grid, build_table, direct_log_limits, reference_limits
from stability import sdm
from stability.sdm import SDMProblem
from stability.setup_io import read_setup

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "kr500_acetal"
#: Limits found by the same search from multipliers equal to rounding: measured 5e-15 relative
#: (the matrix-free product sums in another order); 1e-9 leaves room for the Arnoldi residual
#: test (1e-9) where the dense path would fall back to LAPACK, and is 6 orders below the search's
#: own bracket (2e-3).
SAME_SEARCH_RTOL = 1e-9
#: Limits of searches started elsewhere: each ends in a bracket 2e-3 wide (``reference_limits``'
#: ``depth_rtol``), its root interpolated inside it (measured on the example: 2.2e-4 at most).
OTHER_START_RTOL = 2e-3


@pytest.fixture(scope="module")
def example():
    """The kr500 example's two tool modes (720/735 Hz, 2 %), 2-flute 30 deg helix, 6 mm down
    milling: at 500-1000 rpm a tooth period holds 20-45 mode periods (monodromies of ~500-1500)."""
    setup = read_setup(EXAMPLE / "setup.yaml")
    return setup, read_modal_model(EXAMPLE / "models" / "tool_mode.yaml")


def test_table_limits_equal_those_of_the_formed_monodromy(example, monkeypatch):
    """``reference_limits`` (the tables' solver) over 450-3000 rpm, where its multipliers are
    found matrix-free, equals the same searches on the formed monodromy."""
    setup, model = example
    coef = setup.material.cutting_coefficients
    rpm = np.geomspace(450.0, 3000.0, 9)
    fast = reference_limits(model, setup.tool, setup.cut, coef, rpm, method="sdm")
    monkeypatch.setattr(sdm, "MATRIX_FREE_MIN_SIZE", np.inf)
    formed = reference_limits(model, setup.tool, setup.cut, coef, rpm, method="sdm")
    np.testing.assert_allclose(fast, formed, rtol=SAME_SEARCH_RTOL)


def test_searches_started_from_the_zoa_limit_agree_with_fewer_evaluations(example, monkeypatch):
    """``zoa_start``: the same limits to the search's tolerance, fewer multipliers evaluated
    (from 1 mm the bracketing doubles its way up to the limit)."""
    setup, model = example
    coef = setup.material.cutting_coefficients
    rpm = np.geomspace(2000.0, 20000.0, 40)  # lobes enough for the envelope to hold cusps
    counted, radii = [], SDMProblem._radii
    monkeypatch.setattr(SDMProblem, "_radii",
                        lambda self, r, a, m: counted.append(np.size(r)) or radii(self, r, a, m))
    runs = {}
    for start in (False, True):
        counted.clear()
        runs[start] = reference_limits(model, setup.tool, setup.cut, coef, rpm, method="sdm", zoa_start=start), \
            sum(counted)
    np.testing.assert_allclose(runs[True][0], runs[False][0], rtol=OTHER_START_RTOL)
    assert runs[True][1] < 0.85 * runs[False][1]


def _correlated_samples(n: int, seed: int) -> np.ndarray:
    """Log-multipliers whose damping and ``Krc/Ktc`` factors are strongly correlated (as the
    example's posterior: corners of the node grid stay empty)."""
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((n, 5))
    u = z * np.array([0.03, 0.2, 0.3, 0.1, 0.1])
    u[:, 4] = u[:, 3] + 0.9 * u[:, 2] + 0.05 * z[:, 4]  # ratio factor follows damping
    return u


def _posterior_and_grid(setup, model, u, method, zeta_nodes, ratio_nodes):
    """A posterior of the samples ``u`` (log-multipliers of the example's tool modes), and a grid
    over their frequency factors with these damping and ``Krc/Ktc`` nodes."""
    post = Posterior(reference=model, coefficients=setup.material.cutting_coefficients,
                     prior_log_sd=np.array([0.1, 0.3, 0.5, 0.25, 0.25]), samples=u,
                     log_posterior=-np.sum(u ** 2, axis=1), method=method)
    return post, Grid((float(u[:, 0].min()), float(u[:, 0].max())), 0.015, np.asarray(zeta_nodes),
                      np.asarray(ratio_nodes))


def test_a_table_for_samples_holds_the_whole_tables_values_where_they_read(example, monkeypatch):
    """``build_table(..., samples=)`` solves fewer entries; those it solves equal the whole
    table's, the others are NaN (a parameter set reading them gets NaN, not a number), and the
    samples' log limits equal the whole table's."""
    setup, model = example
    u = _correlated_samples(60, 1)
    grid = Grid((float(u[:, 0].min()), float(u[:, 0].max())), 0.015, np.linspace(-0.9, 0.9, 4),
                np.linspace(-0.8, 0.8, 3))
    rpm = np.geomspace(9000.0, 14000.0, 12)
    cuts = (rpm, np.full(rpm.size, setup.cut.radial_depth_m), np.ones(rpm.size, bool))
    base = (model, setup.tool, setup.cut, setup.material.cutting_coefficients)
    whole = build_table(*base, *cuts, grid, method="zoa", workers=1)
    solved, job = [], tables._log_limits_job
    monkeypatch.setattr(tables, "_log_limits_job", lambda j: solved.append(j[5].size) or job(j))
    part = build_table(*base, *cuts, grid, method="zoa", workers=1, samples=u)
    monkeypatch.undo()
    have = np.isfinite(part.values[0])
    assert sum(solved) == have.sum() < 0.85 * have.size  # empty corners are not solved
    # the ZOA envelope of other speeds agrees to rounding (measured 2e-14)
    np.testing.assert_allclose(part.values[0][have], whole.values[0][have], rtol=SAME_SEARCH_RTOL)
    np.testing.assert_allclose(part.log_limit(*u.T), whole.log_limit(*u.T), rtol=SAME_SEARCH_RTOL)
    corner = np.array([[0.0, 0.0, -0.9, 0.0, 0.8]])  # low damping with a high ratio: no sample there
    assert np.all(np.isnan(part.log_limit(*corner.T))) and np.all(np.isfinite(whole.log_limit(*corner.T)))


def test_probability_lobes_equal_the_dense_reference(example, monkeypatch):
    """The fast path (matrix-free multipliers, a table for the samples, searches from the ZOA
    limit) against the dense reference (the formed monodromy, the whole table, from 1 mm) at low
    speed, where the fast path saves most: the same limits of every sample and the same 5/50/95 %
    depths, to the searches' tolerance."""
    setup, model = example
    u = _correlated_samples(80, 2)
    post, grid = _posterior_and_grid(setup, model, u, "sdm", [-0.5, 0.5], [-0.45, 0.45])
    rng = (900.0, 1250.0)
    fast = probability_lobes(post, setup, rng, n_rpm=12, grid=grid, check=0)  # the table alone
    monkeypatch.setattr(sdm, "MATRIX_FREE_MIN_SIZE", np.inf)  # the formed monodromy
    rpm = np.geomspace(*rng, 12)
    dense_table = build_table(model, setup.tool, setup.cut, post.coefficients, rpm,
                              np.full(12, setup.cut.radial_depth_m), np.ones(12, bool), grid, method="sdm", workers=1)
    ref = lobes_from_table(post.thinned(400), dense_table, rpm, radial_depth_m=setup.cut.radial_depth_m,
                           milling="down")
    assert np.isnan(dense_table.values[0]).sum() == 0
    np.testing.assert_allclose(fast.limits, ref.limits, rtol=OTHER_START_RTOL)
    for p in ref.levels:
        np.testing.assert_allclose(fast.quantiles[p], ref.quantiles[p], rtol=OTHER_START_RTOL)


def test_the_lobes_carry_their_tables_measured_error(example):
    """A table on a coarse node grid (damping and ``Krc/Ktc`` nodes 1.8 and 1.6 apart in log) is
    off the directly solved limits by much more than the training cuts' error (0 here): the check
    measures it, its estimate holds at other samples and speeds than it used (within a factor 2
    of their RMS error), and the contours' soft boundary carries it."""
    setup, model = example
    u = _correlated_samples(60, 3)
    post, grid = _posterior_and_grid(setup, model, u, "zoa", [-0.9, 0.9], [-0.8, 0.8])  # coarse nodes
    rng, n_rpm = (9000.0, 14000.0), 41
    lobes = probability_lobes(post, setup, rng, n_rpm=n_rpm, grid=grid, check=8, check_speeds=11)
    assert post.likelihood.model_error == 0 and lobes.table_error > 0.05  # measured 0.15
    assert lobes.scale == pytest.approx(np.hypot(post.likelihood.boundary_scale, lobes.table_error))
    # elsewhere: 8 other samples (the check drew with seed 0 from the thinned posterior, here the
    # same 60) at the speeds between the check's (its 11 of 41 are every 4th)
    thin = post.thinned(400).samples  # the lobes' samples, in their order (the MAP first)
    checked = np.random.default_rng(0).permutation(thin.shape[0])[:8]
    others = np.setdiff1d(np.arange(thin.shape[0]), checked)[:8]
    cols = np.arange(2, n_rpm, 4)
    direct = direct_log_limits(model, setup.tool, setup.cut, post.coefficients, lobes.rpm[cols],
                               np.full(cols.size, setup.cut.radial_depth_m), np.ones(cols.size, bool), thin[others],
                               method="zoa", workers=1)
    held_out = np.sqrt(np.mean((np.log(lobes.limits[np.ix_(others, cols)]) - direct) ** 2))
    assert 0.5 < lobes.table_error / held_out < 2.0


def test_predictions_carry_their_tables_measured_error(example):
    """``--predict`` checks its table as the lobes do (8 samples, 12 of the cuts spread over their
    speeds): on the coarse node grid the error measured holds at the other cuts (within a factor
    2 of their RMS error) and the predictions' soft boundary carries it."""
    setup, model = example
    u = _correlated_samples(60, 4)
    post, grid = _posterior_and_grid(setup, model, u, "zoa", [-0.9, 0.9], [-0.8, 0.8])  # coarse nodes
    n = 36
    rpm = np.random.default_rng(5).permutation(np.geomspace(9000.0, 14000.0, n))  # any order
    ae = np.where(np.arange(n) % 2, 0.006, 0.003)  # two engagements
    cuts = CutTable(rpm, np.full(n, 0.004), ae, np.ones(n, bool), np.full(n, -1), np.ones(n), np.full(n, np.nan),
                    np.zeros(n, bool))
    p, err = checked_predictions(post, setup, cuts, grid=grid)
    assert err > 0.05 and post.likelihood.model_error == 0
    p0, err0 = checked_predictions(post, setup, cuts, grid=grid, check=0)
    assert err0 == 0 and not np.allclose(p, p0)
    # the error at cuts the check did not use, for other samples
    checked = np.random.default_rng(0).permutation(u.shape[0])[:8]
    others = np.setdiff1d(np.arange(u.shape[0]), checked)[:8]
    used = np.argsort(rpm, kind="stable")[np.round(np.linspace(0, n - 1, 12)).astype(int)]
    rest = np.setdiff1d(np.arange(n), used)
    table = build_table(model, setup.tool, setup.cut, post.coefficients, rpm[rest], ae[rest], np.ones(rest.size, bool),
                        grid, method="zoa", workers=1)
    direct = direct_log_limits(model, setup.tool, setup.cut, post.coefficients, rpm[rest], ae[rest],
                               np.ones(rest.size, bool), u[others], method="zoa", workers=1)
    held_out = np.sqrt(np.mean((post.log_limits(table, samples=u[others]) - direct) ** 2))
    assert 0.5 < err / held_out < 2.0
