"""Benchmark of ``robomill posture`` (robomill issue 11, item 7): 1 000 points x 36 rotations.

Run from the repository root::

    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_posture.py [--quick]

The path: the example cell's path (part frame) resampled to 1 000 points, its deep stretch
(15 mm) kept, on the example's truth robot (``truth/robot_truth.yaml``) with the tool modes;
36 rotations (10 deg). Cases: the default (64 stations: inverse kinematics of every branch at
64 x 36 states, the margin of the two candidate branches' feasible states by the check, the two
dynamic programmes, the refinement, then the joints of all 1 000 points and the check before and
after), and 200 stations. The brute-force reference: the smallest margin along the path at each
constant flange angle of a 10-deg grid (36 full checks of the path). Times are medians, wall and
CPU of this process; BLAS pinned to one thread.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from oma.modal_io import read_modal_model  # noqa: E402
from planner.robot import read_robot  # noqa: E402
from planner.robot.posture import choose_posture, constant_rotation_margins  # noqa: E402
from planner.toolpath_io import read_toolpath  # noqa: E402

EXAMPLE = ROOT / "examples" / "kr500_acetal"


def resampled(base, n):
    t = np.linspace(0.0, base.n_points - 1.0, n)
    k = np.arange(base.n_points)
    near = np.rint(t).astype(int)
    pos = np.column_stack([np.interp(t, k, base.positions_m[:, j]) for j in range(3)])
    return replace(base, positions_m=pos, joints_deg=None, spindle_rpm=base.spindle_rpm[near],
                   feed_per_tooth_m=base.feed_per_tooth_m[near], radial_depth_m=base.radial_depth_m[near],
                   axial_depth_m=base.axial_depth_m[near], milling=base.milling[near])


def timed(fn, repeats):
    wall, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu), out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one repeat, no 200-station case")
    args = parser.parse_args(argv)
    repeats = 1 if args.quick else 3
    warnings.simplefilter("ignore", UserWarning)
    robot = read_robot(EXAMPLE / "truth" / "robot_truth.yaml")
    tool = read_modal_model(EXAMPLE / "models" / "tool_mode.yaml")
    path = resampled(read_toolpath(EXAMPLE / "toolpath.yaml"), 1000)
    choose_posture(robot, resampled(path, 50), tool_model=tool, stations=8)  # warm-up (numba caches)
    rows = []
    for stations in (64,) if args.quick else (64, 200):
        wall, cpu, res = timed(lambda: choose_posture(robot, path, tool_model=tool, stations=stations), repeats)
        rows.append((stations, wall, cpu, res))
    c0, t0 = time.process_time(), time.perf_counter()
    sweep = constant_rotation_margins(robot, path, np.arange(-180.0, 180.0, 10.0), tool_model=tool)
    brute_cpu, brute_wall = time.process_time() - c0, time.perf_counter() - t0
    best = float(np.max(sweep))
    print("stations | points x rotations | wall s | CPU s | min margin before | min margin after | "
          "after / best constant | unreachable | margin evaluations")
    print("--- | --- | --- | --- | --- | --- | --- | --- | ---")
    for stations, wall, cpu, res in rows:
        print(f"{stations} | {res.rotation_deg.size} x {res.rotations_deg.size} | {wall:.1f} | {cpu:.1f} | "
              f"{res.min_margin_before:.4f} | {res.min_margin_after:.4f} | {res.min_margin_after / best:.4f} | "
              f"{len(res.unreachable)} | {res.evaluations.get('margin_evaluations')}")
    print(f"\nbrute force: 36 constant flange angles, best smallest margin {best:.4f} "
          f"(worst feasible {np.min(sweep[np.isfinite(sweep)]):.4f}), {brute_wall:.1f} s wall, {brute_cpu:.1f} s CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
