"""Robomill issue 14: ``identify --output-only`` (and ``identify``) against the record's sampling rate.

Shop accelerometers record at 5-51.2 kHz; the issue's target (3 s CPU per 20 s record) is set at
1 kHz. Per rate: 20 s of the paper cell's accelerations (the benchmark's tooth case, 2700 rpm),
``identify --output-only`` as shipped (records decimated to the rate the analysis needs,
:mod:`oma.decimation`) and at the recorded rate throughout (``decimate=False``, the
baseline), each in a fresh process per run (its peak memory is that run's): the median CPU of
``--repeats`` runs, the ratio of the baseline's to the shipped, the peak resident memory, the rate
analysed, and the modes both ways.

Run: ``python benchmarks/bench_oma_sample_rate.py [--rates 1000 2500 5000 10000 25600]
[--repeats 3]`` (about 10 minutes on one core with 51.2 kHz).

``--force-based [--seeds N]`` (session 31): the force-based ``identify`` instead, on 20 s of force
and acceleration whose background force keeps the benchmark's spectral level at every rate (its
variance grows with the rate), seeds 1..N (default 3), each run in a fresh process, decimated and
undecimated: the median CPU over the seeds, the largest peak memory, and in how many seeds the
model is exactly the three true modes (each within 1 % in frequency, 10 % in damping and stiffness)
and trusted (about 10 minutes for 1, 5 and 10 kHz, 3 seeds; 25.6 kHz undecimated takes 2-3 minutes
and 7 GB per seed).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_ONE_RUN = """
import json, resource, sys, time
sys.path.insert(0, {bench!r})
from bench_oma_output_only import TRUTH
from oma._linalg import single_threaded_blas
from oma.output_only.identify import identify_output_only
from oma.synthetic import synthetic_record
fs = {fs!r}
decimate = {decimate!r}
rec = synthetic_record(TRUTH, duration_s=20.0, sample_rate_hz=fs, output="acceleration", rng=3, spindle_rpm=2700.0)
identify_output_only([synthetic_record(TRUTH, duration_s=2.0, output="acceleration", rng=1)])   # compiled kernels
with single_threaded_blas():
    t0 = time.process_time()
    res = identify_output_only([rec], decimate=decimate)
    cpu = time.process_time() - t0
m = res.modes
print(json.dumps({{"cpu": cpu, "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "analysis_rate_hz": res.analysis_rate_hz,
                  "modes": [[float(f), float(z)] for f, z in zip(m.freq_hz, m.damping_ratio)]}}))
"""


_ONE_FORCE_BASED = """
import json, resource, time
import numpy as np
from oma.identify import identify
from oma.synthetic import PAPER_BACKGROUND_VARIANCE_N2, paper_like_model, synthetic_record
fs, seed, decimate = {fs!r}, {seed!r}, {decimate!r}
truth = paper_like_model()
rec = synthetic_record(truth, duration_s=20.0, sample_rate_hz=fs, rng=seed, output="acceleration",
                       background_variance_N2=tuple(np.array(PAPER_BACKGROUND_VARIANCE_N2) * fs / 1000.0))
t0 = time.process_time()
res = identify([rec], decimate=decimate)
cpu = time.process_time() - t0
m = res.model
exact = m.n_modes == 3
for a in range(3):
    j = int(np.argmax(np.abs(m.directions[:, a])))
    exact &= bool(abs(m.natural_frequency_hz[j] / truth.natural_frequency_hz[a] - 1) < 0.01
                  and abs(m.damping_ratio[j] / truth.damping_ratio[a] - 1) < 0.1
                  and abs(m.stiffness_N_m[j] / truth.stiffness_N_m[a] - 1) < 0.1)
print(json.dumps({{"cpu": cpu, "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "analysis_rate_hz": res.analysis_rate_hz, "exact": bool(exact), "trusted": bool(res.trusted),
                  "modes": [[float(f), float(z)] for f, z in zip(m.natural_frequency_hz, m.damping_ratio)]}}))
"""


def one_run(fs: float, decimate: bool, seed: int | None = None) -> dict:
    """One identification of a 20 s record at ``fs`` in a fresh process (force-based with a seed)."""
    if seed is None:
        code = _ONE_RUN.format(bench=str(ROOT / "benchmarks"), fs=float(fs), decimate=bool(decimate))
    else:
        code = _ONE_FORCE_BASED.format(fs=float(fs), seed=int(seed), decimate=bool(decimate))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _modes(modes) -> str:
    return ", ".join(f"{f:.2f} / {100 * z:.2f}" for f, z in modes)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[1000.0, 2500.0, 5000.0, 10000.0, 25600.0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--force-based", action="store_true", help="the force-based identify (session 31)")
    ap.add_argument("--seeds", type=int, default=3, help="records per rate with --force-based")
    args = ap.parse_args(argv)
    if args.force_based:
        return force_based(sorted(args.rates), args.seeds)
    rows = _measure(sorted(args.rates), lambda fs, decimate: [one_run(fs, decimate) for _ in range(args.repeats)])
    print(f"20 s accelerations of the paper cell, tooth case; median of {args.repeats} runs, one core")
    print("| rate (Hz) | analysed at (Hz) | CPU (s) | CPU undecimated (s) | ratio | peak memory (MB) | "
          "undecimated (MB) | modes (Hz / % damping) | undecimated |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for fs, (cpu, rss, runs), (cpu_f, rss_f, runs_f) in rows:
        print(f"| {fs:g} | {runs[-1]['analysis_rate_hz']:g} | {cpu:.2f} | {cpu_f:.2f} | {cpu_f / cpu:.1f} | {rss:.0f} | "
              f"{rss_f:.0f} | {_modes(runs[-1]['modes'])} | {_modes(runs_f[-1]['modes'])} |")
    return 0


def _measure(rates, runs_of):
    """Per rate, shipped and undecimated: (median CPU, largest peak memory, the runs) of
    ``runs_of(fs, decimate)``."""
    rows = []
    for fs in rates:
        both = []
        for decimate in (True, False):
            runs = runs_of(fs, decimate)
            both.append((statistics.median(r["cpu"] for r in runs), max(r["rss_mb"] for r in runs), runs))
        rows.append((fs, *both))
        print(f"  {fs:g} Hz done", file=sys.stderr, flush=True)
    return rows


def force_based(rates, seeds) -> int:
    rows = _measure(rates, lambda fs, decimate: [one_run(fs, decimate, seed) for seed in range(1, seeds + 1)])
    print(f"20 s of force and acceleration of the paper cell, force-based identify; seeds 1-{seeds}, one core")
    print("| rate (Hz) | analysed at (Hz) | CPU median (s) | undecimated (s) | ratio | peak memory (MB) | "
          "undecimated (MB) | true modes, trusted | undecimated |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")

    def ok(runs):
        return f"{sum(r['exact'] and r['trusted'] for r in runs)} of {len(runs)}"

    for fs, (cpu, rss, runs), (cpu_f, rss_f, runs_f) in rows:
        print(f"| {fs:g} | {runs[0]['analysis_rate_hz']:g} | {cpu:.2f} | {cpu_f:.2f} | {cpu_f / cpu:.1f} | {rss:.0f} | "
              f"{rss_f:.0f} | {ok(runs)} | {ok(runs_f)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
