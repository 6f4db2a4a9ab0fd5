"""Benchmark of the diagnosis (robomill issues 6 and 10): confusion matrix over hidden-effect cases
with nuisance, parameter accuracy and validation gains per cause and form, the chatter table of the
measured Hurco cuts, and the paper's shortcuts on the example cell.

Run::

    .venv/bin/python benchmarks/bench_diagnosis.py [--seeds 10] [--first-seed 100] [--causes C ...]
        [--no-nuisance] [--workers N] [--skip-hurco] [--skip-shortcuts] [--shortcuts-method default|h1]

Every case is simulated by :func:`planner.diagnosis.cases.hidden_effect_case` (paper-like robot
cell, parameters drawn from the ranges in that module's notes, seeded), each effect in each of its
forms (alternating over the seeds), with nuisance on every record (coefficients off by up to 20 %,
another background, a helix up to 5 deg off), and diagnosed with the model that lacks the effect.
The tests use seeds below 100; this script starts at 100.
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
from planner.diagnosis.cases import (CAUSES, COEFFICIENT_FLOOR, FORMS, MAIN_PARAMETER, expected_cause,  # noqa: E402
                                     hidden_effect_case)


def _one(args):
    cause, seed, form, nuisance = args
    case = hidden_effect_case(cause, seed, form=form, nuisance=nuisance)
    expected = expected_cause(case)
    t0 = time.process_time()
    d = diagnose(case.records, case.model, plot_data=False)
    cpu = time.process_time() - t0
    err = math.nan
    truth = case.truth if cause != "none" else case.nuisance.get("coefficients", {})
    key = MAIN_PARAMETER.get(expected)
    if key is not None and d.cause == expected:
        err = abs(d.parameters[key] - truth[key]) / abs(truth[key])
    # a clean record whose nuisance coefficients sit within 20 % of the floor: either answer is right
    ok = d.cause == expected
    coef = case.nuisance.get("coefficients", {})
    size = max(abs(coef.get("Ktc_relative_change", 0.0)), abs(coef.get("ratio_relative_change", 0.0)))
    borderline = cause == "none" and abs(size - COEFFICIENT_FLOOR) <= 0.2 * COEFFICIENT_FLOOR
    if borderline and d.cause in ("none", "cutting_coefficients"):
        ok = True
    floor = next((r.practical for r in d.ranking if r.cause == d.cause), {})
    return {"cause": cause, "expected": expected, "form": form or "default", "seed": seed, "named": d.cause,
            "ok": ok, "error": err, "gain": d.gain, "z": d.significance, "cpu_s": cpu,
            "size": floor.get("size", math.nan), "coef_size": size}


def confusion(n_seeds: int, first_seed: int = 100, *, nuisance: bool = True, causes=None, workers: int = 1):
    """Every cause in every form (forms alternate over the seeds), nuisance on every record."""
    jobs = []
    for cause in (causes or CAUSES):
        forms = FORMS.get(cause, (None,))
        for seed in range(first_seed, first_seed + n_seeds):
            jobs.append((cause, seed, forms[(seed - first_seed) % len(forms)], nuisance))
    rows = []
    if workers > 1:
        from multiprocessing import Pool

        with Pool(workers) as pool:
            it = pool.imap(_one, jobs)
            for r in it:
                rows.append(r)
                _print_row(r)
    else:
        for job in jobs:
            r = _one(job)
            rows.append(r)
            _print_row(r)
    return rows


def _print_row(r):
    print(f"  {r['cause']:22s} {r['form']:15s} seed {r['seed']:3d} -> {r['named']:22s} (expected {r['expected']:21s}) "
          f"{'ok ' if r['ok'] else 'BAD'} gain {r['gain']:5.2f} z {r['z']:7.1f} size {r['size']:8.3g} "
          f"param error {r['error']:6.3f} cpu {r['cpu_s']:4.1f} s", flush=True)


def print_confusion(rows):
    names = ["none"] + [c for c in CAUSES if c != "none"]
    width = 8
    print("\nConfusion matrix with nuisance (rows: hidden effect, columns: named cause)")
    head = "".join(f"{n[:width - 1]:>{width}s}" for n in names)
    print(f"{'':24s}{head}")
    for truth in names:
        counts = [sum(1 for r in rows if r["cause"] == truth and r["named"] == n) for n in names]
        if sum(counts):
            print(f"{truth:24s}" + "".join(f"{c:{width}d}" for c in counts))
    correct = sum(1 for r in rows if r["ok"])
    print(f"right: {correct} / {len(rows)} (a clean record is right with 'none', or with 'cutting_coefficients' when "
          f"its nuisance coefficients are >= {COEFFICIENT_FLOOR:.0%} off; within 20 % of that floor either)")
    clean = [r for r in rows if r["cause"] == "none"]
    if clean:
        false = sum(1 for r in clean if r["named"] not in ("none", "cutting_coefficients"))
        print(f"clean records: {false} false alarms of an effect in {len(clean)}; "
              f"{sum(1 for r in clean if r['named'] == 'cutting_coefficients')} named cutting_coefficients "
              f"({sum(1 for r in clean if r['expected'] == 'cutting_coefficients')} have coefficients "
              "off by the floor or more)")

    print("\nPer cause and form: named right, main parameter relative error (named cases), validation gain")
    print(f"{'cause':24s}{'form':16s}{'right':>7s}{'parameter':>28s}{'median':>8s}{'max':>8s}{'<=20%':>7s}"
          f"{'min gain':>9s}{'med gain':>9s}{'cpu/case':>9s}")
    for cause in names:
        for form in sorted({r["form"] for r in rows if r["cause"] == cause}):
            rs = [r for r in rows if r["cause"] == cause and r["form"] == form]
            cpu = np.mean([r["cpu_s"] for r in rs])
            right = f"{sum(r['ok'] for r in rs)}/{len(rs)}"
            errs = np.array([r["error"] for r in rs if np.isfinite(r["error"])])
            gains = np.array([r["gain"] for r in rs if r["named"] == r["expected"] and r["named"] != "none"])
            key = MAIN_PARAMETER.get(cause, "-")
            within = f"{np.sum(errs <= 0.2)}/{len(errs)}" if errs.size else "-"
            med = f"{np.median(errs):8.3f}" if errs.size else f"{'-':>8s}"
            mx = f"{np.max(errs):8.3f}" if errs.size else f"{'-':>8s}"
            gmin = f"{np.min(gains):9.2f}" if gains.size else f"{'-':>9s}"
            gmed = f"{np.median(gains):9.2f}" if gains.size else f"{'-':>9s}"
            print(f"{cause:24s}{form:16s}{right:>7s}{key:>28s}{med}{mx}{within:>7s}{gmin}{gmed}{cpu:9.1f}")


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
    parser.add_argument("--first-seed", type=int, default=100, help="the tests use seeds below 100")
    parser.add_argument("--causes", nargs="*", default=None, help="a subset of the causes (default all)")
    parser.add_argument("--no-nuisance", action="store_true", help="records without nuisance (issue 6's cases)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--skip-hurco", action="store_true")
    parser.add_argument("--skip-shortcuts", action="store_true")
    parser.add_argument("--shortcuts-method", default="default", choices=("default", "h1"))
    args = parser.parse_args(argv)
    if args.seeds > 0:
        causes = args.causes or list(CAUSES)
        print(f"Hidden-effect cases: {len(causes)} causes x {args.seeds} seeds (forms alternating), "
              f"nuisance {'off' if args.no_nuisance else 'on'}, seeds from {args.first_seed}")
        rows = confusion(args.seeds, args.first_seed, nuisance=not args.no_nuisance, causes=causes,
                         workers=args.workers)
        print_confusion(rows)
    if not args.skip_hurco:
        print_hurco()
    if not args.skip_shortcuts:
        print_shortcuts(args.shortcuts_method)


if __name__ == "__main__":
    main()
