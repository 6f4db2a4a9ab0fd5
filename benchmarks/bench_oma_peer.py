"""Robomill's modal fit side by side with sdypy-EMA (LSCF poles + LSFD constants).

1. Synthetic FRFs: a roving-hammer row (one response, three excitations) of a known three-mode
   system with 1 % complex noise, several seeds; both tools' modes against the truth.
2. Real data: the measured accelerance FRFs of ``shared/data/frf-uff58/measurement.uff`` (pyuff's
   example file, 0-1000 Hz, peaks near 142, 279, 460, 687, 959 Hz); both tools' five modes and the
   relative fit error of each reconstruction on the measured accelerance.

Run: ``python benchmarks/bench_oma_peer.py`` (needs the test extra sdypy-EMA).
"""

from __future__ import annotations

import os
import time
import warnings

import numpy as np

from oma.fit import fit_poles_residues, prune_modes, relative_fit_error, stabilisation_diagram
from oma.modal import ModalModel

UFF = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "frf-uff58", "measurement.uff")
TRUTH = ModalModel([142.0, 279.0, 460.0], [0.01, 0.02, 0.015], [2e6, 5e6, 8e6],
                   [[1, 0.5, 0.2], [0.3, 1, -0.4], [-0.6, 0.2, 1]])


def sdypy_fit(freq, frf, approx_hz, *, lower, upper, form, order=60):
    """sdypy-EMA's LSCF poles closest to ``approx_hz`` and its LSFD reconstruction.

    Returns natural frequencies, damping ratios, the reconstructed FRFs and the measured FRFs on
    sdypy's own frequency grid (it expects the grid to start at 0 Hz and trims it to ``upper``).
    """
    import contextlib
    import io

    from sdypy import EMA

    with warnings.catch_warnings(), contextlib.redirect_stderr(io.StringIO()):
        warnings.simplefilter("ignore")
        m = EMA.Model(frf=frf, freq=freq, lower=lower, upper=upper, pol_order_high=order, frf_form=form)
        m.get_poles(show_progress=False)
        m.select_closest_poles(list(approx_hz), f_window=max(10.0, 0.05 * min(approx_hz)))
        h, _ = m.get_constants(whose_poles="own", FRF_ind="all")
    return np.asarray(m.nat_freq), np.asarray(m.nat_xi), np.asarray(h), np.asarray(m.freq), np.asarray(m.frf)


def nearest(fs, zs, target):
    i = int(np.argmin(np.abs(np.asarray(fs) - target)))
    return fs[i], zs[i]


def synthetic(seeds=5):
    print("== synthetic roving-hammer row, 3 modes, 1 % noise ==")
    print(f"{'seed':>4} {'mode':>6} | {'robomill f (Hz)':>15} {'zeta':>8} | {'sdypy f (Hz)':>13} {'zeta':>8} | "
          f"{'truth f':>8} {'zeta':>7}")
    errs = {"robomill": [], "sdypy": []}
    for seed in range(seeds):
        f = np.arange(1.0, 600.0, 0.5)
        frf = TRUTH.receptance(f)[0]
        rng = np.random.default_rng(seed)
        h = frf + 0.01 * np.abs(frf).max() * (rng.standard_normal(frf.shape) + 1j * rng.standard_normal(frf.shape)) / np.sqrt(2)
        band = (f > 50) & (f < 599)
        diag = stabilisation_diagram(f[band], h[:, band], max_order=30)
        fit = fit_poles_residues(f[band], h[:, band], diag.natural_frequency_hz, diag.damping_ratio)
        sf, sz, *_ = sdypy_fit(np.r_[0.0, f], np.hstack([np.zeros((3, 1)), h]), TRUTH.natural_frequency_hz,
                                lower=50, upper=599, form="receptance", order=40)
        for fn, zeta in zip(TRUTH.natural_frequency_hz, TRUTH.damping_ratio):
            rf, rz = nearest(fit.natural_frequency_hz, fit.damping_ratio, fn)
            pf, pz = nearest(sf, sz, fn)
            errs["robomill"].append((rf / fn - 1, rz / zeta - 1))
            errs["sdypy"].append((pf / fn - 1, pz / zeta - 1))
            print(f"{seed:4d} {fn:6.0f} | {rf:15.3f} {rz:8.4f} | {pf:13.3f} {pz:8.4f} | {fn:8.1f} {zeta:7.4f}")
    for tool, e in errs.items():
        e = np.abs(np.array(e)) * 100
        print(f"{tool:>9}: max |error| frequency {e[:, 0].max():.3f} %, damping {e[:, 1].max():.1f} % "
              f"(targets 1 % and 10 %)")


def real():
    print("\n== measured accelerance, measurement.uff (1 response, 3 excitations) ==")
    try:
        from oma.frf_io import read_uff58_functions

        funcs = read_uff58_functions(UFF)
        f = funcs[0].freq_hz
        acc = np.array([fn.measured for fn in funcs])
        rec = np.array([fn.receptance_m_N for fn in funcs])
    except ImportError:  # the reader is another module's; fall back on pyuff directly
        import pyuff

        sets = pyuff.UFF(UFF).read_sets()
        f = np.real(sets[0]["x"])[1:]
        acc = np.array([s["data"][1:] for s in sets])
        rec = acc / (-(2 * np.pi * f) ** 2)
    band = (f >= 50) & (f <= 1000)
    f_b, acc_b, rec_b = f[band], acc[:, band], rec[:, band]
    w2 = (2 * np.pi * f_b) ** 2
    t0 = time.perf_counter()
    # weights w^2 on the receptance = uniform weights on the measured accelerance
    diag = stabilisation_diagram(f_b, acc_b, max_order=60)
    order = np.argsort(diag.natural_frequency_hz)
    opts = dict(weights=np.broadcast_to(w2, rec_b.shape), upper_residual=True, lower_residual=True, complex_modes=True)
    fit = fit_poles_residues(f_b, rec_b, diag.natural_frequency_hz[order], diag.damping_ratio[order], **opts)
    fit = prune_modes(f_b, rec_b, fit, **opts)
    t_r = time.perf_counter() - t0
    acc_fit = -w2 * fit.evaluate(f_b)
    err_r = relative_fit_error(acc_b, acc_fit)
    approx = [142, 279, 460, 687, 959]
    import pyuff

    raw = pyuff.UFF(UFF).read_sets()  # sdypy wants the file's own grid, from 0 Hz
    t0 = time.perf_counter()
    sf, sz, h_s, f_s, acc_s = sdypy_fit(np.real(raw[0]["x"]), np.array([d["data"] for d in raw]), approx,
                                        lower=50, upper=1000, form="accelerance", order=60)
    t_s = time.perf_counter() - t0
    sel_s = (f_s >= 50) & (f_s <= 1000)
    err_s = relative_fit_error(acc_s[:, sel_s], h_s[:, sel_s])
    print(f"{'':>10} {'robomill f (Hz)':>15} {'zeta':>8} | {'sdypy f (Hz)':>13} {'zeta':>8}")
    for target in approx:
        rf, rz = nearest(fit.natural_frequency_hz, fit.damping_ratio, target)
        pf, pz = nearest(sf, sz, target)
        print(f"{'~' + str(target):>10} {rf:15.2f} {rz:8.4f} | {pf:13.2f} {pz:8.4f}")
    extra = [x for x in fit.natural_frequency_hz if np.min(np.abs(np.array(approx) - x)) > 20]
    print(f"robomill modes: {fit.n_modes} ({len(extra)} beyond the five: {np.round(extra, 1).tolist()})")
    print("relative fit error on the accelerance, per FRF (50-1000 Hz):")
    print(f"   robomill: {np.round(err_r, 4).tolist()}  ({t_r:.2f} s)")
    print(f"   sdypy   : {np.round(err_s, 4).tolist()}  ({t_s:.2f} s)")


if __name__ == "__main__":
    synthetic()
    real()
