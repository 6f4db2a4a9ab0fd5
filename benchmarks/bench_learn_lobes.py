"""Benchmark of the probability lobes of a posterior (``lobes --model``, ``learn --plot``,
``learn --suggest-for boundary``): the fast path against the old one, measured in the same run.

Old: the limit table over the posterior's whole box (every lattice point of the speeds x every
damping and ``Krc/Ktc`` node), each SDM multiplier from the formed monodromy
(``stability.sdm.MATRIX_FREE_MIN_SIZE`` set to infinity), searches from 1 mm. New:
:func:`planner.learn.predictive.probability_lobes` as shipped (the multipliers matrix-free, only
the table entries the samples read, and since the table check its direct solves of 8 samples at
12 speeds, which the old path did not have). Both fill the table with the default worker count.

Cases:

* ``example``: the kr500 example (``examples/kr500_acetal``: the setup and its tool-mode prior,
  720/735 Hz at 2 %), the posterior ``robomill learn`` writes from the 12 test cuts of the
  session-14 audit (``examples/kr500_acetal/cuts.csv``: 6-18 krpm, 6 mm down milling), lobes
  over the setup's 500-24 000 rpm;
* ``synthetic``: ``bench_learn``'s one-mode tool (``planner.learn.synthetic.tool_problem``, the
  prior off by U(-1.5, 1.5) prior sds), 20 random cuts labelled by the converged SDM with 5 %
  flipped, ``learn()``; lobes at the production engagement over 1 500-24 000 rpm (low speeds
  included: there the old path spent its time).

Reported per case: the wall time (median of the runs) and CPU time (this process and its
workers) of the old and the new path and their ratio, the table entries each solved, and the
new 5/50/95 % depths against the old ones (largest and RMS difference in log) next to the
posterior's ``model_error`` (the forward model's error ``learn`` measured at its training cuts,
which the lobes carry).

Run: ``MPLBACKEND=Agg .venv/bin/python benchmarks/bench_learn_lobes.py`` (9 min on the 2 shared
cores at a load of ~1, of which the old path on the example 4.5 min; 9-12 min of it under a load
of 4); ``--quick``: the synthetic seeds 0 and 1, one run each (3 min).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from planner.learn import tables  # noqa: E402
from planner.learn.posterior import PriorSD  # noqa: E402
from planner.learn.predictive import lobes_from_table, predictive_grid, probability_lobes  # noqa: E402
from planner.learn.synthetic import label, random_cuts, tool_problem, true_limits  # noqa: E402
from stability import sdm  # noqa: E402
from _timing import median_time  # noqa: E402

EXAMPLE = ROOT / "examples" / "kr500_acetal"


@contextmanager
def dense_multipliers():
    """The old solver: every multiplier from the formed monodromy (``SDMProblem``'s own path)."""
    saved = sdm.MATRIX_FREE_MIN_SIZE
    sdm.MATRIX_FREE_MIN_SIZE = np.inf
    try:
        yield
    finally:
        sdm.MATRIX_FREE_MIN_SIZE = saved


def old_lobes(post, setup, rpm_range, n_rpm=150, max_samples=400):
    """``probability_lobes`` as it was: the whole table of the posterior's box, dense multipliers."""
    with dense_multipliers():
        rpm = np.geomspace(*rpm_range, n_rpm)
        p = post.thinned(max_samples)
        ae, mill = setup.cut.radial_depth_m, setup.cut.milling
        table = tables.build_table(p.reference, setup.tool, setup.cut, p.coefficients, rpm, np.full(n_rpm, ae),
                                   np.full(n_rpm, mill == "down"), predictive_grid(p), method=p.method, desc=None)
        return lobes_from_table(p, table, rpm, radial_depth_m=ae, milling=mill), table


def new_lobes(post, setup, rpm_range):
    """``probability_lobes`` as shipped, and its table (caught on the way)."""
    seen = {}
    build = tables.build_table

    def spy(*a, **k):
        seen["table"] = build(*a, **k)
        return seen["table"]

    import planner.learn.predictive as predictive

    predictive.build_table = spy
    try:
        return probability_lobes(post, setup, rpm_range), seen["table"]
    finally:
        predictive.build_table = build


def example_case(log):
    import contextlib
    import io

    from planner.cli import main
    from planner.learn.posterior_io import read_posterior
    from stability.setup_io import read_setup

    with tempfile.TemporaryDirectory() as d:
        cuts = EXAMPLE / "cuts.csv"
        post_path = Path(d) / "post.yaml"
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):  # its JSON report
            code = main(["learn", str(EXAMPLE / "setup.yaml"), "--model", str(EXAMPLE / "models" / "tool_mode.yaml"),
                         "--cuts", str(cuts), "-o", str(post_path), "--json"])
        log(f"(example: learn {time.perf_counter() - t0:.0f} s, exit {code})", err=True)
        post = read_posterior(post_path)
    setup = read_setup(EXAMPLE / "setup.yaml")
    return "kr500 example, 12 cuts", post, setup, tuple(float(v) for v in setup.limits.spindle_rpm)


def synthetic_case(seed: int, log):
    from planner.learn.update import learn

    rng = np.random.default_rng(seed)
    pr = tool_problem(u_prior=rng.uniform(-1.5, 1.5, 5) * PriorSD().log_sds(), rpm_range=(6000.0, 24000.0))
    cuts = random_cuts(pr, 20, rng)
    cuts = label(cuts, true_limits(pr, cuts.spindle_rpm, cuts.radial_depth_m, cuts.down), rng)
    res = learn(pr.setup, pr.prior, cuts, seed=seed)
    return f"synthetic seed {seed}, 20 cuts", res.posterior, pr.setup, (1500.0, 24000.0)


def compare(name, post, setup, rpm_range, repeats, old_repeats, log):
    t_old, c_old, (old, t_o) = median_time(lambda: old_lobes(post, setup, rpm_range), old_repeats, children=True)
    t_new, c_new, (new, t_n) = median_time(lambda: new_lobes(post, setup, rpm_range), repeats, children=True)
    solved_old = sum(int(np.isfinite(v).sum()) for v in t_o.values)
    solved_new = sum(int(np.isfinite(v).sum()) for v in t_n.values)
    d = np.concatenate([np.log(new.quantiles[p] / old.quantiles[p]) for p in old.levels])
    lim = np.log(new.limits / old.limits)
    row = dict(name=name, rpm=rpm_range, t_old=t_old, t_new=t_new, c_old=c_old, c_new=c_new,
               solved_old=solved_old, solved_new=solved_new, q_max=float(np.max(np.abs(d))),
               q_rms=float(np.sqrt(np.mean(d ** 2))), lim_max=float(np.max(np.abs(lim))),
               model_error=float(post.likelihood.model_error), runs=(old_repeats, repeats))
    log(f"(done: {name}: old {t_old:.1f} s, new {t_new:.1f} s)", err=True)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", choices=["example", "synthetic"], default=["example", "synthetic"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="synthetic cases' seeds")
    ap.add_argument("--repeats", type=int, default=3, help="runs of the new path (median)")
    ap.add_argument("--old-repeats", type=int, default=1, help="runs of the old path (5-12 min each on the example)")
    ap.add_argument("--quick", action="store_true", help="synthetic seeds 0 and 1, one run each")
    args = ap.parse_args(argv)
    if args.quick:
        args.cases, args.seeds, args.repeats, args.old_repeats = ["synthetic"], [0, 1], 1, 1

    def log(s, err=False):
        print(s, file=sys.stderr if err else sys.stdout, flush=True)

    from planner.workers import default_workers

    rows = []
    t_all = time.perf_counter()
    if "example" in args.cases:
        rows.append(compare(*example_case(log), args.repeats, args.old_repeats, log))
    if "synthetic" in args.cases:
        for s in args.seeds:
            rows.append(compare(*synthetic_case(s, log), args.repeats, args.old_repeats, log))
    log(f"\n## probability lobes (150 speeds, 400 samples): old vs new, {default_workers()} worker(s); "
        f"wall: median of the runs (old, new), CPU: this process and its workers")
    log("| case | speeds (rpm) | old wall | new wall | ratio | old CPU | new CPU | ratio | table entries old / new "
        "| 5/50/95 % depths new vs old: max, RMS \\|d log\\| | sample limits: max \\|d log\\| | model_error |")
    log("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        log(f"| {r['name']} | {r['rpm'][0]:.0f}-{r['rpm'][1]:.0f} | {r['t_old']:.1f} s ({r['runs'][0]}) | "
            f"{r['t_new']:.1f} s ({r['runs'][1]}) | {r['t_old'] / r['t_new']:.1f}x | {r['c_old']:.0f} s | "
            f"{r['c_new']:.0f} s | {r['c_old'] / r['c_new']:.1f}x | {r['solved_old']} / {r['solved_new']} | "
            f"{r['q_max']:.1e}, {r['q_rms']:.1e} | {r['lim_max']:.1e} | {r['model_error']:.3f} |")
    log(f"\ntotal {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
