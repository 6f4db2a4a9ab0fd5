"""Benchmark of the cutting-parameter planner (robomill issue 5, part 1).

Run from the repository root::

    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_plan.py          # about 1-2 minutes
    MPLBACKEND=Agg .venv/bin/python benchmarks/bench_plan.py --sdm-example  # + the example by SDM

Cases (each: plan time, removal rate, active constraints, and the exhaustive grid search of
tests/problems.py over the same constraints, the surface error on the whole finished wall as the
plan bounds it (formats.md), with its time and the relative difference)

1. the bundled example (examples/kr500_acetal: acetal, 25.4 mm 2-flute 30 deg helix, ae 6 mm,
   robot and tool modes), ZOA, 500-24000 rpm;
2. aluminium 7075, 16 mm 3-flute 45 deg helix, ae 8 mm up milling, the example's model, ZOA;
3. the aluminium tool at ae/D = 0.1 on the tool modes alone, SDM ('auto'), 6000-20000 rpm;
4. (``--sdm-example``) the example planned with the SDM (slow: the robot modes need many steps).

BLAS is pinned to one thread so that the shared 2-core machine gives reproducible numbers.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import problems  # noqa: E402
from oma.modal_io import read_modal_model  # noqa: E402
from planner.optimize import PlanSettings, plan  # noqa: E402
from stability.lobes import lobe_diagram  # noqa: E402
from stability.setup_io import read_setup  # noqa: E402
from test_plan import aluminium_setup, low_immersion_setup  # noqa: E402


def run(name, setup, model, *, method="auto", settings=None, reference=True):
    t0 = time.perf_counter()
    result = plan(setup, model, method=method, settings=settings)
    t_plan = time.perf_counter() - t0
    line = (f"{name:<28s} {result.method:>4s} {len(result.pockets):>4d} pockets {t_plan:7.2f} s  "
            f"{(result.mrr_m3_s or 0) * 1e6:9.4f} cm^3/s  {result.status:<10s} "
            f"[{', '.join(result.active_constraints)}]")
    if reference and result.success:
        limit_at = None
        if result.method == "sdm":
            res = result.diagram.resolution
            coef = setup.material.cutting_coefficients

            def limit_at(r):
                r = np.asarray(r, dtype=float)
                d = lobe_diagram(model, setup.tool, setup.cut, coef, rpm_range=(r[0], r[-1] + 1.0), rpm=r,
                                 method="sdm", steps_per_mode_period=res.steps_per_mode_period,
                                 min_steps=res.min_steps)
                return np.asarray(d.depth_limit_m)

        t0 = time.perf_counter()
        ref = problems.grid_search(setup, model, limit_at=limit_at, **({"n_rpm": 200} if limit_at else {}))
        t_ref = time.perf_counter() - t0
        line += (f"\n{'':<28s} grid search {t_ref:7.2f} s ({ref.evaluated:.2e} points): {ref.mrr_m3_s * 1e6:9.4f} "
                 f"cm^3/s; plan / grid - 1 = {result.mrr_m3_s / ref.mrr_m3_s - 1:+.2e}")
    print(line, flush=True)
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sdm-example", action="store_true", help="also plan the example with the SDM")
    args = parser.parse_args(argv)
    example = ROOT / "examples" / "kr500_acetal"
    planning = read_modal_model(example / "models" / "planning_model.yaml")
    tool_modes = read_modal_model(example / "models" / "tool_mode.yaml")
    setup = read_setup(example / "setup.yaml")
    run("example (acetal)", setup, planning)
    run("aluminium, 3 flutes", aluminium_setup(), planning)
    run("aluminium ae/D = 0.1", low_immersion_setup(axial_depth_m=(2e-4, 3e-2), surface_location_error_m=2e-5,
                                                     spindle_rpm=(6000.0, 20000.0)), tool_modes)
    if args.sdm_example:
        run("example (acetal), SDM", setup, planning, method="sdm", settings=PlanSettings(n_rpm_sdm=100),
            reference=False)


if __name__ == "__main__":
    main()
