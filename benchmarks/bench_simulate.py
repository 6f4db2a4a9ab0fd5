"""Speed and accuracy of the time-domain milling simulator (stability/simulate.py).

Run: ``.venv/bin/python benchmarks/bench_simulate.py [--quick]``

Prints three tables:

1. JIT cost: first call in a fresh process with an empty numba cache (compile) and with the
   on-disk cache (load).
2. Speed: median of 5 runs of ``simulate`` for 10 s of a 1 kHz record at 2700 rpm, 2 teeth
   (the KR500 acetal cut of Nguyen & Melkote 2020), for 1 mode/1 slice, 3 modes/12 slices and 4
   modes incl. a 700 Hz spindle mode/12 slices, with background force; the time inside the
   compiled kernel; ratio against the 1-mode case; the same kernel run as plain Python
   (``run.py_func`` timed on 0.2 s, scaled to the duration) and its ratio to the compiled kernel.
3. Accuracy: chatter onset of the 1-DOF 2-tooth slotting benchmark (Insperger & Stepan 2004;
   m = 0.03993 kg, fn = 922 Hz, zeta = 0.011, Kt = 6e8, Kn = 2e8 N/m^2) at 5000 rpm by bisection
   on depth, against the number of steps per tooth. DOMAIN.md quotes ~0.41 mm for a converged
   semi-discretisation and 0.48 mm for 40 steps per tooth.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from oma.cutting import Cut, CuttingCoefficients, Tool  # noqa: E402
from oma.modal import ModalModel  # noqa: E402
from stability import _sim_kernel  # noqa: E402
from stability.simulate import BackgroundForce, simulate  # noqa: E402

ACETAL = CuttingCoefficients(Ktc_N_m2=1.2e8, Krc_N_m2=4.5e7, Kac_N_m2=2.0e7, Kte_N_m=2.0e3, Kre_N_m=3.0e3,
                             Kae_N_m=5.0e2)
TOOL = Tool(2, 0.0254, math.radians(30.0))
CUT = Cut(5e-4, 0.006, "down", [0, 1, 0], [-1, 0, 0], spindle_rpm=2700.0, axial_depth_m=0.006)
BACKGROUND = BackgroundForce((232.0, 278.0, 251.0), 200.0)

ROBOT_MODES = dict(natural_frequency_hz=[10.5, 24.8, 11.5], damping_ratio=[0.05, 0.04, 0.05],
                   stiffness_N_m=[1.5e6, 3.0e6, 2.0e6], directions=[[1, 0, 0], [0, 1, 0], [0, 0, 1]])


def _model(n_modes: int) -> ModalModel:
    f = list(ROBOT_MODES["natural_frequency_hz"])
    z = list(ROBOT_MODES["damping_ratio"])
    k = list(ROBOT_MODES["stiffness_N_m"])
    u = [list(d) for d in ROBOT_MODES["directions"]]
    if n_modes == 4:
        f, z, k, u = f + [700.0], z + [0.03], k + [2.0e7], u + [[1, 1, 0]]
    return ModalModel(f[:n_modes], z[:n_modes], k[:n_modes], u[:n_modes])


CONFIGS = [
    ("1 mode, 1 slice", _model(1), 1),
    ("3 modes, 12 slices", _model(3), 12),
    ("4 modes (700 Hz), 12 slices", _model(4), 12),
]


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def jit_cost() -> tuple[float, float]:
    """Seconds for the first call in a fresh process: empty cache (compile) and warm cache."""
    code = (
        "import time, sys; sys.path.insert(0, %r)\n"
        "from stability import simulate as s; from benchmarks.bench_simulate import TOOL, CUT, ACETAL, _model\n"
        "t0 = time.perf_counter(); s.simulate(_model(1), TOOL, CUT, ACETAL, duration_s=0.05, axial_slices=1)\n"
        "print(time.perf_counter() - t0)\n" % str(ROOT)
    )
    out = []
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for _ in range(2):  # cold, then warm (same cache dir)
            res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True,
                                 cwd=ROOT)
            out.append(float(res.stdout.strip().splitlines()[-1]))
    return out[0], out[1]


def kernel_seconds(fn) -> float:
    """Seconds spent inside the compiled kernel during ``fn()``."""
    compiled = _sim_kernel.run
    spent = []

    def timed(*args):
        t0 = time.perf_counter()
        compiled(*args)
        spent.append(time.perf_counter() - t0)

    _sim_kernel.run = timed
    try:
        fn()
    finally:
        _sim_kernel.run = compiled
    return sum(spent)


def python_kernel_seconds_per_step(model: ModalModel, slices: int, duration_s: float = 0.2) -> float:
    """Seconds per step inside the same kernel run as plain Python (``py_func``, no numba)."""
    simulate(model, TOOL, CUT, ACETAL, duration_s=0.01, axial_slices=slices)  # compile the real one first
    compiled_force, compiled_run = _sim_kernel.cutting_force, _sim_kernel.run
    spent = []

    def timed(*args):
        t0 = time.perf_counter()
        compiled_run.py_func(*args)
        spent.append(time.perf_counter() - t0)

    try:
        _sim_kernel.cutting_force = compiled_force.py_func  # run.py_func looks this global up at call time
        _sim_kernel.run = timed
        r = simulate(model, TOOL, CUT, ACETAL, duration_s=duration_s, axial_slices=slices, background=BACKGROUND,
                     seed=1)
    finally:
        _sim_kernel.cutting_force, _sim_kernel.run = compiled_force, compiled_run
    return sum(spent) / (r.time_s.size - 1)


def speed_table(duration_s: float, repeats: int) -> None:
    print(f"\n2. simulate(): {duration_s:g} s at 2700 rpm, 2 teeth, 1 kHz record, background force; "
          f"median of {repeats}")
    header = f"{'configuration':32s} {'steps/tooth':>11s} {'steps':>8s} {'time (s)':>9s} {'us/step':>8s} " \
             f"{'kernel (s)':>10s} {'vs 1 mode':>9s} {'python kernel (s)':>18s} {'speed-up':>9s}"
    print(header)
    print("-" * len(header))
    base = None
    for name, model, slices in CONFIGS:
        def run():
            return simulate(model, TOOL, CUT, ACETAL, duration_s=duration_s, axial_slices=slices,
                            background=BACKGROUND, seed=1)

        r = run()
        t = _median_time(run, repeats)
        n = r.time_s.size - 1
        base = t if base is None else base
        k = float(np.median([kernel_seconds(run) for _ in range(repeats)]))
        py = python_kernel_seconds_per_step(model, slices) * n
        print(f"{name:32s} {r.steps_per_tooth:11d} {n:8d} {t:9.3f} {1e6 * t / n:8.2f} {k:10.3f} {t / base:9.2f} "
              f"{py:18.1f} {py / k:9.0f}")


def insperger_onset(steps_per_tooth: int | None, rpm: float = 5000.0) -> tuple[float, int]:
    model = ModalModel([922.0], [0.011], [0.03993 * (2 * math.pi * 922.0) ** 2], [[1, 0, 0]])
    tool = Tool(2, 0.02, 0.0)
    cut = Cut(1e-4, 0.02, "down", [1, 0, 0], [0, 1, 0])
    coef = CuttingCoefficients(6e8, 2e8)

    def growth(depth):
        r = simulate(model, tool, cut, coef, duration_s=1.0, spindle_rpm=rpm, axial_depth_m=depth,
                     steps_per_tooth=steps_per_tooth, sample_rate_hz=1000.0)
        return r.chatter_growth(start_fraction=0.3), r.steps_per_tooth

    lo, hi = 0.2e-3, 1.0e-3
    g_lo, spt = growth(lo)
    g_hi, _ = growth(hi)
    assert g_lo < 0 < g_hi, (g_lo, g_hi)
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        if growth(mid)[0] < 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi), spt


def accuracy_table() -> None:
    print("\n3. chatter onset, 1-DOF 2-tooth slot at 5000 rpm (Insperger & Stepan 2004 benchmark)")
    print(f"{'steps/tooth':>11s} {'onset (mm)':>11s} {'time (s)':>9s}")
    for spt in (None, 20, 40, 80, 160, 320):
        t0 = time.perf_counter()
        depth, used = insperger_onset(spt)
        label = f"{used} (rule)" if spt is None else f"{used}"
        print(f"{label:>11s} {1e3 * depth:11.4f} {time.perf_counter() - t0:9.2f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 s instead of 10 s, 3 repeats")
    args = parser.parse_args(argv)
    cold, warm = jit_cost()
    print("1. JIT: first call in a fresh process")
    print(f"   empty numba cache (compile): {cold:6.2f} s")
    print(f"   warm numba cache (load):     {warm:6.2f} s")
    speed_table(2.0 if args.quick else 10.0, 3 if args.quick else 5)
    accuracy_table()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
