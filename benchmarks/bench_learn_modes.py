"""Benchmark of ``learn`` with a two-mode prior: what one factor per group does when the modes are off apart.

``learn`` moves every mode by one frequency, one stiffness and one damping factor (docs/learn.md:
a per-mode posterior is not implemented). This measures what that costs on a tool whose two modes
are off from the prior in *different* directions, against a control whose modes are off together.

Truth: a two-mode tool (:func:`planner.learn.synthetic.two_mode_problem`: 900 Hz along the feed,
1250 Hz along the cut normal, 3 %, 1.5e7 / 2e7 N/m, the benchmark's coefficients). Case ``apart``:
the prior is off by up to ``--prior-scale`` prior sds in each of the eight per-mode parameters,
independently; case ``together``: both modes off by the same factors (what the model represents).
Test cuts as in ``bench_learn.py``: random speeds, immersions 0.1/0.25/0.5/1.0 D, up/down, depths
log-uniform, labelled by the converged SDM with 5 % of the labels flipped; held-out cuts unflipped.

Reports per seed and the medians: held-out accuracy of the prior's nominal model and of the
posterior, the 50 % boundary's error against the true limit at the production cut (0.5 D down), the
share of the truth's per-mode parameters inside the posterior's 5-95 % range (both modes given the
one factor; per mode), the modes' shares of the cuts' limits that ``learn`` reports (which mode the
outcomes are evidence about), the cross-validated accuracy ``learn`` reports, and whether it warned that the
posterior predicts the cuts worse than the prior.

Run: ``PYTHONPATH=. python benchmarks/bench_learn_modes.py [--seeds 0 1 2 ...] [--cuts 30] [--held 30]
[--mode-correlation 0.5]``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from planner.learn.posterior import PriorSD
from planner.learn.predictive import predict_cuts, probability_lobes
from planner.learn.synthetic import label, random_cuts, true_limits, two_mode_problem
from planner.learn.update import learn

RPM = (6000.0, 24000.0)


def truth_offsets(rng, scale, case):
    """Per-mode log-multipliers of the truth against the prior (frequency[0, 1], stiffness[0, 1],
    damping[0, 1], Ktc, Krc), uniform in +-scale prior sds; ``together``: one draw per group."""
    sd = PriorSD().log_sds()
    u = rng.uniform(-scale, scale, 8) * np.repeat(sd, [2, 2, 2, 1, 1])
    if case == "together":
        u[[1, 3, 5]] = u[[0, 2, 4]]
    return u


def coverage(post, u_truth):
    """Whether each of the truth's per-mode log-multipliers is inside the posterior's 5-95 % range
    (both modes given the posterior's one factor per group, plus their own deviations below full
    correlation): (mode 0's three, mode 1's three, the coefficients' two) as three shares."""
    rng = np.random.default_rng(0)
    u = post.samples[:, [0, 0, 1, 1, 2, 2, 3, 4]]
    # below full correlation each mode's own deviation (not learned) is part of its posterior
    u[:, :6] += np.repeat(post.mode_spread, 2)[None, :] * rng.standard_normal((u.shape[0], 6))
    lo, hi = np.quantile(u, [0.05, 0.95], axis=0)
    inside = (u_truth >= lo) & (u_truth <= hi)
    return float(np.mean(inside[[0, 2, 4]])), float(np.mean(inside[[1, 3, 5]])), float(np.mean(inside[6:]))


def run_seed(seed, case, n_cuts, n_held, log):
    rng = np.random.default_rng(1000 + seed)
    u_true = truth_offsets(rng, ARGS.prior_scale, case)
    pb = two_mode_problem(u_prior=-u_true)  # truth = prior x exp(u_true)
    train, held = random_cuts(pb, n_cuts, rng), random_cuts(pb, n_held, rng)
    train = label(train, true_limits(pb, train.spindle_rpm, train.radial_depth_m, train.down), rng, flip=0.05)
    stable_he = held.axial_depth_m < true_limits(pb, held.spindle_rpm, held.radial_depth_m, held.down)
    rpm = np.geomspace(*RPM, 60)
    lim_prod = true_limits(pb, rpm, np.full(rpm.size, pb.setup.cut.radial_depth_m), np.ones(rpm.size, bool))
    t0 = time.perf_counter()
    res = learn(pb.setup, pb.prior, train, seed=seed, mode_correlation=ARGS.mode_correlation)
    t = time.perf_counter() - t0
    p = predict_cuts(res.posterior, pb.setup, held)
    err = np.abs(probability_lobes(res.posterior, pb.setup, RPM, n_rpm=60).quantiles[0.5] / lim_prod - 1.0)
    prior_pb = replace(pb, truth=pb.prior, truth_coefficients=pb.setup.material.cutting_coefficients)
    prior_lim = true_limits(prior_pb, held.spindle_rpm, held.radial_depth_m, held.down, converged=False)
    prior_err = np.abs(true_limits(prior_pb, rpm, np.full(rpm.size, pb.setup.cut.radial_depth_m),
                                   np.ones(rpm.size, bool), converged=False) / lim_prod - 1.0)
    row = {"seed": seed, "case": case, "prior_acc": float(np.mean((held.axial_depth_m < prior_lim) == stable_he)),
           "acc": float(np.mean((p >= 0.5) == stable_he)), "boundary": float(np.median(err)),
           "prior_boundary": float(np.median(prior_err)), "coverage": coverage(res.posterior, u_true),
           "shares": res.to_dict()["mode_shares"],
           "cv_before": res.accuracy_before, "cv_after": res.accuracy_after, "time": t,
           "warned_worse": any("worse than the prior" in w for w in res.warnings)}
    log(f"{case} seed {seed}: held-out prior {row['prior_acc']:.3f} posterior {row['acc']:.3f}; boundary prior "
        f"{row['prior_boundary']:.3f} posterior {row['boundary']:.3f}; truth inside (mode 0 / mode 1 / "
        f"coefficients) {'/'.join(f'{x:.2f}' for x in row['coverage'])}; mode shares "
        f"{'/'.join(f'{x:.2f}' for x in row['shares'])}; "
        f"cv {row['cv_before']:.2f} -> {row['cv_after']:.2f}; warned {row['warned_worse']}; {t:.0f} s")
    return row


def main(argv=None):
    global ARGS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(6)))
    ap.add_argument("--cases", nargs="+", default=["apart", "together"], choices=["apart", "together"])
    ap.add_argument("--cuts", type=int, default=30)
    ap.add_argument("--held", type=int, default=30)
    ap.add_argument("--prior-scale", type=float, default=1.5)
    ap.add_argument("--mode-correlation", type=float, default=1.0,
                    help="learn's correlation of the modes' factors (below 1: their own deviations integrated out)")
    ARGS = ap.parse_args(argv)
    rows = [run_seed(s, c, ARGS.cuts, ARGS.held, lambda m: print(m, flush=True)) for c in ARGS.cases for s in ARGS.seeds]
    print(f"\n{len(ARGS.seeds)} seeds per case, {ARGS.cuts} cuts, {ARGS.held} held out, mode correlation "
          f"{ARGS.mode_correlation:g} (medians; warned: share of seeds)")
    print("| case | held-out accuracy prior / posterior | 50 % boundary error prior / posterior | truth inside 5-95 % "
          "(mode 0 / mode 1 / coefficients, mean) | mode shares (median) | cross-validated before / after "
          "| warned 'worse than the prior' | time |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for c in ARGS.cases:
        rs = [r for r in rows if r["case"] == c]
        med = lambda k: float(np.median([r[k] for r in rs]))  # noqa: E731
        print(f"| {c} | {med('prior_acc'):.3f} / {med('acc'):.3f} | {med('prior_boundary'):.3f} / {med('boundary'):.3f} "
              f"| {' / '.join(f'{x:.2f}' for x in np.mean([r['coverage'] for r in rs], axis=0))} "
              f"| {' / '.join(f'{x:.2f}' for x in np.median([r['shares'] for r in rs], axis=0))} "
              f"| {med('cv_before'):.2f} / {med('cv_after'):.2f} | "
              f"{np.mean([r['warned_worse'] for r in rs]):.2f} | {med('time'):.0f} s |")


if __name__ == "__main__":
    main()
