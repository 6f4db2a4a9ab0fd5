"""Benchmark of the workspace atlas (robomill issue 13): 10 000 positions x 12 tool rotations.

Run from the repository root (``ROBOMILL_SHARED`` as for the robot tests)::

    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_atlas.py           # full (a few minutes)
    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_atlas.py --quick   # one repeat, smaller cases

Cases (the example cell: KR 500 R2800-2 with a 150 kg spindle, examples/kr500_acetal/setup.yaml,
ZOA over the setup's 500-24000 rpm, 300 speeds x 500 chatter frequencies per pose, modes with at
least 1e-3 of the largest tool-tip compliance):

1. *target*: ``robomill atlas`` as a user runs it: a local cluster of 2 worker processes started by
   the run, 10 000 positions (a 25 x 40 x 10 box, 4 cm step) x 12 rotations. Wall time from the call
   to the assembled table (cluster start, worker imports and numba cache loads included).
2. *scaling*: the compute phase alone on a warm LocalCluster of 1 and of 2 workers (the same
   2 000 positions x 12 rotations, the cluster started and warmed before the clock starts):
   throughput per core (positions per second per worker) and the speed-up of 2 workers over 1.
3. *cost per row*: CPU time per (position, rotation) of one serial chunk, by part (IK, branch
   choice, singularity measure, modes, ZOA kernel), the basis of the chunk sizing.
4. *accuracy of the defaults*: 200 positions x 12 rotations serially, the defaults against 10 000
   chatter frequencies and against every mode kept: rows whose best speed, depth limit and MRR
   differ; and the limit at the chosen speed against ``stability.zoa.envelope`` (predict's ZOA).
   ``--tool`` (cases 3 and 4) adds spindle/tool modes at 720/735 Hz (2 % damping) in series.

The machine is shared by several agents: the load average is printed before and after each case;
times are medians of ``--repeat`` runs.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))


def _load():
    return "load %.1f" % os.getloadavg()[0]


def _problem(step_m=0.04, shape=(25, 40, 10), rotations=12, n_freq=500, **options):
    from atlas_cases import SETUP, robot_file
    from planner.atlas import Region, build_problem, default_rotations_deg
    from planner.robot import read_robot
    from stability.setup_io import read_setup

    robot = read_robot(robot_file(tempfile.mkdtemp()))
    lower = np.array([1.4, -0.8, 0.2])
    upper = lower + step_m * (np.array(shape) - 1)
    region = Region(lower, upper, step_m, default_rotations_deg(360.0 / rotations))
    return build_problem(robot, read_setup(SETUP), region, n_freq=n_freq, **options), region


def case_target(repeat):
    from planner.atlas import run_atlas

    problem, region = _problem()
    walls = []
    for _ in range(repeat):
        print(f"  [{_load()}]", flush=True)
        t0 = time.perf_counter()
        result = run_atlas(problem, region, n_workers=2, progress=False)
        walls.append(time.perf_counter() - t0)
    c = result.counts()
    w = statistics.median(walls)
    print(f"target: {region.n_points} positions x {region.rotations_deg.size} rotations, local cluster of 2 "
          f"workers, {result.engine['chunks']} chunks of {result.engine['points_per_chunk']} positions")
    print(f"  wall {w:.1f} s (runs: {', '.join(f'{x:.1f}' for x in walls)}) [{_load()}]; "
          f"{region.n_points / w:.0f} positions/s, {region.n_points * region.rotations_deg.size / w:.0f} rows/s; "
          f"reachable rows {c['reachable']}, with a stable cut {c['stable_cut']}")
    return w


def _cpu_s():
    t = os.times()
    return t.user + t.system


def _rss_mb():
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def case_scaling(repeat, n_points):
    from distributed import LocalCluster

    from planner.atlas import run_atlas
    from planner.atlas.engine import WORKER_ENV

    nz = max(1, n_points // (25 * 8))
    problem, region = _problem(shape=(25, 8, nz))
    warm_problem, warm_region = _problem(shape=(2, 2, 2))
    rows = {}
    for workers in (1, 2):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None, env=dict(WORKER_ENV))
        try:
            run_atlas(warm_problem, warm_region, scheduler=cluster.scheduler_address, progress=False,
                      points_per_chunk=1)  # imports and numba caches loaded in every worker
            walls = []
            client = cluster.get_client()
            for _ in range(repeat):
                load = _load()
                cpu0 = sum(client.run(_cpu_s).values())
                t0 = time.perf_counter()
                run_atlas(problem, region, scheduler=cluster.scheduler_address, progress=False)
                walls.append(time.perf_counter() - t0)
                cpu = sum(client.run(_cpu_s).values()) - cpu0
                rss = max(client.run(_rss_mb).values())
                print(f"  {workers} worker(s): {walls[-1]:.1f} s wall, {cpu:.1f} s CPU in the workers "
                      f"({cpu / (region.n_points * region.rotations_deg.size) * 1e6:.0f} us per row), "
                      f"largest worker RSS {rss:.0f} MB [{load} -> {_load()}]", flush=True)
        finally:
            cluster.close()
        rows[workers] = statistics.median(walls)
    n = region.n_points
    print(f"scaling: {n} positions x {region.rotations_deg.size} rotations, compute phase on a warm cluster")
    print("| workers | wall (s) | positions/s | positions/s per core | speed-up |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    for workers, wall in rows.items():
        print(f"| {workers} | {wall:.2f} | {n / wall:.0f} | {n / wall / workers:.0f} | {rows[1] / wall:.2f} |")
    return rows


def case_cost(n_points=200, tool=False):
    from planner.atlas import evaluate as ev
    from planner.atlas._kernel import atlas_kernel
    from planner.robot import robot_modes
    from planner.robot.ik import inverse_kinematics, singularity_measure

    problem, region = _problem(shape=(10, 5, 4), **({"tool_model": tool_model()} if tool else {}))
    pos = region.to_machine(region.positions_m())[:n_points]
    ev.evaluate_chunk(problem, pos[:2])  # warm
    n_rot = problem.rotations_rad.size
    p = np.repeat(pos, n_rot, axis=0)
    rho = np.tile(problem.rotations_rad, pos.shape[0])
    parts = {}
    t = time.process_time()
    sol = inverse_kinematics(problem.robot, p, problem.tool_axis, rho, problem.feed_direction)
    parts["inverse kinematics (8 branches)"] = time.process_time() - t
    t = time.process_time()
    branch, q = ev._choose_branch(problem.robot, sol)
    parts["branch choice"] = time.process_time() - t
    q = q[branch >= 0]
    t = time.process_time()
    singularity_measure(problem.robot, q)
    parts["singularity measure"] = time.process_time() - t
    t = time.process_time()
    modes = robot_modes(problem.robot, q)
    parts["robot modes"] = time.process_time() - t
    t = time.process_time()
    g = q.shape[0]
    res = [np.empty(g) for _ in range(5)] + [np.empty(g, dtype=np.int64), np.empty((0, 0))]
    atlas_kernel()(*ev._structures(problem, modes), float(problem.teeth), problem.n_freq, problem.rpm_grid,
                   problem.ap_lo_m, problem.ap_hi_m, problem.ap_hi_code, problem.power_depth_rpm, problem.margin,
                   *res)
    parts["ZOA envelope + best cut + exact limit"] = time.process_time() - t
    rows = p.shape[0]
    print(f"cost per (position, rotation), CPU, {rows} rows ({g} reachable){', tool modes' if tool else ''}:")
    print("| part | us per row |")
    print("| --- | ---: |")
    for name, sec in parts.items():
        print(f"| {name} | {sec / rows * 1e6:.1f} |")
    print(f"| total | {sum(parts.values()) / rows * 1e6:.1f} |")


def tool_model():
    """Spindle/tool modes in series with the arm (``--tool``): 720 Hz along X and 735 Hz along Y,
    2 % damping (the 2026-11-26 audit's case, where the default grid missed the tool lobes)."""
    from oma.modal import ModalModel

    return ModalModel([720.0, 735.0], [0.02, 0.02], [4.0e6, 4.4e6], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def case_accuracy(n_points=200, tool=False):
    """The defaults (500 chatter frequencies, modes with >= 1e-3 of the largest tool-tip
    compliance) against 10 000 frequencies and every mode down to 1e-9 of it; and the limit at the
    chosen speed against ``stability.zoa.envelope`` (predict_point's ZOA, 10 000 frequencies) for
    the same modes, on every 10th row."""
    from planner.atlas.evaluate import evaluate_chunk
    from planner.robot import robot_modal_model
    from stability import zoa

    extra = {"tool_model": tool_model()} if tool else {}

    def run(**options):
        problem, region = _problem(shape=(10, 5, 4), **extra, **options)
        return problem, evaluate_chunk(problem, region.to_machine(region.positions_m())[:n_points])

    problem, a = run()
    rows = np.flatnonzero(np.isfinite(a["depth_limit_m"]))[::10]
    rel = []
    for i in rows:
        q = np.radians([a[f"q{j}_deg"][i] for j in range(1, 7)])
        model = robot_modal_model(problem.robot, q, min_tip_fraction=problem.min_tip_fraction, **extra)
        env = zoa.envelope(model, problem.tool, problem.cut_machine, problem.coefficients, [a["spindle_rpm"][i]],
                           n_freq=10_000)
        rel.append(abs(a["depth_limit_m"][i] / env.depth_limit_m[0] - 1))
    print(f"accuracy{' (with the tool modes)' if tool else ''}: limit at the chosen speed against "
          f"stability.zoa.envelope (10 000 frequencies, same modes), {rows.size} rows: max {max(rel):.1e}")
    for label, options in (("10 000 chatter frequencies", {"n_freq": 10_000}),
                           ("all modes (min_tip_fraction 1e-9)", {"min_tip_fraction": 1e-9})):
        _, b = run(**options)
        ok = np.isfinite(a["mrr_m3_s"]) & np.isfinite(b["mrr_m3_s"])
        same_rpm = np.mean(a["spindle_rpm"][ok] == b["spindle_rpm"][ok])
        fin = ok & np.isfinite(a["depth_limit_m"]) & np.isfinite(b["depth_limit_m"])
        dlim = np.abs(a["depth_limit_m"][fin] / b["depth_limit_m"][fin] - 1)
        dmrr = np.abs(a["mrr_m3_s"][ok] / b["mrr_m3_s"][ok] - 1)
        dmin = np.abs(a["min_depth_limit_m"][ok] / b["min_depth_limit_m"][ok] - 1)
        print(f"accuracy of the defaults against {label}, {ok.sum()} rows with a cut: same best speed "
              f"{same_rpm:.1%}; depth limit at it: max {dlim.max() if dlim.size else 0:.1e}; MRR: max "
              f"{dmrr.max():.1e}; smallest limit over the range: max {dmin.max():.1e}, median {np.median(dmin):.1e}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", choices=["target", "scaling", "cost", "accuracy"], default=None)
    ap.add_argument("--tool", action="store_true", help="cost, accuracy: with spindle/tool modes in series (720/735 Hz)")
    args = ap.parse_args(argv)
    repeat = 1 if args.quick else args.repeat
    cases = [args.only] if args.only else ["cost", "accuracy", "scaling", "target"]
    for case in cases:
        if case == "target":
            case_target(repeat)
        elif case == "scaling":
            case_scaling(repeat, 400 if args.quick else 2000)
        elif case == "cost":
            case_cost(tool=args.tool)
        else:
            case_accuracy(60 if args.quick else 200, tool=args.tool)


if __name__ == "__main__":
    main()
