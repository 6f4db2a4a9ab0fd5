"""Robomill's modal fit side by side with sdypy-EMA (LSCF poles + LSFD constants).

1. Synthetic FRFs: a roving-hammer row (one response, three excitations) of a known three-mode
   system with 1 % complex noise, several seeds; both tools' modes against the truth. Robomill
   chooses the number of modes itself (stabilisation diagram, then :func:`oma.fit.prune_modes`);
   sdypy is told the true frequencies.
2. The same with correlated noise (a smooth error along frequency, as a windowed estimate or a
   systematic measurement error gives): how many modes robomill keeps. An information criterion
   that counted every line as an independent datum would buy extra modes with such an error.
3. Real data: the measured accelerance FRFs of ``shared/data/frf-uff58/measurement.uff`` (pyuff's
   example file, 0-1000 Hz at 1 Hz). Its resonance peaks are found in the data (local maxima of
   the summed magnitude standing out of the FRF's median level); robomill fits without being told
   them, sdypy is given (a) the five peaks the data README lists and (b) the peaks found in the
   data. Printed: both tools' modes, the relative fit error of each reconstruction against the
   measured accelerance, and the time each takes.

Run: ``python benchmarks/bench_oma_peer.py`` (needs the test extra sdypy-EMA).
"""

from __future__ import annotations

import contextlib
import io
import os
import time
import warnings

import numpy as np
from scipy.signal import find_peaks

from oma._linalg import single_threaded_blas
from oma.fit import fit_poles_residues, prune_modes, relative_fit_error
from oma.lscf import stabilisation_diagram
from oma.modal import ModalModel

UFF = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "frf-uff58", "measurement.uff")
TRUTH = ModalModel([142.0, 279.0, 460.0], [0.01, 0.02, 0.015], [2e6, 5e6, 8e6],
                   [[1, 0.5, 0.2], [0.3, 1, -0.4], [-0.6, 0.2, 1]])
#: Peaks of the real file as its data README lists them, Hz.
README_PEAKS_HZ = (142.0, 279.0, 460.0, 687.0, 959.0)


def sdypy_fit(freq, frf, approx_hz, *, lower, upper, form, order=60):
    """sdypy-EMA's LSCF poles closest to ``approx_hz`` and its LSFD reconstruction.

    Returns natural frequencies, damping ratios, the reconstructed FRFs and the measured FRFs on
    sdypy's own frequency grid (it expects the grid to start at 0 Hz and trims it to ``upper``).
    """
    from sdypy import EMA

    # one BLAS thread, as robomill's fit uses: threaded BLAS on a shared, loaded machine slows
    # either tool down by up to an order of magnitude, which would measure the load, not the method
    with warnings.catch_warnings(), contextlib.redirect_stderr(io.StringIO()), \
            contextlib.redirect_stdout(io.StringIO()), single_threaded_blas():
        warnings.simplefilter("ignore")
        m = EMA.Model(frf=frf, freq=freq, lower=lower, upper=upper, pol_order_high=order, frf_form=form)
        m.get_poles(show_progress=False)
        m.select_closest_poles(list(approx_hz), f_window=max(10.0, 0.05 * min(approx_hz)))
        h, _ = m.get_constants(whose_poles="own", FRF_ind="all")
    return np.asarray(m.nat_freq), np.asarray(m.nat_xi), np.asarray(h), np.asarray(m.freq), np.asarray(m.frf)


def robomill_fit(freq, frf, *, max_order, weights=None, **opts):
    """Robomill's automatic pole-residue fit: diagram, nonlinear least squares, mode selection."""
    diag = stabilisation_diagram(freq, frf if weights is None else frf * weights, max_order=max_order)
    order = np.argsort(diag.natural_frequency_hz)
    fit = fit_poles_residues(freq, frf, diag.natural_frequency_hz[order], diag.damping_ratio[order],
                             weights=weights, **opts)
    return prune_modes(freq, frf, fit, weights=weights, **opts), diag


def nearest(fs, zs, target):
    i = int(np.argmin(np.abs(np.asarray(fs) - target)))
    return fs[i], zs[i]


def noisy_row(seed, *, amplitude=0.01, smooth_lines=1):
    """Row 0 of the truth's receptance with complex noise of ``amplitude`` times its peak.

    ``smooth_lines > 1`` correlates the noise along frequency (Hann-window moving average,
    unit power gain), as a windowed spectral estimate or a slowly varying systematic error does.
    """
    f = np.arange(1.0, 600.0, 0.5)
    frf = TRUTH.receptance(f)[0]
    rng = np.random.default_rng(seed)
    e = (rng.standard_normal(frf.shape) + 1j * rng.standard_normal(frf.shape)) / np.sqrt(2)
    if smooth_lines > 1:
        k = np.hanning(smooth_lines + 2)[1:-1]
        k /= np.sqrt(np.sum(k**2))
        e = np.array([np.convolve(x, k, mode="same") for x in e])
    return f, frf + amplitude * np.abs(frf).max() * e


def synthetic(seeds=5):
    print("== synthetic roving-hammer row, 3 modes, 1 % white noise ==")
    print(f"{'seed':>4} {'mode':>6} | {'robomill f (Hz)':>15} {'zeta':>8} | {'sdypy f (Hz)':>13} {'zeta':>8} | "
          f"{'truth f':>8} {'zeta':>7}")
    errs = {"robomill": [], "sdypy": []}
    times = {"robomill": 0.0, "sdypy": 0.0}
    n_kept = []
    for seed in range(seeds):
        f, h = noisy_row(seed)
        band = (f > 50) & (f < 599)
        t0 = time.perf_counter()
        fit, _ = robomill_fit(f[band], h[:, band], max_order=30)
        times["robomill"] += time.perf_counter() - t0
        n_kept.append(fit.n_modes)
        t0 = time.perf_counter()
        sf, sz, *_ = sdypy_fit(np.r_[0.0, f], np.hstack([np.zeros((3, 1)), h]), TRUTH.natural_frequency_hz,
                               lower=50, upper=599, form="receptance", order=40)
        times["sdypy"] += time.perf_counter() - t0
        for fn, zeta in zip(TRUTH.natural_frequency_hz, TRUTH.damping_ratio):
            rf, rz = nearest(fit.natural_frequency_hz, fit.damping_ratio, fn)
            pf, pz = nearest(sf, sz, fn)
            errs["robomill"].append((rf / fn - 1, rz / zeta - 1))
            errs["sdypy"].append((pf / fn - 1, pz / zeta - 1))
            print(f"{seed:4d} {fn:6.0f} | {rf:15.3f} {rz:8.4f} | {pf:13.3f} {pz:8.4f} | {fn:8.1f} {zeta:7.4f}")
    for tool, e in errs.items():
        e = np.abs(np.array(e)) * 100
        print(f"{tool:>9}: max |error| frequency {e[:, 0].max():.3f} %, damping {e[:, 1].max():.1f} % "
              f"(targets 1 % and 10 %); {times[tool] / seeds:.2f} s per fit")
    print(f"robomill modes kept per seed (truth 3, found by itself): {n_kept}")


def correlated(seeds=8, smooth_lines=9):
    print(f"\n== synthetic row, 1 % noise correlated over {smooth_lines} lines: modes robomill keeps ==")
    for seed in range(seeds):
        f, h = noisy_row(seed, smooth_lines=smooth_lines)
        band = (f > 50) & (f < 599)
        fit, diag = robomill_fit(f[band], h[:, band], max_order=30)
        spurious = [x for x in fit.natural_frequency_hz if np.min(np.abs(TRUTH.natural_frequency_hz / x - 1)) > 0.01]
        print(f"seed {seed}: diagram candidates {np.round(np.sort(diag.natural_frequency_hz), 1).tolist()}, "
              f"kept {np.round(fit.natural_frequency_hz, 1).tolist()}, spurious {len(spurious)}")


def read_real():
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
    return f, acc, rec


def data_peaks(freq, frf):
    """Resonance peaks of measured FRFs: local maxima of the summed magnitude whose prominence
    exceeds the median magnitude (a peak at least doubling the FRF's typical level)."""
    s = np.sum(np.abs(frf), axis=0)
    k, _ = find_peaks(s, prominence=np.median(s))
    return freq[k]


def real(lower_hz=50.0, upper_hz=1000.0):
    print(f"\n== measured accelerance, measurement.uff (1 response, 3 excitations), {lower_hz:g}-{upper_hz:g} Hz ==")
    f, acc, rec = read_real()
    band = (f >= lower_hz) & (f <= upper_hz)
    f_b, acc_b, rec_b = f[band], acc[:, band], rec[:, band]
    peaks = data_peaks(f_b, acc_b)
    print(f"resonance peaks in the data: {peaks.tolist()} Hz (data README lists {list(README_PEAKS_HZ)})")
    w2 = (2 * np.pi * f_b) ** 2
    t0 = time.perf_counter()
    # weights w^2 on the receptance = uniform weights on the measured accelerance
    opts = dict(upper_residual=True, lower_residual=True, complex_modes=True)
    fit, _ = robomill_fit(f_b, rec_b, max_order=60, weights=np.broadcast_to(w2, rec_b.shape), **opts)
    t_r = time.perf_counter() - t0
    err_r = relative_fit_error(acc_b, -w2 * fit.evaluate(f_b))
    import pyuff

    raw = pyuff.UFF(UFF).read_sets()  # sdypy wants the file's own grid, from 0 Hz
    x_raw, d_raw = np.real(raw[0]["x"]), np.array([d["data"] for d in raw])
    sdy = {}
    for name, approx in (("sdypy (README's 5)", README_PEAKS_HZ), ("sdypy (data's peaks)", peaks)):
        t0 = time.perf_counter()
        sf, sz, h_s, f_s, acc_s = sdypy_fit(x_raw, d_raw, approx, lower=lower_hz, upper=upper_hz, form="accelerance",
                                            order=60)
        t_s = time.perf_counter() - t0
        sel_s = (f_s >= lower_hz) & (f_s <= upper_hz)
        sdy[name] = (sf, sz, relative_fit_error(acc_s[:, sel_s], h_s[:, sel_s]), t_s)
    names = list(sdy)
    print(f"{'peak':>6} | {'robomill f (Hz)':>15} {'zeta':>8} | " + " | ".join(f"{n:>24}" for n in names))
    for target in peaks:
        rf, rz = nearest(fit.natural_frequency_hz, fit.damping_ratio, target)
        cells = []
        for n in names:
            sf, sz = sdy[n][:2]
            pf, pz = nearest(sf, sz, target)
            cells.append(f"{pf:14.2f} {pz:9.5f}" if abs(pf / target - 1) < 0.02 else f"{'-':>24}")
        print(f"{target:6.0f} | {rf:15.2f} {rz:8.5f} | " + " | ".join(cells))
    extra = [x for x in fit.natural_frequency_hz if np.min(np.abs(peaks / x - 1)) > 0.02]
    print(f"robomill modes: {fit.n_modes} ({len(extra)} not at a peak of the data: {np.round(extra, 1).tolist()})")
    print(f"relative fit error on the accelerance, per FRF ({lower_hz:g}-{upper_hz:g} Hz), and time:")
    print(f"   {'robomill':>22}: {np.round(err_r, 4).tolist()}  ({t_r:.2f} s)")
    for n in names:
        print(f"   {n:>22}: {np.round(sdy[n][2], 4).tolist()}  ({sdy[n][3]:.2f} s)")


if __name__ == "__main__":
    synthetic()
    correlated()
    real()
