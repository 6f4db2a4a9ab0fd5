"""Benchmark of ``robomill learn`` (issue 12): accuracy, boundary, calibration, baselines, suggest, speed.

Truth: a one-mode tool and its cutting coefficients; the prior is off by up to 1.5 prior sds in
each of the five parameters (uniform). Test cuts: random speeds (6-24 krpm), radial immersions
0.1/0.25/0.5/1.0 D, up or down milling, axial depths log-uniform; labelled by the converged SDM
(40 steps per mode period, 80 per tooth period at least) with 5 % of the labels flipped. Held-out
cuts are labelled by the same SDM, unflipped.

Reports (medians over seeds):
* held-out accuracy: the prior's nominal model (what a shop uses without learning) and the
  posterior (P(stable) >= 0.5), per number of training cuts;
* the posterior's 50 % boundary against the true limit over speed at the production cut
  (0.5 D, down): median relative error and the share of speeds within 10 %;
* reliability: held-out cuts binned by posterior P(stable), the share truly stable per bin;
* baselines on the same cuts: logistic regression and k-nearest neighbours (k = 5) on
  (speed, log axial depth, radial immersion, down), numpy only, and how many cuts each needs for
  90 % held-out accuracy;
* --suggest vs a grid of test cuts: cuts needed to find a stable cut within 5 % of the best stable
  MRR at the production engagement;
* speed: learning 40 cuts, predicting 1000.

Run: ``PYTHONPATH=. python benchmarks/bench_learn.py [--seeds 20] [--quick]``. The README's numbers:
two processes ``--seed-list 0 2 ... 18`` and ``1 3 ... 19`` with ``--sizes 20 40 --held 30 --no-speed
--suggest-seeds 0 --save PART.pkl``, then ``--combine A.pkl B.pkl --sizes 20 40 --held 30``;
``--seeds 0 --suggest-seeds 4``; ``--seeds 0 --speed``.
"""

from __future__ import annotations

import argparse
import os
import pickle
import sys
import time
from dataclasses import replace

import numpy as np

from planner.learn.likelihood import DETECTION_LAG, DETECTION_SCALE, LEARNED_MISLABEL_SD, STABLE, Likelihood
from planner.learn.outcomes_io import CutTable
from planner.learn.posterior import PriorSD
from planner.learn.predictive import lobes_from_table, predict_cuts, predictive_grid, probability_lobes
from planner.learn.suggest import suggest_cuts
from planner.learn.synthetic import label, random_cuts, record_labels, tool_problem, true_limits
from planner.learn.tables import build_table, reference_limits
from planner.workers import default_workers

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import median_time  # noqa: E402
from planner.learn.update import learn

RPM = (6000.0, 24000.0)


# ----------------------------------------------------------------------------------- baselines
def _features(c: CutTable, d):
    return np.stack([c.spindle_rpm / 1e4, np.log(c.axial_depth_m * 1e3), c.radial_depth_m / d, c.down * 1.0], 1)


def logistic(train: CutTable, test: CutTable, d, *, l2=1e-2) -> np.ndarray:
    """P(stable) by L2-regularised logistic regression (Newton / IRLS)."""
    x, xt = _features(train, d), _features(test, d)
    mu, sd = x.mean(0), x.std(0) + 1e-12
    x, xt = (x - mu) / sd, (xt - mu) / sd
    x, xt = np.c_[np.ones(len(x)), x], np.c_[np.ones(len(xt)), xt]
    y = (train.outcome == STABLE) * 1.0
    w = np.zeros(x.shape[1])
    for _ in range(50):
        p = 1 / (1 + np.exp(-x @ w))
        g = x.T @ (p - y) + l2 * w
        h = x.T @ (x * (p * (1 - p))[:, None]) + l2 * np.eye(len(w))
        step = np.linalg.solve(h, g)
        w -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return 1 / (1 + np.exp(-xt @ w))


def knn(train: CutTable, test: CutTable, d, *, k=5) -> np.ndarray:
    x, xt = _features(train, d), _features(test, d)
    mu, sd = x.mean(0), x.std(0) + 1e-12
    x, xt = (x - mu) / sd, (xt - mu) / sd
    dist = np.linalg.norm(xt[:, None, :] - x[None, :, :], axis=2)
    idx = np.argsort(dist, axis=1)[:, : min(k, len(x))]
    return np.mean(train.outcome[idx] == STABLE, axis=1)


def subset(c: CutTable, n: int) -> CutTable:
    return c.take(slice(0, n))


def acc(p, truth_stable):
    return float(np.mean((p >= 0.5) == truth_stable))


# ----------------------------------------------------------------------------------- one seed
def shared_predictions(posts, setup, held: CutTable, rpm):
    """P(stable) of the held-out cuts and the probability lobes over ``rpm`` at the setup's
    engagement, for each posterior of ``posts``. One posterior: ``predict_cuts`` and
    ``probability_lobes`` themselves; several: through tables built once over all of their
    samples (the tables are the cost; each posterior is then a cheap interpolation)."""
    if len(posts) == 1:
        lobes = probability_lobes(posts[0], setup, (rpm[0], rpm[-1]), n_rpm=rpm.size)
        return [predict_cuts(posts[0], setup, held)], [lobes]
    union = replace(posts[0], samples=np.concatenate([p.samples for p in posts]), log_posterior=np.zeros(0),
                    mislabel_samples=np.zeros(0))
    grid = predictive_grid(union)
    held_table = build_table(union.reference, setup.tool, setup.cut, union.coefficients, held.spindle_rpm,
                             held.radial_depth_m, held.down, grid, method=union.method)
    lobe_table = build_table(union.reference, setup.tool, setup.cut, union.coefficients, rpm,
                             np.full(rpm.size, setup.cut.radial_depth_m), np.full(rpm.size, setup.cut.milling == "down"),
                             grid, method=union.method)
    p_all, lobes_all = [], []
    for post in posts:
        p_all.append(post.probability_stable(held_table, held.axial_depth_m))
        lobes_all.append(lobes_from_table(post.thinned(400), lobe_table, rpm, radial_depth_m=setup.cut.radial_depth_m,
                                          milling=setup.cut.milling))
    return p_all, lobes_all


def run_seed(seed, sizes, base_sizes, n_held, log, *, flip=0.05, likelihood=Likelihood(), prior_scale=1.0,
             design=None, start=10, batch=5, labels="sdm"):
    """One seed: the prior and the posterior after each size of ``sizes`` training cuts.

    ``design=None``: the first n of a pool of random cuts (the issue's benchmark). ``design='boundary'``
    (or ``'mrr'``): the first ``start`` random cuts of the same pool, then rounds of ``batch`` cuts
    suggested by ``learn --suggest-for DESIGN`` from the posterior so far, labelled like the pool
    (converged SDM, the same share flipped).

    ``labels='records'``: every training cut is simulated in the time domain and judged by the
    chatter detection (:func:`planner.learn.synthetic.record_labels`; its confidence the weight, no
    flips); held-out accuracy is then reported against the SDM truth and against the held-out cuts'
    own record labels (what the shop would see).
    """
    rng = np.random.default_rng(seed)
    sd = PriorSD().log_sds()
    u = rng.uniform(-1.5, 1.5, 5) * sd
    prob = tool_problem(u_prior=u, rpm_range=RPM)
    d = prob.setup.tool.diameter_m
    n_max = max(max(sizes), max(base_sizes))
    pool = random_cuts(prob, n_max, rng)
    pool_lim = true_limits(prob, pool.spindle_rpm, pool.radial_depth_m, pool.down)
    n_labelled = [0]

    def labelled(cuts, limits, label_rng):
        if labels == "sdm":
            return label(cuts, limits, label_rng, flip=flip)
        n_labelled[0] += 1
        return record_labels(prob, cuts, seed=1_000 * seed + 100 * (n_labelled[0] - 1))[0]

    pool = labelled(pool, pool_lim, rng)
    held = random_cuts(prob, n_held, np.random.default_rng(seed + 10_000))
    held_lim = true_limits(prob, held.spindle_rpm, held.radial_depth_m, held.down)
    truth = held.axial_depth_m < held_lim
    held_rec = None
    if labels == "records":
        held_rec = record_labels(prob, held, seed=1_000 * seed + 99_000)[0].outcome == STABLE
    # prior's nominal model on the held-out cuts
    prior_lim = np.empty(held.n_cuts)
    keys = np.stack([held.radial_depth_m, held.down * 1.0], 1)
    for key in np.unique(keys, axis=0):
        rows = np.all(keys == key, axis=1)
        cut = replace(prob.setup.cut, radial_depth_m=float(key[0]), milling="down" if key[1] else "up")
        prior_lim[rows] = reference_limits(prob.prior, prob.setup.tool, cut, prob.setup.material.cutting_coefficients,
                                           held.spindle_rpm[rows], method="sdm")
    rr = np.geomspace(*RPM, 48)
    boundary_truth = true_limits(prob, rr, np.full(rr.size, prob.setup.cut.radial_depth_m), np.ones(rr.size, bool))
    boundary_prior = reference_limits(prob.prior, prob.setup.tool, prob.setup.cut, prob.setup.material.cutting_coefficients,
                                      rr, method="sdm")
    out = {"seed": seed, "u_prior_in_sd": (u / sd).round(2).tolist(), "acc_prior": acc((held.axial_depth_m < prior_lim) * 1.0, truth),
           "boundary_prior_err": float(np.median(np.abs(boundary_prior / boundary_truth - 1))),
           "boundary_prior_within_10": float(np.mean(np.abs(boundary_prior / boundary_truth - 1) < 0.10)),
           "design": design, "labels": labels,
           "label_agreement": float(np.mean((pool.outcome == STABLE) == (pool.axial_depth_m < pool_lim)))}
    if held_rec is not None:
        out["held_record_agreement"] = float(np.mean(held_rec == truth))
    wide = PriorSD(*(prior_scale * getattr(PriorSD(), f) for f in ("frequency", "stiffness", "damping", "coefficients")))

    def fit(train):
        t0 = time.perf_counter()
        return learn(prob.setup, prob.prior, train, seed=seed, likelihood=likelihood, prior_sd=wide), \
            time.perf_counter() - t0

    def evaluate(n, res, t_learn):
        # the posterior, and with an averaged rate of wrong marks also its two components (the
        # rate fixed, the rate learned: an A/B from the same run, through shared tables)
        tags = ("", "fixed_", "learned_") if res.components else ("",)
        posts = (res.posterior,) + tuple(res.components)
        t0 = time.perf_counter()
        p_all, lobes_all = shared_predictions(posts, prob.setup, held, rr)
        t_pred = time.perf_counter() - t0
        for tag, p, lobes in zip(tags, p_all, lobes_all):
            out[f"acc_post_{tag}{n}"] = acc(p, truth)
            if held_rec is not None:
                out[f"acc_post_rec_{tag}{n}"] = acc(p, held_rec)
            out[f"p_held_{tag}{n}"] = p
            # the boundary: the limit's median (the samples with the tables' error); the predictive
            # P(stable) = 50 % contour beside it (it leans towards the mean of a skewed posterior)
            mid = lobes.limit_quantile(0.5)
            err = np.abs(mid / boundary_truth - 1)
            out[f"boundary_median_err_{tag}{n}"] = float(np.median(err))
            out[f"boundary_within_10_{tag}{n}"] = float(np.mean(err < 0.10))
            out[f"boundary_bias_{tag}{n}"] = float(np.median(np.log(mid / boundary_truth)))
            out[f"boundary_p50_err_{tag}{n}"] = float(np.median(np.abs(lobes.quantiles[0.5] / boundary_truth - 1)))
            # is the posterior's own uncertainty honest? the truth inside its 5-95 % band, and the band's width
            # (the band of the limit itself: the samples with the tables' error, not the soft boundary)
            out[f"boundary_band_{tag}{n}"] = float(np.mean((lobes.limit_quantile(0.05) <= boundary_truth) &
                                                           (boundary_truth <= lobes.limit_quantile(0.95))))
            out[f"boundary_sd_{tag}{n}"] = float(np.median(np.std(np.log(lobes.limits), axis=0)))
        if res.model_probability:
            out[f"p_learned_{n}"] = res.model_probability[1]
        out["truth_held"] = truth
        out[f"time_learn_{n}"] = t_learn
        out[f"time_predict_{n}"] = t_pred
        out[f"cause_{n}"] = res.posterior.cause()
        out[f"table_error_{n}"] = float(np.median(res.model_error)) if res.model_error.size else float("nan")
        out[f"loo_{n}"] = (res.accuracy_before, res.accuracy_after)
        out[f"warn_{n}"] = len(res.warnings)
        out[f"warnings_{n}"] = list(res.warnings)
        eps = res.posterior.mislabel_samples
        out[f"mislabel_{n}"] = float(np.median(eps)) if eps.size else likelihood.mislabel
        if n == max(sizes):
            out["post"] = res
        log(f"  seed {seed} n={n}{' ' + design if design else ''}: prior {out['acc_prior']:.2f} "
            f"post {out[f'acc_post_{n}']:.2f} learn {t_learn:.1f}s predict({held.n_cuts}) {t_pred:.1f}s "
            f"cause {out[f'cause_{n}']} boundary err {out[f'boundary_median_err_{n}']:.3f} "
            f"band {out[f'boundary_band_{n}']:.2f} eps {out[f'mislabel_{n}']:.3f}"
            + (f" P(learned) {res.model_probability[1]:.2f} (fixed: err "
               f"{out[f'boundary_median_err_fixed_{n}']:.3f} band {out[f'boundary_band_fixed_{n}']:.2f}; learned: "
               f"err {out[f'boundary_median_err_learned_{n}']:.3f} band {out[f'boundary_band_learned_{n}']:.2f})"
               if res.model_probability else ""))

    if design is None:
        for n in sizes:
            evaluate(n, *fit(subset(pool, n)))
    else:
        train = subset(pool, start)
        label_rng = np.random.default_rng(seed + 20_000)
        while train.n_cuts < max(sizes):
            res, t_learn = fit(train)
            if train.n_cuts in sizes:
                evaluate(train.n_cuts, res, t_learn)
            lobes = probability_lobes(res.posterior, prob.setup, RPM, n_rpm=100)
            k = min(batch, max(sizes) - train.n_cuts)
            new, _, _ = suggest_cuts(lobes, k, criterion=design, likelihood=res.posterior.likelihood)
            new = labelled(new, true_limits(prob, new.spindle_rpm, new.radial_depth_m, new.down), label_rng)
            train = train.concat(new)
        out["designed_cuts"] = train
        evaluate(train.n_cuts, *fit(train))
    for n in base_sizes:
        tr = subset(pool, n)
        out[f"acc_logit_{n}"] = acc(logistic(tr, held, d), truth)
        out[f"acc_knn_{n}"] = acc(knn(tr, held, d), truth)
    return out, prob


# ---------------------------------------------------------------------------- suggest vs grid
def suggest_vs_grid(seed, max_cuts, log):
    rng = np.random.default_rng(seed + 500)
    sd = PriorSD().log_sds()
    prob = tool_problem(u_prior=rng.uniform(-1.5, 1.5, 5) * sd, rpm_range=RPM)
    ae, down = prob.setup.cut.radial_depth_m, prob.setup.cut.milling == "down"
    fine = np.geomspace(*RPM, 160)
    tl = true_limits(prob, fine, np.full(fine.size, ae), np.full(fine.size, down))
    best = float(np.max(tl * fine))

    def truth_stable(rpm, ap):
        return ap < true_limits(prob, np.atleast_1d(rpm), np.full(np.size(rpm), ae), np.full(np.size(rpm), down))

    # grid: k speeds x k depths up to 3x the truth's highest limit (an oracle's scale, generous to
    # the grid), k = 2..8; the best stable MRR it finds as a share of the best
    grid_need, grid_share = np.nan, []
    dmax = 3.0 * float(np.max(tl))
    for k in range(2, 9):
        r, a = np.meshgrid(np.linspace(*RPM, k), np.linspace(dmax / k, dmax, k), indexing="ij")
        st = truth_stable(r.ravel(), a.ravel())
        grid_share.append(float(np.max((r.ravel() * a.ravel())[st], initial=0.0)) / best)
        if grid_share[-1] >= 0.95 and np.isnan(grid_need):
            grid_need = k * k
    log(f"  grid seed {seed}: best stable MRR found / best, k x k cuts for k = 2..8: "
        + " ".join(f"{v:.2f}" for v in grid_share))
    # the best grid shape in hindsight: n_s speeds x n_d depths, the fewest cuts that reach 95 %
    shaped = np.nan
    for n_s in range(2, 33):
        r = np.linspace(*RPM, n_s)
        lim = true_limits(prob, r, np.full(n_s, ae), np.full(n_s, down))
        for n_d in range(1, 64 // n_s + 1):
            a = np.linspace(dmax / n_d, dmax, n_d)
            if np.max((r[:, None] * a[None, :])[a[None, :] < lim[:, None]], initial=0.0) >= 0.95 * best:
                shaped = np.nanmin([shaped, n_s * n_d])
                break
    log(f"  grid seed {seed}: the best n_s x n_d shape in hindsight needs {shaped} cuts")
    # suggest: start from 3 shallow cuts, then one suggested cut at a time
    rpm0 = np.array([8000.0, 14000.0, 20000.0])
    ap0 = np.full(3, 0.3 * float(np.min(tl)))
    cuts = CutTable(rpm0, ap0, np.full(3, ae), np.full(3, down), np.where(truth_stable(rpm0, ap0), 0, 1), np.ones(3),
                    np.full(3, np.nan), np.zeros(3, bool))
    need = np.nan
    for _ in range(max_cuts - 3):
        res = learn(prob.setup, prob.prior, cuts, seed=seed, n_particles=1000)
        lobes = probability_lobes(res.posterior, prob.setup, RPM, n_rpm=100)
        s, _, _ = suggest_cuts(lobes, 1)
        st = truth_stable(s.spindle_rpm, s.axial_depth_m)
        cuts = cuts.concat(replace(s, outcome=np.where(st, 0, 1)))
        found = float(np.max((cuts.spindle_rpm * cuts.axial_depth_m)[cuts.outcome == 0], initial=0.0))
        if found >= 0.95 * best:
            need = cuts.n_cuts
            break
    log(f"  suggest seed {seed}: grid needs {grid_need} cuts, suggest needs {need}")
    return grid_need, need


def speed(repeats, log, likelihood=Likelihood()):
    """Learn 40 cuts and predict 1000 (2 engagements x 50 speeds x 10 depths): median wall time of
    ``repeats`` runs with the tables filled by one process and by the default worker count."""
    rng = np.random.default_rng(99)
    pr = tool_problem(u_prior=rng.uniform(-1.5, 1.5, 5) * PriorSD().log_sds(), rpm_range=RPM)
    c40 = random_cuts(pr, 40, rng)
    c40 = label(c40, true_limits(pr, c40.spindle_rpm, c40.radial_depth_m, c40.down), rng)
    rr, aa, ee = np.meshgrid(np.linspace(*RPM, 50), np.geomspace(5e-4, 2e-2, 10), [0.1, 0.5], indexing="ij")
    m = rr.size
    grid = CutTable(rr.ravel(), aa.ravel(), ee.ravel() * pr.setup.tool.diameter_m, np.ones(m, bool), np.full(m, -1),
                    np.ones(m), np.full(m, np.nan), np.zeros(m, bool))
    saved = os.environ.get("ROBOMILL_WORKERS")
    rows = {}
    try:
        for name, workers in (("1 process", "1"), (f"{default_workers()} processes", None)):
            if workers is None:
                os.environ.pop("ROBOMILL_WORKERS", None)
            else:
                os.environ["ROBOMILL_WORKERS"] = workers
            t_learn, _, res = median_time(lambda: learn(pr.setup, pr.prior, c40, likelihood=likelihood), repeats)
            t_pred, _, _ = median_time(lambda: predict_cuts(res.posterior, pr.setup, grid), repeats)
            rows[name] = (t_learn, t_pred)
    finally:
        if saved is None:
            os.environ.pop("ROBOMILL_WORKERS", None)
        else:
            os.environ["ROBOMILL_WORKERS"] = saved
    log(f"\n## speed (median wall time of {repeats} runs)")
    log("| | learn 40 cuts | predict 1000 cuts |")
    log("|---|---|---|")
    for name, (tl, tp) in rows.items():
        log(f"| {name} | {tl:.1f} s | {tp:.1f} s |")
    (l1, p1), (ln, pn) = rows.values()
    log(f"| speed-up | {l1 / ln:.2f}x | {p1 / pn:.2f}x |")


def summary(rows, sizes, base_sizes, n_held, log):
    """The tables of the README from per-seed rows (of one run, or of several saved runs)."""
    med = lambda k: float(np.median([r[k] for r in rows]))  # noqa: E731
    log("\n## held-out accuracy (median over %d seeds, %d held-out cuts each)" % (len(rows), n_held))
    log("| training cuts | prior (nominal) | posterior | logistic | kNN (k=5) |")
    log("|---|---|---|---|---|")
    for n in base_sizes:
        post = f"{med(f'acc_post_{n}'):.3f}" if n in sizes else "-"
        log(f"| {n} | {med('acc_prior'):.3f} | {post} | {med(f'acc_logit_{n}'):.3f} | {med(f'acc_knn_{n}'):.3f} |")
    for n in sizes:
        share = np.mean([r[f"acc_post_{n}"] >= 0.9 for r in rows])
        worse = sum(r[f"acc_post_{n}"] < r["acc_prior"] for r in rows)
        log(f"posterior, {n} cuts: share of seeds >= 90 %: {share:.2f}; mean {np.mean([r[f'acc_post_{n}'] for r in rows]):.3f}; "
            f"worse than the prior in {worse} of {len(rows)}")
    low = [r for r in rows if r["acc_prior"] < 0.85]
    if low:
        log(f"seeds where the prior is markedly lower (< 0.85): {len(low)}; prior median "
            f"{np.median([r['acc_prior'] for r in low]):.3f}; posterior median "
            + ", ".join(f"{n} cuts {np.median([r[f'acc_post_{n}'] for r in low]):.3f}" for n in sizes)
            + "; logistic " + ", ".join(f"{n} cuts {np.median([r[f'acc_logit_{n}'] for r in low]):.3f}" for n in sizes))
    if rows[0].get("labels") == "records":
        log(f"marks from simulated records: agreement with the SDM truth, median over seeds "
            f"{med('label_agreement'):.3f} (training pool), {med('held_record_agreement'):.3f} (held-out cuts); "
            "posterior accuracy against the held-out cuts' own record marks: "
            + ", ".join(f"{n} cuts {med(f'acc_post_rec_{n}'):.3f}" for n in sizes))
    for name in ("logit", "knn"):
        need = [n for n in base_sizes if med(f"acc_{name}_{n}") >= 0.9]
        log(f"{name}: cuts needed for a median of 90 %: {need[0] if need else '> %d' % max(base_sizes)}")
    need = [n for n in sizes if med(f"acc_post_{n}") >= 0.9]
    log(f"posterior: cuts needed for a median of 90 %: {need[0] if need else '> %d' % max(sizes)}")
    log("\n## 50 % boundary vs the true (converged SDM) limit, production cut 0.5 D down")
    log(f"prior (nominal model): median relative error {med('boundary_prior_err'):.3f}; median share of speeds within "
        f"10 %: {med('boundary_prior_within_10'):.2f}")
    for n in sizes:
        if f"boundary_median_err_{n}" in rows[0]:
            log(f"{n} cuts: median relative error {med(f'boundary_median_err_{n}'):.3f}; median share of speeds within "
                f"10 %: {med(f'boundary_within_10_{n}'):.2f}")
        if f"boundary_p50_err_{n}" in rows[0]:
            log(f"{n} cuts: the predictive P(stable) = 50 % contour instead: median relative error "
                f"{med(f'boundary_p50_err_{n}'):.3f} (fixed rate: "
                f"{med(f'boundary_p50_err_fixed_{n}') if f'boundary_p50_err_fixed_{n}' in rows[0] else float('nan'):.3f})")
        if f"boundary_bias_{n}" in rows[0]:
            log(f"{n} cuts: median over seeds of the median log(boundary / truth) {med(f'boundary_bias_{n}'):+.3f} "
                "(> 0: the posterior's boundary above the truth)")
        if f"boundary_band_{n}" in rows[0]:
            log(f"{n} cuts: the posterior's own log-limit sd (median over speeds and seeds) {med(f'boundary_sd_{n}'):.3f}; "
                f"truth inside the 5-95 % band at {np.mean([r[f'boundary_band_{n}'] for r in rows]):.2f} of the speeds "
                f"(mean over seeds; 0.90 if the band is honest)")
    for n in sizes:
        if f"p_held_{n}" not in rows[0]:
            continue
        p = np.concatenate([r[f"p_held_{n}"] for r in rows])
        t = np.concatenate([r["truth_held"] for r in rows])
        log(f"\n## reliability, {n} cuts (held-out cuts pooled over seeds)")
        log("| P(stable) bin | cuts | mean P | share stable |")
        log("|---|---|---|---|")
        edges = np.array([0, 0.05, 0.2, 0.4, 0.6, 0.8, 0.95, 1.0001])
        for lo, hi in zip(edges[:-1], edges[1:]):
            sel = (p >= lo) & (p < hi)
            if sel.any():
                log(f"| {lo:.2f}-{min(hi, 1):.2f} | {sel.sum()} | {p[sel].mean():.3f} | {t[sel].mean():.3f} |")
    for n in sizes:
        if f"acc_post_fixed_{n}" not in rows[0]:
            continue
        p_l = [r[f"p_learned_{n}"] for r in rows]
        log(f"\n## the rate of wrong marks, {n} cuts: averaged by the evidence against fixed and learned (same runs)")
        log(f"P(learned) over seeds: median {np.median(p_l):.2f}, quartiles {np.quantile(p_l, 0.25):.2f}-"
            f"{np.quantile(p_l, 0.75):.2f}, above 0.5 in {sum(x > 0.5 for x in p_l)} of {len(p_l)}")
        log("| rate of wrong marks | accuracy median (markedly-lower seeds) | boundary median error | speeds within 10 % | "
            "truth inside 5-95 % band | log-limit sd | P 0.6-0.8: share stable | P 0.8-0.95: share stable |")
        log("|---|---|---|---|---|---|---|---|")
        t = np.concatenate([r["truth_held"] for r in rows])
        for tag, name in (("", "averaged"), ("fixed_", "fixed 5 %"), ("learned_", "learned")):
            p = np.concatenate([r[f"p_held_{tag}{n}"] for r in rows])
            rel = [t[(p >= lo) & (p < hi)].mean() if np.any((p >= lo) & (p < hi)) else float("nan")
                   for lo, hi in ((0.6, 0.8), (0.8, 0.95))]
            low_acc = np.median([r[f"acc_post_{tag}{n}"] for r in low]) if low else float("nan")
            log(f"| {name} | {med(f'acc_post_{tag}{n}'):.3f} ({low_acc:.3f}) | {med(f'boundary_median_err_{tag}{n}'):.3f} | "
                f"{med(f'boundary_within_10_{tag}{n}'):.2f} | {np.mean([r[f'boundary_band_{tag}{n}'] for r in rows]):.2f} | "
                f"{med(f'boundary_sd_{tag}{n}'):.3f} | {rel[0]:.2f} | {rel[1]:.2f} |")
    for n in sizes:
        log(f"learn {n} cuts: median {med(f'time_learn_{n}'):.1f} s (max {max(r[f'time_learn_{n}'] for r in rows):.1f}); "
            f"predict {n_held} held-out cuts median {med(f'time_predict_{n}'):.1f} s")
        if f"table_error_{n}" in rows[0]:
            log(f"table vs direct limits at posterior samples ({n} cuts): median over seeds of the cuts' median RMS log "
                f"error {med(f'table_error_{n}'):.3f}")
        if f"mislabel_{n}" in rows[0]:
            log(f"learned mislabel rate ({n} cuts): median over seeds {med(f'mislabel_{n}'):.3f}")
        causes = [r[f"cause_{n}"] for r in rows]
        log(f"causes named ({n} cuts): " + ", ".join(f"{c}: {causes.count(c)}" for c in sorted(set(causes))))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="0: only the --suggest comparison")
    ap.add_argument("--seed-list", type=int, nargs="+", default=None,
                    help="these seeds instead of 0..seeds-1 (split a run over processes)")
    ap.add_argument("--quick", action="store_true", help="3 seeds, 20 cuts, 1 suggest seed")
    ap.add_argument("--sizes", type=int, nargs="+", default=[15, 30])
    ap.add_argument("--held", type=int, default=60)
    ap.add_argument("--flip", type=float, default=0.05, help="share of the training marks flipped")
    ap.add_argument("--prior-scale", type=float, default=1.0,
                    help="the learner's prior sds this many times the ones the truth is drawn from (wide priors)")
    ap.add_argument("--mislabel-model", choices=["fixed", "learned", "average"], default="average",
                    help="the rate of wrong marks fixed at 5 %%, learned, or both averaged by their evidence (the CLI default; then "
                         "the fixed and the learned posteriors are reported too, from the same run)")
    ap.add_argument("--mislabel-sd", type=float, default=LEARNED_MISLABEL_SD,
                    help="prior log-odds sd of a learned rate (--mislabel-model learned or average)")
    ap.add_argument("--design", choices=["boundary", "mrr"], default=None,
                    help="training cuts: --start random ones, then rounds of --batch suggested by this criterion")
    ap.add_argument("--start", type=int, default=10, help="random cuts before the first suggestion (--design)")
    ap.add_argument("--batch", type=int, default=5, help="cuts suggested per round (--design)")
    ap.add_argument("--labels", choices=["sdm", "records"], default="sdm",
                    help="training marks from the converged SDM with --flip flipped, or from simulated records "
                         "judged by the chatter detection (its confidence the weight)")
    ap.add_argument("--detection-lag", type=float, default=DETECTION_LAG,
                    help="log-depth lag of the detected outcomes' boundary (--labels records; 0 with "
                         "--detection-scale 0.03: read as marks, the model before session 9)")
    ap.add_argument("--detection-scale", type=float, default=DETECTION_SCALE,
                    help="width of the detected outcomes' boundary")
    ap.add_argument("--suggest-seeds", type=int, default=4)
    ap.add_argument("--suggest-max-cuts", type=int, default=18)
    ap.add_argument("--suggest-first", type=int, default=0, help="first suggest seed (split a run over processes)")
    ap.add_argument("--no-speed", action="store_true", help="skip the speed runs (learn 40 cuts, predict 1000)")
    ap.add_argument("--speed", action="store_true", help="the speed runs (also with --seeds 0)")
    ap.add_argument("--speed-repeats", type=int, default=3)
    ap.add_argument("--save", default=None, help="pickle the per-seed rows here (to --combine runs of other processes)")
    ap.add_argument("--combine", nargs="+", default=None, help="only print the summary of these saved runs")
    ap.add_argument("--budget-s", type=float, default=np.inf,
                    help="start no new seed after this many seconds (the summary covers the seeds done)")
    args = ap.parse_args(argv)
    if args.quick:
        args.seeds, args.sizes, args.held, args.suggest_seeds = 3, [20], 30, 1
    base_sizes = sorted(set(args.sizes) | {10, 20, 30, 60, 120})
    log = lambda s: print(s, flush=True)  # noqa: E731
    if args.combine:
        rows = [r for f in args.combine for r in pickle.load(open(f, "rb"))]
        summary(sorted(rows, key=lambda r: r["seed"]), args.sizes, base_sizes, args.held, log)
        return
    likelihood = Likelihood(mislabel_sd=0.0 if args.mislabel_model == "fixed" else args.mislabel_sd,
                            mislabel_average=args.mislabel_model == "average",
                            detection_lag=args.detection_lag, detection_scale=args.detection_scale)
    rows = []
    t_all = time.perf_counter()
    for seed in (args.seed_list if args.seed_list else range(args.seeds)):
        if time.perf_counter() - t_all > args.budget_s:
            log(f"budget reached: {len(rows)} seeds done")
            break
        r, last_prob = run_seed(seed, args.sizes, base_sizes, args.held, log, flip=args.flip,
                                likelihood=likelihood,
                                prior_scale=args.prior_scale,
                                design=args.design, start=args.start, batch=args.batch, labels=args.labels)
        rows.append(r)
        if args.save:
            with open(args.save, "wb") as fh:
                pickle.dump([{k: v for k, v in x.items() if k != "post"} for x in rows], fh)
    if rows:
        summary(rows, args.sizes, base_sizes, args.held, log)
    if args.speed or (rows and not args.no_speed):
        speed(args.speed_repeats, log, likelihood)
    if args.suggest_seeds:
        log("\n## --suggest vs a grid of test cuts (cuts to a stable cut within 5 % of the best stable MRR)")
        log("| seed | grid | suggest |")
        log("|---|---|---|")
        for s in range(args.suggest_first, args.suggest_first + args.suggest_seeds):
            g, q = suggest_vs_grid(s, args.suggest_max_cuts, log)
            log(f"| {s} | {g} | {q} |")
    log(f"\ntotal {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
