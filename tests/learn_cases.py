"""A posterior for ``plan`` and ``lobes`` tests (tests/test_learn_plan.py, tests/test_learn_support.py):
the benchmark's one-mode tool slotting in a 9-12 krpm window, samples drawn around the prior
(frequency and stiffness free, ZOA learned)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from planner.learn.posterior import Posterior, PriorSD
from planner.learn.synthetic import tool_problem
from stability.setup import Limits


def slotting_posterior(**limits):
    """(problem, setup, posterior): the setup slotting with speed, depth and feed limits (and
    ``limits``, e.g. ``stability_margin``), 300 samples of 0.3 prior sd in frequency and stiffness."""
    problem = tool_problem()
    setup = replace(problem.setup, cut=replace(problem.setup.cut, radial_depth_m=problem.setup.tool.diameter_m),
                    limits=Limits(spindle_rpm=(9000.0, 12000.0), axial_depth_m=(1e-4, 0.05),
                                  feed_per_tooth_m=(5e-5, 1e-4), **limits))
    rng = np.random.default_rng(7)
    sd = PriorSD().log_sds() * np.array([1, 1, 0, 0, 0])
    samples = rng.standard_normal((300, 5)) * sd * 0.3
    post = Posterior(reference=problem.prior, coefficients=setup.material.cutting_coefficients, prior_log_sd=sd,
                     samples=samples, log_posterior=-np.sum((samples[:, :2] / sd[:2]) ** 2, axis=1), method="zoa")
    return problem, setup, post
