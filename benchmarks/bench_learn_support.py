"""Benchmark of what ``plan`` says about its cut with a posterior (``learned.support``, session 28).

For each seed: the benchmark's one-mode tool (``planner.learn.synthetic.tool_problem``), the prior
off by up to 1.5 prior sds in each of the five parameters; 30 random test cuts (as
``bench_learn.py``) labelled by the truth's converged SDM with 5 % flipped; ``learn`` with the
CLI's default likelihood; the plan at P(stable) >= 0.95 over 6-24 krpm at the production cut
(0.5 D down, axial depth at most 40 mm). Then the plan is cut as a test (labelled by the truth,
unflipped), learned again and planned again. Reported per plan: whether it is truly stable (its
depth under the truth's limit at its speed) and its support status (``backed``, ``contradicted``,
``extrapolated``; :func:`planner.learn.support.plan_support`). Where it is not backed, the best cut
the stable test cuts prove (:func:`planner.learn.support.best_backed`, session 29): its speed, depth,
true stability and share of the plan's removal rate, with stable marks trusted up to each of
:data:`DOUBTS` (the posterior's probability that the mark is wrong; 1: every mark at face value).

Truths: ``exact`` (the model's family: one mode), ``two`` (a mode the prior lacks: the tool has
modes at 700 Hz along x and 900 Hz along y, the prior the benchmark's one mode), ``extra`` (one
more mode at 1450 Hz along x).

Run: ``PYTHONPATH=. python benchmarks/bench_learn_support.py --truth exact two [--seeds 1 2 3 4 5 6]
[--flip 0.05]`` (the share of the random cuts' marks flipped)
(1-2 min per seed and truth on 2 cores: the default 6 seeds of both truths in 15-20 min, session
29). docs/learn.md, sessions 28-29, has seeds 1-6 of ``exact`` and ``two``.
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
from planner.learn.support import best_backed, plan_support
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
    """``learn`` then ``plan`` at P >= 0.95: (rpm, depth, mrr, MAP model, each mark's probability
    of being wrong) or None."""
    result = learn(prob.setup, prob.prior, cuts, likelihood=likelihood, seed=seed)
    post = result.posterior
    model = post.map_model()[0]
    limit, _ = chance_limit_for_plan(post, model, prob.setup, probability=0.95)
    result_plan = plan(prob.setup, model, stability_limit=limit)
    if not result_plan.success:
        return None
    d = result_plan.to_dict()
    return d["spindle_rpm"], d["axial_depth_m"], d["mrr_m3_s"], model, result.mislabel_probability


#: The doubt levels the best backed cut is tried at (a stable mark backs nothing when the
#: posterior's probability that it is wrong exceeds the level; 1: every mark at face value).
DOUBTS = (0.5, 0.2, 0.05, 1.0)


def alternative(prob, cuts, model, mislabelled, mrr, max_doubt):
    """The best backed cut: (rpm, depth, true limit, share of the plan's removal rate, the backing
    mark's probability of being wrong) or None."""
    alt = best_backed(prob.setup, model, cuts, mislabelled=mislabelled, max_doubt=max_doubt)
    if alt is None:
        return None
    cut = prob.setup.cut
    lim = float(true_limits(prob, [alt["spindle_rpm"]], [cut.radial_depth_m], [cut.milling == "down"])[0])
    return alt["spindle_rpm"], alt["axial_depth_m"], lim, alt["mrr_m3_s"] / mrr, float(mislabelled[alt["backed_by"]])


def one_seed(truth: str, seed: int, likelihood, flip: float = 0.05):
    """The two plans of a seed: (rpm, depth, true limit, status, the best backed cut at each of
    :data:`DOUBTS`) each, or None."""
    prob = problem(truth, seed)
    ae, down = prob.setup.cut.radial_depth_m, prob.setup.cut.milling == "down"
    rng = np.random.default_rng(1000 + seed)
    cuts = random_cuts(prob, 30, rng)
    cuts = label(cuts, true_limits(prob, cuts.spindle_rpm, cuts.radial_depth_m, cuts.down), rng, flip=flip)
    rows = []
    for _ in range(2):
        p = planned(prob, cuts, likelihood, seed)
        if p is None:
            rows.append(None)
            break
        n, ap, mrr, model, wrong = p
        lim = float(true_limits(prob, [n], [ae], [down])[0])
        status = plan_support(cuts, n, ap, ae, down, mislabelled=wrong)["status"]
        alts = [alternative(prob, cuts, model, wrong, mrr, d) if status != "backed" else None for d in DOUBTS]
        rows.append((n, ap, lim, status, alts))
        # the plan cut as a test, labelled by the truth
        cuts = cuts.concat(CutTable(np.array([n]), np.array([ap]), np.array([ae]), np.array([down]),
                                    np.array([CHATTER if ap >= lim else STABLE]), np.ones(1), np.full(1, np.nan),
                                    np.zeros(1, bool)))
    return rows


def _alt(a):
    if a is None:
        return f"{'-':>22}"
    n, depth, lim, share, doubt = a
    mark = "!" if depth >= lim else " "
    return f"{n:6.0f} {1e3 * depth:5.1f}{mark} {100 * share:3.0f}% {doubt:4.2f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--truth", nargs="+", choices=sorted(TRUTHS), default=["exact", "two"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--flip", type=float, default=0.05, help="share of the random cuts' marks flipped")
    args = ap.parse_args(argv)
    likelihood = _likelihood(build_parser().parse_args(["learn", "s", "--model", "m", "--cuts", "c"]))
    summary, alts = {}, {}
    print("best backed cut at each doubt level: rpm, depth mm (! chatters), share of the plan's removal rate, "
          "the backing mark's probability of being wrong")
    print(f"{'truth':>6} {'seed':>4} | {'plan':>6} {'rpm':>7} {'depth mm':>9} {'true mm':>8} {'stable':>6} "
          f"{'status':>13} | " + " | ".join(f"{'doubt <= ' + format(d, 'g'):>22}" for d in DOUBTS) + " | s")
    for truth in args.truth:
        tally = summary.setdefault(truth, {})
        for seed in args.seeds:
            t0 = time.perf_counter()
            for k, row in enumerate(one_seed(truth, seed, likelihood, args.flip)):
                if row is None:
                    print(f"{truth:>6} {seed:>4} | {k:>6} no plan")
                    continue
                n, depth, lim, status, found = row
                stable = depth < lim
                tally[(status, stable)] = tally.get((status, stable), 0) + 1
                for d, a in zip(DOUBTS, found):
                    if a is not None:
                        t = alts.setdefault(d, [0, 0, []])
                        t[0 if a[1] < a[2] else 1] += 1
                        t[2].append(a[3])
                print(f"{truth:>6} {seed:>4} | {('first', 'second')[k]:>6} {n:7.0f} {1e3 * depth:9.2f} "
                      f"{1e3 * lim:8.2f} {str(stable):>6} {status:>13} | " + " | ".join(_alt(a) for a in found)
                      + f" | {time.perf_counter() - t0:.0f}", flush=True)
    print("\nplans by status (truly stable / chattering):")
    for truth, tally in summary.items():
        parts = [f"{s}: {tally.get((s, True), 0)} / {tally.get((s, False), 0)}"
                 for s in ("backed", "contradicted", "extrapolated")]
        print(f"  {truth}: " + "; ".join(parts))
    print("best backed cuts by doubt level (truly stable / chattering; median share of the plan's removal rate):")
    for d in DOUBTS:
        if d in alts:
            ok, bad, shares = alts[d]
            print(f"  <= {d:g}: {ok} / {bad}; {100 * np.median(shares):.0f} %")


if __name__ == "__main__":
    main()
