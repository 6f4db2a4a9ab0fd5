"""Benchmark of the stability lobes (robomill issue 4, item 6).

Run from the repository root::

    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_lobes.py          # full (about 1-2 minutes)
    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_lobes.py --quick  # fewer repeats
    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_lobes.py --only zoa  # the ZOA cases (1, 1b)

Cases

1. ZOA: a 2x2 structure (5 oblique modes in the feed-normal plane, 180-1400 Hz), 10^4 chatter
   frequencies, every lobe reaching 2000-20000 rpm, envelope on 2000 speeds plus the exact cusps.
1b. ZOA on the example cell (examples/kr500_acetal: planning model and setup) with its 720/735 Hz
   tool modes at 0.5 % damping, where lobes start inside a grid interval: ``predict_point`` at
   22 195 rpm and the lobe diagram on 1000 speeds over 500-24 000 rpm (default 10^4 lines), and
   the diagram's largest deviation from the same ZOA on 2 x 10^5 lines (before the 2026-11-26 fix:
   up to 7.9x).
2. SDM: the Insperger-Stepan / Ding 1-DOF benchmark (fn 922 Hz, zeta 0.011, 2 teeth), slotting and
   a/D = 0.05, 200 speeds over 5000-25000 rpm, step count chosen for rtol = 1 % by the convergence
   rule (included in the time).
3. SDM against a straightforward dense-matrix SDM (the published scripts' way: one matrix
   exponential per step, one dense N x N step matrix per step multiplied together, all
   eigenvalues by LAPACK) with the same discretisation, step counts, bracketing root search and
   guesses, in the same run: measured at four speeds of case 2; for the whole 200-speed diagram
   its time is estimated as (evaluations per speed, the same for both) x (its measured time per
   evaluation at each step count), as running it takes minutes.

Times are medians of repeated runs. BLAS is pinned to one thread (set before numpy is imported)
so that the shared 2-core machine gives reproducible numbers; both methods run under it.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from oma.cutting import Cut, CuttingCoefficients, Tool  # noqa: E402
from oma.modal import ModalModel  # noqa: E402
from stability import zoa  # noqa: E402
from stability.lobes import lobe_diagram  # noqa: E402
from stability.sdm import SDMProblem, dense_monodromy, steps_per_period  # noqa: E402


class DenseSDM(SDMProblem):
    """The same discretisation computed the straightforward way, as the published scripts do:
    per step, the matrix exponential of that step (``scipy.linalg.expm``), then one dense N x N
    step matrix per step multiplied together, and all eigenvalues of the product (LAPACK); one
    speed and one depth at a time."""

    def straightforward_maps(self, rpm, depth, steps):
        n, d, m = self.n, self.d, int(steps)
        dt = float(self.tooth_period_s(rpm)) / m
        e = self._engagement(m, np.array([float(depth)]))[0]
        phi, gd, lam = np.zeros((m, 2 * n, 2 * n)), np.zeros((m, 2 * n, d)), np.zeros((m, 2 * n, d))
        for i in range(m):
            kk = self.minv_u3t @ np.einsum("ijk,k->ij", self._dyn, e[i]) / self.w_ref
            aug = np.zeros((2 * n + 2 * d, 2 * n + 2 * d))
            aug[: 2 * n, : 2 * n] = self.a0
            aug[n : 2 * n, :n] += kk @ self.u
            aug[n : 2 * n, 2 * n : 2 * n + d] = -kk @ self.l_mat
            aug[2 * n : 2 * n + d, 2 * n + d :] = np.eye(d) / dt
            ex = scipy.linalg.expm(aug * dt)
            phi[i], lam[i] = ex[: 2 * n, : 2 * n], ex[: 2 * n, 2 * n + d :]
            gd[i] = ex[: 2 * n, 2 * n : 2 * n + d] - lam[i]
        return phi, gd, lam

    def _radii(self, rpm, depth, steps):
        mus = []
        for r, a in zip(np.atleast_1d(rpm), np.atleast_1d(depth)):
            mono = dense_monodromy(self, r, a, steps, maps=self.straightforward_maps(r, a, steps))
            mu = scipy.linalg.eigvals(mono, overwrite_a=True, check_finite=False)
            mus.append(mu[np.argmax(np.abs(mu))])
        mus = np.array(mus)
        return np.abs(mus), mus


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def zoa_case(repeats):
    fn = np.array([180.0, 420.0, 650.0, 980.0, 1400.0])
    ang = np.radians([10.0, 60.0, 100.0, 145.0, 30.0])
    model = ModalModel(fn, [0.04, 0.03, 0.02, 0.025, 0.015], [2e7, 3e7, 4e7, 5e7, 8e7],
                       np.column_stack([np.cos(ang), np.sin(ang), np.zeros(5)]))
    tool = Tool(3, 0.016)
    cut = Cut(1e-4, 0.008, "down", [1, 0, 0], [0, 1, 0])
    coef = CuttingCoefficients(7e8, 2.1e8)
    rpm = np.linspace(2000, 20000, 2000)
    freq = zoa.default_chatter_frequencies(model, n_freq=10_000)

    def run():
        curves = zoa.limit_curves(model, tool, cut, coef, freq)
        return curves, zoa.envelope(model, tool, cut, coef, rpm, curves=curves)

    t, (curves, env) = timed(run, repeats)
    k_lo, k_hi = zoa._lobe_range(curves, rpm[0], rpm[-1])
    t_curves, _ = timed(lambda: zoa.limit_curves(model, tool, cut, coef, freq), repeats)
    return {
        "name": "ZOA 2x2, 5 modes, 1e4 chatter freq., 2000 rpm points",
        "median_s": t, "runs": repeats,
        "detail": (f"lobes k={k_lo}..{k_hi} x 2 branches, {int(env.is_intersection.sum())} exact cusps, "
                   f"curves alone {t_curves * 1e3:.1f} ms, min depth {env.depth_limit_m.min() * 1e3:.4f} mm"),
    }


def zoa_light_case(repeats):
    from oma.modal_io import read_modal_model
    from stability.lobes import predict_point
    from stability.setup_io import read_setup

    example = Path(__file__).resolve().parents[1] / "examples" / "kr500_acetal"
    base = read_modal_model(example / "models" / "planning_model.yaml")
    zeta = np.where(np.isin(base.natural_frequency_hz, [720.0, 735.0]), 0.005, base.damping_ratio)
    model = ModalModel(base.natural_frequency_hz, zeta, base.stiffness_N_m, base.directions,
                       base.residual_compliance_m_N)
    setup = read_setup(example / "setup.yaml")
    args = (model, setup.tool, setup.cut, setup.material.cutting_coefficients)
    t_point, _ = timed(lambda: predict_point(*args, spindle_rpm=22195.0, axial_depth_m=0.005), repeats)
    t, diagram = timed(lambda: lobe_diagram(*args, rpm_range=(500.0, 24000.0), n_rpm=1000), repeats)
    grid = ~diagram.is_intersection
    fn = model.natural_frequency_hz
    fine = zoa.envelope(*args, diagram.rpm[grid], freq_hz=np.geomspace(fn.min() / 3, fn.max() * 3, 200_000))
    dev = np.max(np.abs(diagram.depth_limit_m[grid] / fine.depth_limit_m[~fine.is_intersection] - 1))
    return {
        "name": "ZOA example cell, tool modes at 0.5 % damping, 1000 rpm",
        "median_s": t, "runs": repeats,
        "detail": (f"predict_point {t_point * 1e3:.1f} ms; diagram vs 2e5 lines: max |rel| {dev:.1e}, "
                   f"min depth {diagram.min_depth_limit_m * 1e3:.4f} mm"),
    }


BENCH = ModalModel([922.0], [0.011], [0.03993 * (2 * np.pi * 922.0) ** 2], [[1, 0, 0]])
TOOL = Tool(2, 0.01)
COEF = CuttingCoefficients(6e8, 2e8)


def sdm_case(ratio, repeats):
    cut = Cut(1e-4, ratio * 0.01, "down", [1, 0, 0], [0, 1, 0])
    SDMProblem(BENCH, TOOL, cut, COEF).spectral_radius(10000, 1e-4, 16)  # warm-up: load numba's cache
    t, d = timed(lambda: lobe_diagram(BENCH, TOOL, cut, COEF, rpm_range=(5000, 25000), n_rpm=200,
                                      method="sdm", rtol=0.01), repeats)
    res = d.resolution
    kinds = {k: int(np.sum(d.kind == k)) for k in ("hopf", "flip", "fold")}
    return cut, d, {
        "diagram": d,
        "name": f"SDM 1-DOF benchmark a/D={ratio:g}, 200 speeds, rtol 1 %",
        "median_s": t, "runs": repeats,
        "detail": (f"{res.steps_per_mode_period:g} steps/mode period, >= {res.min_steps} per tooth period "
                   f"(m = {d.steps.min()}..{d.steps.max()}), convergence {['%.3g' % h[2] for h in res.history]}, "
                   f"boundaries {kinds}, min depth {d.min_depth_limit_m * 1e3:.4f} mm"),
    }


def diagram_guess(cut, diagram):
    env = zoa.envelope(BENCH, TOOL, cut, COEF, diagram.rpm, n_freq=2000)
    return np.asarray(env.depth_limit_m)[~env.is_intersection]


def dense_comparison(cut, diagram, speeds, repeats):
    """Limit search at a few speeds by both methods (same steps, guesses, search); and the dense
    cost of one spectral radius at every step count of the diagram, to estimate its diagram time
    (the same search needs the same number of evaluations per speed)."""
    fast = SDMProblem(BENCH, TOOL, cut, COEF)
    dense = DenseSDM(BENCH, TOOL, cut, COEF)
    res = diagram.resolution
    env = zoa.envelope(BENCH, TOOL, cut, COEF, speeds, n_freq=2000)
    guess = np.asarray(env.depth_limit_m)[~env.is_intersection]
    m = steps_per_period(fast, speeds, steps_per_mode_period=res.steps_per_mode_period, min_steps=res.min_steps)
    kw = dict(guess_m=guess, depth_rtol=1e-3, chatter_frequency=False)
    t_fast, lim_fast = timed(lambda: fast.limits(speeds, m, **kw), repeats)
    t_dense, lim_dense = timed(lambda: dense.limits(speeds, m, **kw), 1)
    per_eval = {}
    for steps in np.unique(diagram.steps):
        i = int(np.flatnonzero(diagram.steps == steps)[0])
        depth = diagram.depth_limit_m[i] if np.isfinite(diagram.depth_limit_m[i]) else 1e-3
        per_eval[int(steps)], _ = timed(lambda: dense._radii([diagram.rpm[i]], [depth], int(steps)), 1)
    return t_fast, t_dense, lim_fast, lim_dense, m, per_eval


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    parser.add_argument("--only", choices=["zoa"], default=None, help="only the ZOA cases")
    args = parser.parse_args(argv)
    rep_zoa, rep_sdm, rep_cmp = (3, 1, 3) if args.quick else (7, 5, 5)
    print(f"BLAS threads: {os.environ.get('OPENBLAS_NUM_THREADS')}; medians of repeated runs\n")
    rows = [zoa_case(rep_zoa), zoa_light_case(rep_zoa)]
    if args.only == "zoa":
        print(f"{'case':58s} {'runs':>4s} {'median':>10s}")
        for r in rows:
            print(f"{r['name']:58s} {r['runs']:4d} {r['median_s']:9.3f}s")
            print(f"    {r['detail']}")
        return 0
    cut_slot, slot, row = sdm_case(1.0, rep_sdm)
    rows.append(row)
    cut_low, low, row = sdm_case(0.05, rep_sdm)
    rows.append(row)
    print(f"{'case':58s} {'runs':>4s} {'median':>10s}")
    for r in rows:
        print(f"{r['name']:58s} {r['runs']:4d} {r['median_s']:9.3f}s")
        print(f"    {r['detail']}")
    print("\nSDM against the straightforward dense-matrix SDM (same steps per speed, same search)")
    print(f"{'case':10s} {'speeds':>22s} {'fast':>9s} {'dense':>9s} {'ratio':>6s}   limits (mm) fast / dense")
    for name, cut, diagram in (("slot", cut_slot, slot), ("a/D=0.05", cut_low, low)):
        speeds = np.array([6000.0, 10000.0, 16000.0, 24000.0])
        t_fast, t_dense, lf, ld, m, per_eval = dense_comparison(cut, diagram, speeds, rep_cmp)
        for a, b in zip(lf, ld):
            assert abs(a.depth_limit_m / b.depth_limit_m - 1) < 2e-3, "fast and dense SDM disagree"
        print(f"{name:10s} {'/'.join(f'{x:.0f}' for x in speeds):>22s} {t_fast:8.3f}s {t_dense:8.2f}s "
              f"{t_dense / t_fast:5.0f}x   " + ", ".join(f"{a.depth_limit_m * 1e3:.4f}/{b.depth_limit_m * 1e3:.4f}"
                                                    for a, b in zip(lf, ld)))
        print(f"{'':10s} steps {[int(x) for x in m]}, evaluations {[x.evaluations for x in lf]} fast, "
              f"{[x.evaluations for x in ld]} dense")
        # whole diagram: dense time per spectral radius at each step count x evaluations per speed
        evals = np.array([x.evaluations for x in SDMProblem(BENCH, TOOL, cut, COEF).limits(
            diagram.rpm, diagram.steps, guess_m=diagram_guess(cut, diagram), depth_rtol=1e-3,
            chatter_frequency=False)])
        est = float(sum(e * per_eval[int(s_)] for e, s_ in zip(evals, diagram.steps)))
        t_diag = next(r["median_s"] for r in rows if r.get("diagram") is diagram)
        print(f"{'':10s} whole 200-speed diagram: fast {t_diag:.2f}s (measured, incl. step-count choice), "
              f"dense ~{est:.0f}s (estimated: {evals.sum()} evaluations x dense time per evaluation at "
              f"each step count, {min(per_eval.values()) * 1e3:.0f}-{max(per_eval.values()) * 1e3:.0f} ms) "
              f"-> ~{est / t_diag:.0f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
