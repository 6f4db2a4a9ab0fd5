"""Robomill issue 14: output-only identification on records robomill's simulator did not make.

Each record is synthesised in the frequency domain (``tests/frequency_domain_records.py``: modal
superposition of real modes under a white force on each axis, periodic over the record, 2 % white
sensor noise; no milling lines, so nothing is scaled and every model is untrusted) and identified by
``identify_output_only`` as shipped. Structures chosen to differ from the benchmark's cell: a sharp
mode beside a close pair (its tail runs through their band), a sharp mode below a pair, lightly
damped modes far apart, three modes 7 % apart, the Hurco files' kind of cluster at 350-365 Hz, and
the paper's cell and the oblique probe for reference. On request (``--structures paper_coupled``)
a physical system whose damping is not proportional (the paper's cell with a damper between X and
Z: complex modes; ``physical_superposition``), and (``gyro_5``, ``gyro_10``, ``gyro_20``) a pair at
20 / 23 Hz whose X and Y are coupled by a gyroscopic (skew) term of 5, 10 or 20 per second
(whirling modes, complexity 0.03-0.35). Per structure: records with exactly the true modes,
modes missed and false, the frequency's mean and max |error|, the coverage of the 95 %
frequency and damping intervals, and how many records named a mode complex (``complex_modes``).

Run: ``python benchmarks/bench_oma_independent.py [--seeds 10] [--structures ...] [--noise 0.02]
[--quantity acceleration|velocity|displacement] [--force-slope 0] [--duration S]`` (about 4 minutes
for 10 seeds on one core). The options vary the records away from the defaults: more sensor noise,
another measured quantity, a coloured force (its power going as ``f^slope``), shorter records.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from frequency_domain_records import (gyroscopic_pair, modal_superposition, physical_modes,  # noqa: E402
                                     physical_superposition)

from oma._linalg import single_threaded_blas  # noqa: E402
from oma.output_only.identify import identify_output_only  # noqa: E402
from oma.record import Channel, Record  # noqa: E402
from oma.synthetic import paper_like_cut, paper_like_tool  # noqa: E402

C30, S30 = np.cos(np.pi / 6), np.sin(np.pi / 6)
#: name: (modes (frequency Hz, damping ratio, direction), sample rate Hz, duration s, band Hz)
STRUCTURES = {
    "paper": ([(10.5, 0.05, [1, 0, 0]), (24.8, 0.04, [0, 1, 0]), (10.0, 0.05, [0, 0, 1])], 1000.0, 20.0, (4.0, 100.0)),
    "oblique": ([(12.0, 0.04, [C30, S30, 0]), (26.0, 0.03, [-S30, C30, 0]), (17.0, 0.05, [0, 0, 1])],
                1000.0, 20.0, (4.0, 100.0)),
    "sharp_above": ([(20.0, 0.03, [1, 0, 0]), (23.0, 0.03, [0, 1, 0.3]), (52.0, 0.005, [1, 1, 0])],
                    1000.0, 20.0, (4.0, 100.0)),
    "sharp_below": ([(15.0, 0.004, [1, 0, 1]), (30.0, 0.03, [1, 0, 0]), (33.0, 0.04, [0, 1, 0])],
                    1000.0, 20.0, (4.0, 100.0)),
    "light_apart": ([(50.0, 0.01, [1, 0, 0]), (120.0, 0.008, [0, 1, 0]), (200.0, 0.01, [0, 0, 1])],
                    1000.0, 20.0, (20.0, 400.0)),
    "three_close": ([(40.0, 0.015, [1, 0, 0]), (43.0, 0.015, [0, 1, 0]), (46.0, 0.02, [0, 0, 1])],
                    1000.0, 20.0, (10.0, 150.0)),
    "hurco_like": ([(350.0, 0.008, [1, 0.3, 0.1]), (357.0, 0.010, [0.2, 1, 0.3]), (365.0, 0.02, [0.3, 0.2, 1]),
                    (530.0, 0.002, [1, 1, 0.2])], 2000.0, 15.0, (200.0, 800.0)),
}



def _coupled_paper(c_xz: float):
    """The paper's cell as a physical system of unit masses along X, Y, Z, with a damper of
    ``c_xz`` (N s/m per kg) between X and Z: damping no longer proportional, so the close pair's
    modes are complex (``c_xz = 2``: complexity 0.22-0.24, damping 6.6 / 6.5 %, 10.06 / 10.44 Hz)."""
    w = 2 * np.pi * np.array([10.5, 24.8, 10.0])
    zeta = np.array([0.05, 0.04, 0.05])
    coupling = c_xz * np.array([[1.0, 0.0, -1.0], [0.0, 0.0, 0.0], [-1.0, 0.0, 1.0]])
    return np.eye(3), np.diag(2 * zeta * w) + coupling, np.diag(w ** 2)


#: Physical systems (mass, damping, stiffness matrices), sample rate Hz, duration s, band Hz: the
#: truth is the state matrix's poles (:func:`physical_modes`).
PHYSICAL = {"paper_coupled": (_coupled_paper(2.0), 1000.0, 20.0, (4.0, 100.0)),
            **{f"gyro_{g}": (gyroscopic_pair(float(g)), 1000.0, 20.0, (4.0, 100.0)) for g in (5, 10, 20)}}

QUANTITIES = {"displacement": ("m", 0), "velocity": ("m/s", 1), "acceleration": ("m/s2", 2)}


def record(name: str, seed: int, *, noise: float = 0.02, quantity: str = "acceleration", force_slope: float = 0.0,
           duration_s: float | None = None) -> Record:
    unit, derivative = QUANTITIES[quantity]
    if name in PHYSICAL:
        if force_slope:
            raise ValueError("a physical system's records have a white force (no --force-slope)")
        system, fs, duration, _ = PHYSICAL[name]
        y = physical_superposition(*system, fs, duration if duration_s is None else duration_s, seed,
                                   derivative=derivative, noise=noise)
    else:
        modes, fs, duration, _ = STRUCTURES[name]
        y = modal_superposition(modes, fs, duration if duration_s is None else duration_s, seed,
                                derivative=derivative, noise=noise, force_slope=force_slope)
    channels = tuple(Channel(a.lower(), quantity, a, unit) for a in "XYZ")
    return Record(fs, channels, y, paper_like_tool(), paper_like_cut(), name=f"{name}-{seed}")


def run(name: str, seeds: int, **variant):
    if name in PHYSICAL:
        system, _, _, band = PHYSICAL[name]
        ft, zt, _ = physical_modes(*system)
    else:
        modes, _, _, band = STRUCTURES[name]
        ft = np.array([m[0] for m in modes])
        zt = np.array([m[1] for m in modes])
    exact = missed = false = named = 0
    ferr, fcov, zcov = [], [], []
    for seed in range(seeds):
        res = identify_output_only([record(name, seed, **variant)], band_hz=band)
        m = res.modes
        named += bool(res.complex_modes)
        used = np.zeros(m.n_modes, dtype=bool)
        found = 0
        for f, z in zip(ft, zt):
            d = np.abs(m.freq_hz / f - 1)
            d[used] = np.inf
            k = int(np.argmin(d)) if d.size else -1
            if k < 0 or d[k] > 0.03:
                missed += 1
                continue
            used[k] = True
            found += 1
            ferr.append(abs(m.freq_hz[k] / f - 1))
            lo, hi = m.freq_interval_hz[k]
            fcov.append(lo <= f <= hi)
            zlo, zhi = m.damping_interval[k]
            zcov.append(zlo <= z <= zhi)
        false += int(np.sum(~used))
        exact += found == ft.size and not np.any(~used)
    ferr = np.array(ferr)
    print(f"{name:>12} | {exact:3d}/{seeds:<3d} | {missed:6d} | {false:5d} | {100 * ferr.mean():6.3f} {100 * ferr.max():6.3f} | "
          f"{np.mean(fcov):5.0%} | {np.mean(zcov):8.0%} | {named:3d}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--structures", nargs="+", default=list(STRUCTURES),
                    help=f"of {', '.join([*STRUCTURES, *PHYSICAL])} (default: all but the physical systems)")
    ap.add_argument("--noise", type=float, default=0.02, help="sensor noise, times the response's sd (0.02)")
    ap.add_argument("--quantity", choices=list(QUANTITIES), default="acceleration")
    ap.add_argument("--force-slope", type=float, default=0.0,
                    help="the force's power spectrum goes as f^slope (0: white, -1: pink)")
    ap.add_argument("--duration", type=float, default=None, help="record length, s (default: the structure's)")
    args = ap.parse_args(argv)
    variant = dict(noise=args.noise, quantity=args.quantity, force_slope=args.force_slope, duration_s=args.duration)
    print(f"== records of modal superposition in the frequency domain, {args.seeds} per structure; "
          f"{args.quantity}, sensor noise {args.noise:g}, force slope {args.force_slope:g}, "
          f"duration {'as listed' if args.duration is None else f'{args.duration:g} s'} ==")
    print("   structure | exact   | missed | false | f |e| % mean  max | f cov | zeta cov | complex named")
    with single_threaded_blas():
        for name in args.structures:
            run(name, args.seeds, **variant)


if __name__ == "__main__":
    main()
