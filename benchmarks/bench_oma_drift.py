"""Robomill issue 14: output-only identification of a cut during which the arm's modes drift.

DOMAIN.md's ``pose_drift``: the arm moves along the cut and its modes drift, so the spectra change
over the record, which the stationary models of SSI and of the Whittle refinement do not hold.
Records of the paper's cell (three robot modes; the milling force of the benchmark's cut at 2700
rpm plus the white background force, 20 s at 1 kHz, accelerations) whose every natural frequency
scales by ``1 + change t / T`` over the record, the modal mass and damping ratio fixed. The
response is made by integrating each modal equation exactly over every sample with its
coefficients at that sample (the force held over the sample), nothing of robomill's simulator.
The truth a stationary identification can be held to is the record's mean: each frequency's mean
over the record, and the stiffness at the mean of ``w^2``. Per change and mode: the frequency's
mean and max |error| and its interval's coverage, the damping's median error (drift widens a
peak), and the stiffness's median and max |error| with its interval's coverage; per change, the
records in which ``identify`` names a drifting mode (``drifting_modes``) and those it trusts.

Run: ``python benchmarks/bench_oma_drift.py [--seeds 6] [--changes 0 0.05 0.1 -0.1]`` (about 3
minutes on one core).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from drifting_records import drifting_record  # noqa: E402

from oma._linalg import single_threaded_blas  # noqa: E402
from oma.output_only.identify import identify_output_only  # noqa: E402
from oma.synthetic import paper_like_model  # noqa: E402

def run(change: float, seeds: int):
    model = paper_like_model()
    rows = {k: {"f": [], "fcov": [], "z": [], "k": [], "kcov": [], "found": 0} for k in range(model.n_modes)}
    trusted = named = 0
    for seed in range(seeds):
        rec, scale = drifting_record(change, seed)
        ft = model.natural_frequency_hz * np.mean(scale)
        kt = model.stiffness_N_m * np.mean(scale ** 2)
        res = identify_output_only([rec])
        trusted += res.trusted
        named += bool(res.drifting_modes)
        m, st = res.modes, res.stiffness
        used = set()
        for r in range(model.n_modes):
            cost = np.abs(m.freq_hz / ft[r] - 1) + 0.2 * (1 - np.abs(m.directions @ model.directions[r]))
            cost[list(used)] = np.inf
            j = int(np.argmin(cost)) if cost.size else -1
            if j < 0 or abs(m.freq_hz[j] / ft[r] - 1) > 0.05:
                continue
            used.add(j)
            row = rows[r]
            row["found"] += 1
            row["f"].append(m.freq_hz[j] / ft[r] - 1)
            row["fcov"].append(m.freq_interval_hz[j, 0] <= ft[r] <= m.freq_interval_hz[j, 1])
            row["z"].append(m.damping_ratio[j] / model.damping_ratio[r] - 1)
            if st is not None and np.isfinite(st.stiffness_N_m[j]):
                row["k"].append(st.stiffness_N_m[j] / kt[r] - 1)
                row["kcov"].append(st.interval_N_m[j, 0] <= kt[r] <= st.interval_N_m[j, 1])
    for r, row in rows.items():
        f, z, k = (np.abs(np.array(row[x])) for x in ("f", "z", "k"))
        label = f"{model.natural_frequency_hz[r]:.1f} Hz {'XYZ'[int(np.argmax(np.abs(model.directions[r])))]}"
        print(f"{change:+7.2f} | {label:>9} | {row['found']:2d}/{seeds:<2d} | {100 * f.mean():5.2f} {100 * f.max():5.2f} | "
              f"{np.mean(row['fcov']):4.0%} | {100 * np.median(row['z']):+6.1f} | "
              + (f"{100 * np.median(k):5.2f} {100 * k.max():6.2f} | {np.mean(row['kcov']):4.0%}" if k.size else "  -")
              + (f" | drift named {named}/{seeds}, trusted {trusted}/{seeds}" if r == 0 else ""), flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--changes", type=float, nargs="+", default=[0.0, 0.05, 0.10, -0.10])
    args = ap.parse_args(argv)
    print(f"== the paper's cell, every frequency x (1 + change t / T) over 20 s; {args.seeds} records per change ==")
    print(" change |      mode | found | f |e| % mean max | f cov | zeta err % median | k |e| % median max | k cov")
    with single_threaded_blas():
        for c in args.changes:
            run(c, args.seeds)


if __name__ == "__main__":
    main()
