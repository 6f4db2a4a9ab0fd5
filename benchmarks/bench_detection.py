"""How late the chatter detection of records is: the boundary of detected outcomes against the
true (converged SDM) limit, which ``Likelihood.detection_lag`` and ``detection_scale`` model
(robomill issue 12, docs/learn.md session 9).

Run::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_detection.py [--cuts 300] [--durations 1 2 4]
        [--seed 2] [--fn 900] [--zeta 0.03] [--stiffness 1.5e7]

Cuts at random speeds, immersions (0.1-1 D) and up/down milling of a one-mode tool
(:func:`planner.learn.synthetic.tool_problem`; ``--fn``, ``--zeta``, ``--stiffness`` give another
tool), each at a depth 0.7-2.5x its true limit (log-uniform), simulated in the time domain
(:func:`planner.learn.synthetic.record_labels`: the tool leaving the cut, a weak background force,
10 kHz) and judged by ``diagnose``'s detection. Prints, per record length, the share detected as
chatter per bin of depth / limit and the maximum-likelihood fit of
``P(chatter read) = eps + (1 - 2 eps) expit((log(a/b) - lag) / s)``, unweighted and weighted by
the detection confidence (as ``learn`` weights them).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, log_expit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from planner.learn.likelihood import CHATTER, DETECTION_LAG, DETECTION_SCALE  # noqa: E402
from planner.learn.synthetic import random_cuts, record_labels, tool_problem, true_limits  # noqa: E402

BINS = (0.7, 0.9, 1.0, 1.1, 1.2, 1.35, 1.5, 1.75, 2.0, 2.5)


def fit_lag(log_r, chatter, weight) -> tuple[float, float, float]:
    """Maximum-likelihood (lag, scale, eps) of the lagged logistic read model."""
    def nll(p):
        lag, log_s, logit_e = p
        e = 0.5 * expit(logit_e)
        with np.errstate(divide="ignore", over="ignore"):  # eps -> 0 and a step-like boundary are allowed
            x = (log_r - lag) / np.exp(log_s)
            log_ch = np.logaddexp(np.log(e), np.log1p(-2 * e) + log_expit(x))
            log_st = np.logaddexp(np.log(e), np.log1p(-2 * e) + log_expit(-x))
        return -np.sum(weight * np.where(chatter, log_ch, log_st))

    res = minimize(nll, [0.1, np.log(0.1), -3.0], method="Nelder-Mead",
                   options=dict(xatol=1e-5, fatol=1e-7, maxiter=4000))
    lag, log_s, logit_e = res.x
    return float(lag), float(np.exp(log_s)), float(0.5 * expit(logit_e))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cuts", type=int, default=300)
    ap.add_argument("--durations", type=float, nargs="+", default=[2.0])
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--fn", type=float, default=900.0, help="the tool mode's frequency, Hz")
    ap.add_argument("--zeta", type=float, default=0.03)
    ap.add_argument("--stiffness", type=float, default=1.5e7, help="N/m")
    args = ap.parse_args(argv)
    log = lambda s: print(s, flush=True)  # noqa: E731
    prob = tool_problem(fn_hz=args.fn, zeta=args.zeta, stiffness_N_m=args.stiffness)
    rng = np.random.default_rng(args.seed)
    cuts = random_cuts(prob, args.cuts, rng)
    limit = true_limits(prob, cuts.spindle_rpm, cuts.radial_depth_m, cuts.down)
    ratio = np.exp(rng.uniform(np.log(BINS[0]), np.log(BINS[-1]), args.cuts))
    cuts = replace(cuts, axial_depth_m=limit * ratio)
    log(f"# detection of chatter from records: tool {args.fn:g} Hz / {args.zeta:g} / {args.stiffness:.3g} N/m, "
        f"{args.cuts} cuts, seed {args.seed} (likelihood's lag {DETECTION_LAG}, scale {DETECTION_SCALE})")
    header = "| depth / limit | " + " | ".join(f"{d:g} s" for d in args.durations) + " |"
    reads = {}
    for d in args.durations:
        t0 = time.perf_counter()
        lab, _ = record_labels(prob, cuts, duration_s=d, seed=1000 * args.seed)
        reads[d] = lab
        log(f"{d:g} s records: {time.perf_counter() - t0:.0f} s")
    log("\nshare read as chatter (n)")
    log(header)
    log("|---" * (len(args.durations) + 1) + "|")
    for lo, hi in zip(BINS[:-1], BINS[1:]):
        m = (ratio >= lo) & (ratio < hi)
        cells = [f"{np.mean(reads[d].outcome[m] == CHATTER):.2f} ({m.sum()})" if m.any() else "-"
                 for d in args.durations]
        log(f"| {lo:.2f}-{hi:.2f} | " + " | ".join(cells) + " |")
    log("\nfit of the lagged read model: lag (x limit), scale, eps")
    for d in args.durations:
        ch = reads[d].outcome == CHATTER
        for name, w in (("unweighted", np.ones(args.cuts)), ("confidence-weighted", reads[d].weight)):
            lag, s, e = fit_lag(np.log(ratio), ch, w)
            log(f"| {d:g} s | {name} | lag {lag:.3f} (x{np.exp(lag):.2f}) | scale {s:.3f} | eps {e:.3f} |")


if __name__ == "__main__":
    main()
