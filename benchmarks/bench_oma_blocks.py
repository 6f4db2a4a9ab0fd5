"""Robomill issue 14: the output-only refinement on pooled bins against the bins themselves.

A band of 1 000 bins and more is fitted on blocks of adjacent bins pooled where the model
spectrum is flat across them (:mod:`oma.output_only.blocks`). Two tables:

1. Lightly damped, overlapping modes of the kind of the real Hurco files (350 / 357 / 365 Hz at
   0.8 / 1.0 / 2.0 %, a sharp 530 Hz at 0.2 %; accelerations of 15 s at 2 kHz, a white force on
   each axis, 2 % sensor noise), synthesised in the frequency domain (modal superposition:
   nothing of robomill's simulator), refined from starts off by 0.1 % in frequency and a factor
   e^(+-0.3) in damping. Per mode, both ways: the mean |error| of frequency and damping, the
   coverage of the 95 % intervals (frequency and log damping), the pooled estimate's difference
   from the bins' in the bins' standard errors (median and max), and the refinement's CPU (median
   over the records, and its ratio).
2. The real Hurco accelerations (no truth): CPU of ``identify --output-only`` both ways (median of
   ``--repeats`` runs each, the same process) and the modes each way.

Run: ``python benchmarks/bench_oma_blocks.py [--seeds 20] [--repeats 3] [--no-hurco]`` (about 3
minutes with the Hurco files on one core).
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from bench_oma_output_only import hurco_record  # noqa: E402
from frequency_domain_records import modal_superposition  # noqa: E402
from robot_helpers import shared_dir  # noqa: E402  (the one locator of ../shared, tests and benchmarks)

import oma.output_only.ml as ml  # noqa: E402
from oma._linalg import single_threaded_blas  # noqa: E402

FS, DURATION = 2000.0, 15.0
MODES = [(350.0, 0.008, [1, 0.3, 0.1]), (357.0, 0.010, [0.2, 1, 0.3]), (365.0, 0.02, [0.3, 0.2, 1]),
         (530.0, 0.002, [1, 1, 0.2])]
Z95 = 1.959964


def record(seed):
    """Accelerations (3, n) of :data:`MODES` under a white force on each axis, 2 % sensor noise."""
    return modal_superposition(MODES, FS, DURATION, seed)


@contextlib.contextmanager
def bins_only(on: bool):
    """The refinement without pooling (``on``), restored after."""
    orig = ml.block_bins
    if on:
        ml.block_bins = lambda *a, **k: None
    try:
        yield
    finally:
        ml.block_bins = orig


def synthetic(seeds: int):
    ft = np.array([m[0] for m in MODES])
    zt = np.array([m[1] for m in MODES])
    u0 = np.array([np.asarray(m[2], dtype=float) / np.linalg.norm(m[2]) for m in MODES]).T
    out = {k: [] for k in ("bins", "pooled")}
    cpu = {k: [] for k in out}
    for seed in range(seeds):
        x = record(seed)
        rng = np.random.default_rng(1000 + seed)
        f0 = ft * (1 + 0.001 * rng.standard_normal(ft.size))
        z0 = zt * np.exp(0.3 * rng.standard_normal(ft.size))
        for way in out:
            with bins_only(way == "bins"):
                t0 = time.process_time()
                r = ml.refine_modes_ml([x], FS, f0, z0, u0, derivative=2, band_hz=(20.0, 900.0))
                cpu[way].append(time.process_time() - t0)
            out[way].append((r.freq_hz[:ft.size], r.damping[:ft.size], r.standard_errors[:2, :ft.size]))
    print(f"\n== lightly damped modes, {seeds} records of {DURATION:g} s at {FS:g} Hz: pooled bins against the bins ==")
    print("      mode | way    | f mean|e| % | zeta mean|e| % | f cov | zeta cov | pooled - bins, in the bins' se: f med/max, log zeta med/max")
    for j, (fr, z, _) in enumerate(MODES):
        for way in out:
            f = np.array([o[0][j] for o in out[way]])
            zz = np.array([o[1][j] for o in out[way]])
            se = np.array([o[2][:, j] for o in out[way]])
            fcov = np.mean(np.abs(f - fr) <= Z95 * se[:, 0])
            zcov = np.mean(np.abs(np.log(zz / z)) <= Z95 * se[:, 1])
            line = (f"{fr:6.0f} Hz {100 * z:4.1f} % | {way:6s} | {100 * np.mean(np.abs(f / fr - 1)):11.3f} | "
                    f"{100 * np.mean(np.abs(zz / z - 1)):14.2f} | {fcov:5.0%} | {zcov:8.0%} |")
            if way == "pooled":
                fb = np.array([o[0][j] for o in out["bins"]])
                zb = np.array([o[1][j] for o in out["bins"]])
                seb = np.array([o[2][:, j] for o in out["bins"]])
                df = np.abs(f - fb) / seb[:, 0]
                dz = np.abs(np.log(zz / zb)) / seb[:, 1]
                line += f" {np.median(df):.3f} / {df.max():.3f}, {np.median(dz):.3f} / {dz.max():.3f}"
            print(line)
    cb, cp = statistics.median(cpu["bins"]), statistics.median(cpu["pooled"])
    print(f"refinement CPU median: bins {cb:.2f} s, pooled {cp:.2f} s (ratio {cp / cb:.2f})")


def hurco(repeats: int):
    from oma.output_only.identify import identify_output_only

    folder = shared_dir() / "data" / "milling-vibration-hurco"
    files = sorted(folder.glob("EBI_*.csv"))
    if not files:
        print(f"\n(no Hurco files under {folder}; set ROBOMILL_SHARED)")
        return
    print(f"\n== real Hurco accelerations: identify CPU (median of {repeats}) and modes, bins against pooled bins ==")
    print(f"{'file':>36} | cut s | bins: CPU s per 20 s | pooled: CPU s per 20 s | modes (Hz / %) where they differ")
    warm = True
    for path in files:
        rec = hurco_record(path)
        if rec is None:
            continue
        dur = rec.data.shape[1] / rec.sample_rate_hz
        if warm:   # the compiled loops loaded once before any timing
            identify_output_only([rec], band_hz=(20.0, 600.0), alias_up_to=4.0)
            warm = False
        res, cpus = {}, {}
        for way in ("bins", "pooled"):
            with bins_only(way == "bins"):
                ts = []
                for _ in range(repeats):
                    t0 = time.process_time()
                    m = identify_output_only([rec], band_hz=(20.0, 600.0), alias_up_to=4.0).modes
                    ts.append(time.process_time() - t0)
            res[way], cpus[way] = m, statistics.median(ts)
        same = res["bins"].n_modes == res["pooled"].n_modes and np.allclose(
            res["bins"].freq_hz, res["pooled"].freq_hz, rtol=1e-4) and np.allclose(
            res["bins"].damping_ratio, res["pooled"].damping_ratio, rtol=1e-2)
        desc = "same" if same else " | ".join(
            ", ".join(f"{f:.1f}/{100 * z:.2f}" for f, z in zip(res[w].freq_hz, res[w].damping_ratio)) for w in res)
        name = path.name.removeprefix("EBI_").removesuffix(".csv")
        print(f"{name:>36} | {dur:5.1f} | {cpus['bins']:5.2f} {20 * cpus['bins'] / dur:5.2f} | "
              f"{cpus['pooled']:5.2f} {20 * cpus['pooled'] / dur:5.2f} | {desc}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-hurco", action="store_true")
    args = ap.parse_args(argv)
    with single_threaded_blas():
        synthetic(args.seeds)
        if not args.no_hurco:
            hurco(args.repeats)


if __name__ == "__main__":
    main()
