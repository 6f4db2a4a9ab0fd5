"""Benchmark of the diagnosis (robomill issue 6): confusion matrix over hidden-effect cases, parameter
accuracy and validation gains, the chatter table of the measured Hurco cuts, and the paper's
shortcuts on the example cell.

Run::

    .venv/bin/python benchmarks/bench_diagnosis.py [--seeds 10] [--skip-hurco] [--skip-shortcuts]
                                                   [--shortcuts-method default|h1]

Every case is simulated by :func:`planner.diagnosis.cases.hidden_effect_case` (paper-like robot
cell, parameters drawn from the ranges in that module's notes, seeded) and diagnosed with the model
that lacks the effect. The tests (tests/test_diagnosis_hidden.py) run seeds 0-2 of each cause and
0-4 of the clean cell; this script runs more.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from planner.diagnosis import diagnose  # noqa: E402
from planner.diagnosis.cases import CAUSES, MAIN_PARAMETER, hidden_effect_case  # noqa: E402


def confusion(n_seeds: int, first_seed: int = 0):
    rows = []
    for cause in CAUSES:
        for seed in range(first_seed, first_seed + n_seeds):
            case = hidden_effect_case(cause, seed)
            t0 = time.process_time()
            d = diagnose(case.records, case.model, plot_data=False)
            cpu = time.process_time() - t0
            err = math.nan
            if cause != "none" and d.cause == cause:
                key = MAIN_PARAMETER[cause]
                err = abs(d.parameters[key] - case.truth[key]) / abs(case.truth[key])
            rows.append({"cause": cause, "seed": seed, "named": d.cause, "error": err, "gain": d.gain,
                         "z": d.significance, "cpu_s": cpu})
            print(f"  {cause:22s} seed {seed:2d} -> {d.cause:22s} gain {d.gain:5.2f} z {d.significance:7.1f} "
                  f"param error {err:6.3f} cpu {cpu:4.1f} s", flush=True)
    return rows


def print_confusion(rows):
    names = list(CAUSES)
    width = 8
    print("\nConfusion matrix (rows: hidden effect, columns: named cause)")
    head = "".join(f"{n[:width - 1]:>{width}s}" for n in names)
    print(f"{'':24s}{head}")
    for truth in names:
        counts = [sum(1 for r in rows if r["cause"] == truth and r["named"] == n) for n in names]
        print(f"{truth:24s}" + "".join(f"{c:{width}d}" for c in counts))
    correct = sum(1 for r in rows if r["cause"] == r["named"])
    print(f"correct: {correct} / {len(rows)}")

    print("\nPer cause: main parameter relative error (named cases), validation gain")
    print(f"{'cause':24s}{'parameter':34s}{'median':>8s}{'max':>8s}{'<=20%':>7s}{'min gain':>9s}{'med gain':>9s}"
          f"{'cpu/case':>9s}")
    for cause in names:
        rs = [r for r in rows if r["cause"] == cause]
        cpu = np.mean([r["cpu_s"] for r in rs])
        if cause == "none":
            print(f"{cause:24s}{'-':34s}{'':8s}{'':8s}{'':7s}{'':9s}{'':9s}{cpu:9.1f}")
            continue
        errs = np.array([r["error"] for r in rs if np.isfinite(r["error"])])
        gains = np.array([r["gain"] for r in rs if r["named"] == cause])
        within = f"{np.sum(errs <= 0.2)}/{len(rs)}"
        med = f"{np.median(errs):8.3f}" if errs.size else f"{'-':>8s}"
        mx = f"{np.max(errs):8.3f}" if errs.size else f"{'-':>8s}"
        gmin = f"{np.min(gains):9.2f}" if gains.size else f"{'-':>9s}"
        gmed = f"{np.median(gains):9.2f}" if gains.size else f"{'-':>9s}"
        print(f"{cause:24s}{MAIN_PARAMETER[cause]:34s}{med}{mx}{within:>7s}{gmin}{gmed}{cpu:9.1f}")


def print_hurco():
    from planner.diagnosis.hurco import DEFAULT_DIRECTORY, hurco_table

    if not DEFAULT_DIRECTORY.exists():
        print(f"\n(no Hurco data at {DEFAULT_DIRECTORY})")
        return
    rows = hurco_table()
    print("\nMeasured CNC cuts (milling-vibration-hurco): tooth frequency and chatter (2 s windows of the cut)")
    print(f"{'file':40s}{'rpm':>12s}{'N':>3s}{'tooth nominal':>15s}{'tooth found':>12s}{'chatter':>8s}"
          f"{'kind':>6s}{'freq Hz':>9s}{'windows':>9s}{'CI med':>8s}{'CI>0.9':>7s}{'agree':>6s}")
    for r in rows:
        rpm = "/".join(f"{v:.0f}" for v in r["spindle_rpm"])
        nom = "/".join(f"{v:.2f}" for v in r["tooth_hz_nominal"])
        fc = f"{r['chatter_hz']:.1f}" if r["chatter_hz"] is not None else "-"
        print(f"{r['file']:40s}{rpm:>12s}{r['teeth']:3d}{nom:>15s}{r['tooth_hz']:12.2f}{str(r['chatter']):>8s}"
              f"{r['chatter_kind']:>6s}{fc:>9s}{r['windows_with_chatter']:>5d}/{r['n_windows']:<3d}"
              f"{r['ci_median']:8.2f}{str(r['ci_chatter']):>7s}{str(r['agrees_with_ci']):>6s}")
    agree = sum(r["agrees_with_ci"] for r in rows)
    print(f"agreement with the source's indicator (median CI > 0.9): {agree} / {len(rows)} "
          "(the indicator is not a ground truth)")


def print_shortcuts(method: str):
    from planner.diagnosis.shortcuts import EXAMPLE_DIRECTORY, paper_shortcuts

    if not (EXAMPLE_DIRECTORY / "records" / "cut_short").exists():
        print("\n(example cell not generated)")
        return
    t0 = time.perf_counter()
    rep = paper_shortcuts(method=method)
    print(f"\nThe paper's shortcuts on the example cell (identification method '{method}', "
          f"{time.perf_counter() - t0:.0f} s)")
    print(f"{'shortcut':32s}{'quantity':36s}{'with':>12s}{'without':>12s}{'truth':>10s}")
    for r in rep.rows():
        truth = f"{r['truth']:10.1f}" if "truth" in r else f"{'':10s}"
        print(f"{r['shortcut']:32s}{r['quantity']:36s}{r['with_shortcut']:12.4g}{r['without_shortcut']:12.4g}{truth}")
    for eff in (rep.harmonics, rep.sensor):
        print(f"  {eff.name}: modal errors with the shortcut (frequency, damping, stiffness per true mode):")
        for e in eff.modal_errors_with:
            print(f"    {e['mode_hz']:5.1f} Hz: {100 * e['frequency']:+6.1f} % {100 * e['damping']:+6.1f} % "
                  f"{100 * e['stiffness']:+6.1f} %")
        print("    without:")
        for e in eff.modal_errors_without:
            print(f"    {e['mode_hz']:5.1f} Hz: {100 * e['frequency']:+6.1f} % {100 * e['damping']:+6.1f} % "
                  f"{100 * e['stiffness']:+6.1f} %")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--skip-hurco", action="store_true")
    parser.add_argument("--skip-shortcuts", action="store_true")
    parser.add_argument("--shortcuts-method", default="default", choices=("default", "h1"))
    args = parser.parse_args(argv)
    if args.seeds > 0:
        print(f"Hidden-effect cases: {len(CAUSES)} causes x {args.seeds} seeds")
        rows = confusion(args.seeds, args.first_seed)
        print_confusion(rows)
    if not args.skip_hurco:
        print_hurco()
    if not args.skip_shortcuts:
        print_shortcuts(args.shortcuts_method)


if __name__ == "__main__":
    main()
