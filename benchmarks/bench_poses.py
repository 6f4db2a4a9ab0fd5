"""Speed and accuracy of pose-dependent dynamics (planner/poses.py).

Run: ``.venv/bin/python benchmarks/bench_poses.py [--quick]``

Prints four tables:

1. Speed: time to evaluate 100 000 toolpath poses (median of repeats) with
   :meth:`PoseModels.evaluate`, for the bundled example's toolpath (240 points through its six
   poses, the last ones beyond them) with every point repeated 417 times, for 100 000 distinct poses in a 1-D span, and for
   100 000 distinct poses in a 2-D span with ~10 % of them outside (the slow path: a non-negative
   least squares per outside pose); against a naive loop that evaluates one pose at a time
   (timed on a subset, scaled to 100 000), and a loop over the cached :meth:`PoseModels.at`.
2. Accuracy against a known pose law (the 3-joint arm of tests/test_poses.py: Cartesian stiffness
   ``J^-T K_theta J^-1`` of the KR500 joint stiffness, 300 kg tip mass): largest relative error of
   frequency, damping, stiffness and ``1 - MAC`` between poses, against the number of poses along
   a line and on a square grid, for the cubic, thin-plate-spline and linear kernels.
3. Leave-one-pose-out on the bundled example (examples/kr500_acetal/poses).
4. Leave-one-pose-out on real data: the five-pose table of a surgical robot (Sci. Rep. 14, 2024),
   positions placed at joint 1 = 0, 10, ..., 40 deg (the paper gives no joint angles).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _timing import median_time  # noqa: E402
from oma.modal_io import read_modal_model  # noqa: E402
from planner.poses import PoseModels  # noqa: E402
from planner.toolpath_io import read_toolpath  # noqa: E402
from test_poses import Q_A, TABLE, law_model, line, read_table, tip_modes  # noqa: E402

N_POINTS = 100_000
EXAMPLE = ROOT / "examples" / "kr500_acetal"


def example_models():
    return [read_modal_model(p) for p in sorted((EXAMPLE / "poses").glob("pose_*.yaml"))]


def speed(repeats: int, naive_points: int) -> None:
    rng = np.random.default_rng(1)
    pm1 = PoseModels.fit(example_models())
    knots = pm1.joints_deg
    seg = np.linspace(0, 1, len(knots))
    path = read_toolpath(EXAMPLE / "toolpath.yaml").joints_deg  # 240 points, 23 beyond the poses
    repeated = np.repeat(path, -(-N_POINTS // len(path)), axis=0)[:N_POINTS]
    dense_s = rng.uniform(-0.05, 1.05, N_POINTS)
    distinct = np.column_stack([np.interp(dense_s, seg, knots[:, j]) for j in range(knots.shape[1])])
    distinct += rng.normal(scale=0.2, size=distinct.shape)

    g = np.linspace(0, 1, 4)
    grid = np.array([Q_A + np.array([a * 35.0, 0, b * 25.0, 0, 0, 0]) for a in g for b in g])
    pm2 = PoseModels.fit([law_model(q) for q in grid])
    ab = rng.uniform(-0.05, 1.05, size=(N_POINTS, 2))
    plane = Q_A + np.column_stack([35 * ab[:, 0], np.zeros(N_POINTS), 25 * ab[:, 1], np.zeros((N_POINTS, 3))])

    print(f"\n1. Speed: {N_POINTS} poses, median of {repeats} (naive loop: {naive_points} poses, scaled)")
    print(f"{'case':46s} {'unique':>7s} {'out':>6s} {'evaluate [s]':>13s} {'naive [s]':>10s} {'ratio':>7s}"
          f" {'at() loop [s]':>14s}")
    for name, pm, q in (("example 6 poses, 1-D, example path x 417", pm1, repeated),
                        ("example 6 poses, 1-D, distinct poses", pm1, distinct),
                        ("law 4x4 grid, 2-D, distinct poses", pm2, plane)):
        pm.evaluate(q[:10])  # warm-up
        t_vec = median_time(lambda: pm.evaluate(q), repeats)[0]
        ev = pm.evaluate(q)
        sub = q[:: max(1, len(q) // naive_points)][:naive_points]
        t0 = time.perf_counter()
        for row in sub:
            pm.evaluate(row)
        t_naive = (time.perf_counter() - t0) * len(q) / len(sub)
        t_at = float("nan")
        if name.endswith("x 417"):
            t0 = time.perf_counter()
            for row in q:
                pm.at(row, out_of_span="clamp")
            t_at = time.perf_counter() - t0
        n_unique = len(np.unique(q, axis=0))
        print(f"{name:46s} {n_unique:7d} {np.count_nonzero(~ev.in_span):6d} {t_vec:13.3f} {t_naive:10.1f} "
              f"{t_naive / t_vec:7.0f} {t_at:14.2f}")


def law_errors(pm, poses):
    ev = pm.evaluate(poses)
    truth = [tip_modes(q) for q in poses]
    f, k, z, u = (np.array([t[i] for t in truth]) for i in range(4))
    mac = np.einsum("pmi,pmi->pm", ev.directions, u) ** 2
    return (np.max(np.abs(ev.natural_frequency_hz / f - 1)), np.max(np.abs(ev.damping_ratio / z - 1)),
            np.max(np.abs(ev.stiffness_N_m / k - 1)), 1 - np.min(mac))


def accuracy(quick: bool) -> None:
    rng = np.random.default_rng(2)
    print("\n2. Accuracy against the 3-joint arm law (largest relative error between poses)")
    print(f"{'span':6s} {'kernel':18s} {'poses':>6s} {'freq':>9s} {'damping':>9s} {'stiffness':>9s} {'1-MAC':>9s}")
    along = line(np.linspace(0, 1, 301))
    for kernel in ("cubic", "thin_plate_spline", "linear"):
        for n in ((3, 5, 9) if quick else (3, 4, 5, 6, 7, 9, 13, 17)):
            pm = PoseModels.fit([law_model(q, rng) for q in line(np.linspace(0, 1, n))], kernel=kernel)
            e = law_errors(pm, along)
            print(f"{'line':6s} {kernel:18s} {n:6d} {e[0]:9.2e} {e[1]:9.2e} {e[2]:9.2e} {e[3]:9.2e}")
    ab = rng.uniform(0, 1, size=(400, 2))
    inside = Q_A + np.column_stack([35 * ab[:, 0], np.zeros(400), 25 * ab[:, 1], np.zeros((400, 3))])
    for kernel in ("cubic", "thin_plate_spline"):
        for n in ((3, 5) if quick else (3, 4, 5, 7)):
            g = np.linspace(0, 1, n)
            grid = [Q_A + np.array([a * 35.0, 0, b * 25.0, 0, 0, 0]) for a in g for b in g]
            pm = PoseModels.fit([law_model(q, rng) for q in grid], kernel=kernel)
            e = law_errors(pm, inside)
            print(f"{'grid':6s} {kernel:18s} {n * n:6d} {e[0]:9.2e} {e[1]:9.2e} {e[2]:9.2e} {e[3]:9.2e}")


def print_loo(title, pm):
    loo = pm.leave_one_out()
    print(f"\n{title}")
    print(f"{'pose':>4s} {'extrap':>6s} {'mode':>4s} {'f [Hz]':>9s} {'df/f':>8s} {'dzeta/zeta':>10s} {'dk/k':>8s}"
          f" {'MAC':>8s}")
    for i in range(pm.n_poses):
        for r in range(pm.n_modes):
            flag = "yes" if loo.extrapolated[i] else "no"
            print(f"{i:4d} {flag:>6s} {r:4d} {pm.natural_frequency_hz[i, r]:9.2f} {loo.frequency_error[i, r]:+8.2%} "
                  f"{loo.damping_error[i, r]:+10.2%} {loo.stiffness_error[i, r]:+8.2%} {loo.direction_mac[i, r]:8.5f}")
    for label, interior in (("interior", True), ("all", False)):
        s = loo.summary(interior_only=interior)
        print(f"  {label:8s} poses {s['poses']}: max |df/f| {s['max_abs_frequency_error']:.2%}, max |dzeta/zeta| "
              f"{s['max_abs_damping_error']:.2%}, max |dk/k| {s['max_abs_stiffness_error']:.2%}, "
              f"min MAC {s['min_direction_mac']:.5f}")


def compare_on_table(pm) -> None:
    """Interior-pose LOO of each kernel against simply taking the nearest other pose's values."""
    print("  interior poses, max |relative error| by method:")
    print(f"  {'method':20s} {'freq':>8s} {'damping':>8s} {'stiffness':>9s}")
    for kernel in ("cubic", "thin_plate_spline", "linear"):
        s = PoseModels.fit(read_table(), kernel=kernel).leave_one_out().summary()
        print(f"  {kernel:20s} {s['max_abs_frequency_error']:8.2%} {s['max_abs_damping_error']:8.2%} "
              f"{s['max_abs_stiffness_error']:9.2%}")
    errs = []
    for i in range(1, pm.n_poses - 1):
        d = np.linalg.norm(pm.joints_deg - pm.joints_deg[i], axis=1)
        d[i] = np.inf
        j = int(np.argmin(d))  # nearest other pose (the lower one on ties)
        errs.append([np.max(np.abs(getattr(pm, name)[j] / getattr(pm, name)[i] - 1))
                     for name in ("natural_frequency_hz", "damping_ratio", "stiffness_N_m")])
    e = np.max(errs, axis=0)
    print(f"  {'nearest pose':20s} {e[0]:8.2%} {e[1]:8.2%} {e[2]:9.2%}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats and sizes")
    args = parser.parse_args(argv)
    speed(repeats=3 if args.quick else 7, naive_points=500 if args.quick else 2000)
    accuracy(args.quick)
    print_loo("3. Leave-one-pose-out, bundled example (6 poses, robot + tool modes)",
              PoseModels.fit(example_models()))
    if TABLE.exists():
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            pm = PoseModels.fit(read_table())
        print_loo("4. Leave-one-pose-out, real table (surgical robot, xx and yy modes; assumed joint 1 = "
                  "0, 10, .., 40 deg)", pm)
        compare_on_table(pm)
    else:
        print(f"\n4. skipped: {TABLE} not found")


if __name__ == "__main__":
    main()
