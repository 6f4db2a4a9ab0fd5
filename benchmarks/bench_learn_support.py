"""Benchmark of what ``plan`` says about its cut with a posterior (``learned.support``, session 28).

For each seed: the benchmark's one-mode tool (``planner.learn.synthetic.tool_problem``), the prior
off by up to 1.5 prior sds in each of the five parameters; 30 random test cuts (as
``bench_learn.py``) labelled by the truth's converged SDM with 5 % flipped; ``learn`` with the
CLI's default likelihood; the plan at P(stable) >= 0.95 over 6-24 krpm at the production cut
(0.5 D down, axial depth at most 40 mm). Then the plan is cut as a test (labelled by the truth,
unflipped), learned again and planned again. Reported per plan: whether it is truly stable (its
depth under the truth's limit at its speed) and its support status (``backed``, ``contradicted``,
``extrapolated``; :func:`planner.learn.support.plan_support`).

Truths: ``exact`` (the model's family: one mode), ``two`` (a mode the prior lacks: the tool has
modes at 700 Hz along x and 900 Hz along y, the prior the benchmark's one mode), ``extra`` (one
more mode at 1450 Hz along x).

Run: ``PYTHONPATH=. python benchmarks/bench_learn_support.py --truth exact two [--seeds 1 2 3 4 5 6]``
(about 2.5 min per seed and truth on 2 cores). docs/learn.md, session 28, has seeds 1-6 of
``exact`` and ``two``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from oma.modal import ModalModel
from planner.cli import build_parser
from planner.learn.cli import _likelihood
from planner.learn.likelihood import CHATTER, STABLE
from planner.learn.outcomes_io import CutTable
from planner.learn.posterior import PriorSD
from planner.learn.speed_range import chance_limit_for_plan
from planner.learn.support import plan_support
from planner.learn.synthetic import label, random_cuts, tool_problem, true_limits
from planner.learn.update import learn
from planner.optimize import plan

TRUTHS = {
    "exact": None,
    "two": ModalModel([700.0, 900.0], [0.03, 0.03], [1.5e7, 1.5e7], [[1, 0, 0], [0, 1, 0]]),
    "extra": ModalModel([900.0, 1450.0], [0.03, 0.03], [1.5e7, 2.0e7], [[0.6, 0.8, 0.0], [1, 0, 0]]),
}


def problem(truth: str, seed: int):
    """The benchmark's prior, off by up to 1.5 prior sds, and the truth ``truth``."""
    rng = np.random.default_rng(seed)
    base = tool_problem(u_prior=rng.uniform(-1.5, 1.5, 5) * PriorSD().log_sds())
    base = replace(base, setup=replace(base.setup, limits=replace(base.setup.limits, axial_depth_m=(2e-4, 0.04))))
    return base if TRUTHS[truth] is None else replace(base, truth=TRUTHS[truth])


def planned(prob, cuts, likelihood, seed):
    """``learn`` then ``plan`` at P >= 0.95: (rpm, depth) or None."""
    post = learn(prob.setup, prob.prior, cuts, likelihood=likelihood, seed=seed).posterior
    model = post.map_model()[0]
    limit, _ = chance_limit_for_plan(post, model, prob.setup, probability=0.95)
    result = plan(prob.setup, model, stability_limit=limit)
    if not result.success:
        return None
    d = result.to_dict()
    return d["spindle_rpm"], d["axial_depth_m"]


def one_seed(truth: str, seed: int, likelihood):
    """The two plans of a seed: (rpm, depth, true limit, status) each, or None."""
    prob = problem(truth, seed)
    ae, down = prob.setup.cut.radial_depth_m, prob.setup.cut.milling == "down"
    rng = np.random.default_rng(1000 + seed)
    cuts = random_cuts(prob, 30, rng)
    cuts = label(cuts, true_limits(prob, cuts.spindle_rpm, cuts.radial_depth_m, cuts.down), rng)
    rows = []
    for _ in range(2):
        p = planned(prob, cuts, likelihood, seed)
        if p is None:
            rows.append(None)
            break
        n, ap = p
        lim = float(true_limits(prob, [n], [ae], [down])[0])
        rows.append((n, ap, lim, plan_support(cuts, n, ap, ae, down)["status"]))
        # the plan cut as a test, labelled by the truth
        cuts = cuts.concat(CutTable(np.array([n]), np.array([ap]), np.array([ae]), np.array([down]),
                                    np.array([CHATTER if ap >= lim else STABLE]), np.ones(1), np.full(1, np.nan),
                                    np.zeros(1, bool)))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--truth", nargs="+", choices=sorted(TRUTHS), default=["exact", "two"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5, 6])
    args = ap.parse_args(argv)
    likelihood = _likelihood(build_parser().parse_args(["learn", "s", "--model", "m", "--cuts", "c"]))
    summary = {}
    print(f"{'truth':>6} {'seed':>4} | {'plan':>6} {'rpm':>7} {'depth mm':>9} {'true mm':>8} {'stable':>6} "
          f"{'status':>13} | s")
    for truth in args.truth:
        tally = summary.setdefault(truth, {})
        for seed in args.seeds:
            t0 = time.perf_counter()
            for k, row in enumerate(one_seed(truth, seed, likelihood)):
                if row is None:
                    print(f"{truth:>6} {seed:>4} | {k:>6} no plan")
                    continue
                n, depth, lim, status = row
                stable = depth < lim
                tally[(status, stable)] = tally.get((status, stable), 0) + 1
                print(f"{truth:>6} {seed:>4} | {('first', 'second')[k]:>6} {n:7.0f} {1e3 * depth:9.2f} "
                      f"{1e3 * lim:8.2f} {str(stable):>6} {status:>13} | {time.perf_counter() - t0:.0f}", flush=True)
    print("\nplans by status (truly stable / chattering):")
    for truth, tally in summary.items():
        parts = [f"{s}: {tally.get((s, True), 0)} / {tally.get((s, False), 0)}"
                 for s in ("backed", "contradicted", "extrapolated")]
        print(f"  {truth}: " + "; ".join(parts))


if __name__ == "__main__":
    main()
