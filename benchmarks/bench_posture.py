"""Benchmark of ``robomill posture`` (robomill issue 11, item 7): 1 000 points x 36 rotations.

Run from the repository root::

    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_posture.py [--quick]

Two cells, 1 000 points each, 36 rotations (10 deg):

* *example*: the example cell's path (part frame) resampled to 1 000 points, its deep stretch
  (15 mm) kept, on the example's truth robot (``truth/robot_truth.yaml``) with the tool modes.
  There the stability limit is set by the pose-independent tool modes: the margin does not depend
  on the rotation (the case measures the cost only);
* *offset*: the KR 500 with DOMAIN.md's joint stiffness and a spindle 0.25 m off the flange axis
  (the cell of ``tests/test_posture.py``), a 0.4 m straight path cut 12 mm deep at 2700 rpm, no
  tool modes: the robot's modes limit the cut and the rotation matters.
 Cases: the default (64 stations: inverse kinematics of every branch at
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
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _paths import resampled as resample  # noqa: E402
from _timing import median_time  # noqa: E402

from oma.modal_io import read_modal_model  # noqa: E402
from planner.robot import read_robot  # noqa: E402
from planner.robot.posture import choose_posture, constant_rotation_margins  # noqa: E402
from planner.toolpath_io import read_toolpath  # noqa: E402

EXAMPLE = ROOT / "examples" / "kr500_acetal"


def resampled(base, n):
    """The path resampled to ``n`` points, without joint angles (the posture chooses them)."""
    return replace(resample(base, n), joints_deg=None)


OFFSET_ROBOT = """\
format: robomill-robot/1
urdf: {urdf}
base_link: base_link
flange_link: tool0
tool: {{tip_m: [0.0, 0.25, 0.40], axis: [0.0, 0.0, -1.0], mass_kg: 150.0, center_of_mass_m: [0.0, 0.12, 0.20],
  inertia_kg_m2: [[4.0, 0, 0], [0, 4.0, 0], [0, 0, 1.5]]}}
joints: {{stiffness_N_m_rad: [2.3e6, 8.6e6, 2.8e6, 3.0e6, 0.2e6, 0.9e6], damping_ratio: [0.05, 0.05, 0.05, 0.05, 0.05, 0.05]}}
"""


def offset_cell(base, n, directory):
    """The offset-spindle cell: robot, and a straight 0.4 m path of ``n`` points (machine frame)."""
    path = Path(directory) / "offset_robot.yaml"
    path.write_text(OFFSET_ROBOT.format(urdf=EXAMPLE / "robot" / "kr500_r2800_2.urdf"))
    y = np.linspace(-0.2, 0.2, n)
    full = lambda a: np.full(n, a[0])  # noqa: E731
    tp = replace(base, positions_m=np.column_stack([np.full(n, 1.2), y, np.full(n, 0.4)]), joints_deg=None,
                 workpiece_origin_m=None, workpiece_rpy_deg=None, spindle_rpm=np.full(n, 2700.0),
                 feed_per_tooth_m=full(base.feed_per_tooth_m), radial_depth_m=full(base.radial_depth_m),
                 axial_depth_m=np.full(n, 0.012), milling=full(base.milling))
    return read_robot(path), tp




def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one repeat, no 200-station case")
    args = parser.parse_args(argv)
    repeats = 1 if args.quick else 3
    warnings.simplefilter("ignore", UserWarning)
    import tempfile

    example_path = read_toolpath(EXAMPLE / "toolpath.yaml")
    tmp = tempfile.mkdtemp()
    cells = {"example": (read_robot(EXAMPLE / "truth" / "robot_truth.yaml"), resampled(example_path, 1000),
                         read_modal_model(EXAMPLE / "models" / "tool_mode.yaml")),
             "offset": (*offset_cell(example_path, 1000, tmp), None)}
    robot, path, tool = cells["example"]
    choose_posture(robot, resampled(path, 50), tool_model=tool, stations=8)  # warm-up (numba caches)
    print("cell | stations | points x rotations | wall s | CPU s | min margin before | min margin after | "
          "after / best constant | best / worst constant | unreachable | margin evaluations | brute force CPU s")
    print("--- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | ---")
    for cell, (robot, path, tool) in cells.items():
        c0 = time.process_time()
        sweep = constant_rotation_margins(robot, path, np.arange(-180.0, 180.0, 10.0), tool_model=tool)
        brute_cpu = time.process_time() - c0
        best, worst = float(np.max(sweep)), float(np.min(sweep[np.isfinite(sweep)]))
        for stations in (64,) if args.quick else (64, 200):
            wall, cpu, res = median_time(lambda: choose_posture(robot, path, tool_model=tool, stations=stations), repeats)
            print(f"{cell} | {stations} | {res.rotation_deg.size} x {res.rotations_deg.size} | {wall:.1f} | {cpu:.1f} | "
                  f"{res.min_margin_before:.4f} | {res.min_margin_after:.4f} | {res.min_margin_after / best:.4f} | "
                  f"{best / worst:.3f} | {len(res.unreachable)} | {res.evaluations.get('margin_evaluations')} | "
                  f"{brute_cpu:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
