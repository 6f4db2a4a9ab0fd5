"""Robomill issue 14: how far the output-only refinement's estimates depend on its numerical path.

The same records identified twice: as shipped, and with SSI's leading singular vectors taken by
another LAPACK path to the same subspace (NumPy's full ``eigh`` of ``T T^T`` instead of SciPy's
subset; the subspaces agree to about 1e-11). A maximum-likelihood estimate does not depend on the
path to it; where the refinement's group fits stop short of their optimum (docs/output_only.md,
session 21), the last bits of the start steer the result. Per case: the records whose modes
changed at all, by more than 0.1 % in a frequency or 1 % in a damping, more than 0.3 % / 5 %, more
than 0.5 % / 10 %, and whose number of modes changed. With ``--gaps N``, on the first ``N`` records
of each case, each reported group fit is also polished by BFGS (SciPy, analytic gradient; the polished
value is not used) and the decrease of ``-log L`` it finds is reported: 0 for a fit at its optimum.
Since session 22 the fits polished are those whose estimates are reported (each group's chosen fit,
after the refinement's finish, :func:`oma.output_only._ml_fit._finish`); before, every group fit
(the tail models' and the evidence's too) as the scoring left it.

The cases are those of ``bench_oma_output_only.py`` (the paper-like cell's five and the two probe
structures), 20 s accelerations at 1 kHz.

Run: ``python benchmarks/bench_oma_refinement_paths.py [--seeds 20] [--cases ...] [--gaps 2]``
(about 8 minutes for the 7 cases x 20 seeds on one core).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_oma_output_only import CASES, PROBES, case_record  # noqa: E402

import oma.output_only._ml_fit as ml_fit  # noqa: E402
import oma.output_only.ml as ml  # noqa: E402
import oma.output_only.ssi as ssi  # noqa: E402
from oma._linalg import single_threaded_blas  # noqa: E402
from oma.output_only.identify import identify_output_only  # noqa: E402

#: (frequency, damping) relative differences counted, each pair a column.
THRESHOLDS = ((1e-3, 1e-2), (3e-3, 5e-2), (5e-3, 1e-1))


def _full_eigh(a, subset_by_index, check_finite=False):
    """The ``eigh`` SSI calls, by NumPy's full decomposition: another path to the same subspace."""
    ev, vec = np.linalg.eigh(a)
    lo, hi = subset_by_index
    return ev[lo:hi + 1], vec[:, lo:hi + 1]


@contextlib.contextmanager
def _patched(module, name, value):
    old = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, old)


def _polish_gaps(gaps):
    """An ``_information_se`` that also records how much BFGS lowers ``-log L`` from each fit whose
    estimates are reported (each group's chosen fit, after the refinement's finish; the polished
    value is not used)."""
    from scipy.optimize import minimize

    information_se = ml._information_se

    def wrapped(p, mod, x, *args, **kwargs):
        val = ml_fit._nll(p, mod, x)[0]
        res = minimize(lambda q: ml_fit._nll(q, mod, x), p, jac=True, method="BFGS",
                       options=dict(gtol=1e-6, maxiter=400))
        gaps.append(max(val - float(res.fun), 0.0))
        return information_se(p, mod, x, *args, **kwargs)

    return wrapped


def _identify(rec):
    m = identify_output_only([rec]).modes
    return np.asarray(m.freq_hz), np.asarray(m.damping_ratio)


def run_case(case, seeds, n_gaps):
    rows, gaps = [], []
    for i, s in enumerate(seeds):
        rec, _ = case_record(case, s)
        if i < n_gaps:
            with _patched(ml, "_information_se", _polish_gaps(gaps)):
                a = _identify(rec)
        else:
            a = _identify(rec)
        with _patched(ssi, "eigh", _full_eigh):
            b = _identify(rec)
        if a[0].size != b[0].size:
            rows.append((np.inf, np.inf))
            continue
        df = float(np.max(np.abs(a[0] / b[0] - 1.0), initial=0.0))
        dz = float(np.max(np.abs(a[1] / b[1] - 1.0), initial=0.0))
        rows.append((df, dz))
    return np.array(rows), np.array(gaps)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--cases", nargs="+", default=list(CASES) + list(PROBES), choices=CASES + tuple(PROBES))
    ap.add_argument("--gaps", type=int, default=2, help="records per case whose reported group fits are also polished")
    args = ap.parse_args(argv)
    head = " / ".join(f">{100 * f:g} % or {100 * z:g} %" for f, z in THRESHOLDS)
    print(f"{'case':>8} | records | changed at all | {head} | modes changed | -log L gap to BFGS: median, 90 %, max")
    total = np.zeros(len(THRESHOLDS) + 3, dtype=int)
    with single_threaded_blas():
        for case in args.cases:
            d, gaps = run_case(case, range(args.seeds), args.gaps)
            counts = [int(np.sum((d[:, 0] > f) | (d[:, 1] > z))) for f, z in THRESHOLDS]
            changed = int(np.sum((d[:, 0] > 0) | (d[:, 1] > 0)))
            n_modes = int(np.sum(~np.isfinite(d[:, 0])))
            row = [len(d), changed, *counts, n_modes]
            total += row
            gap = (f"{np.median(gaps):.3f}, {np.quantile(gaps, 0.9):.3f}, {gaps.max():.3f} ({gaps.size} fits)"
                   if gaps.size else "-")
            print(f"{case:>8} | {row[0]:7d} | {changed:14d} | {' / '.join(f'{c:3d}' for c in counts):>38} | "
                  f"{n_modes:13d} | {gap}")
    print(f"{'all':>8} | {total[0]:7d} | {total[1]:14d} | {' / '.join(f'{c:3d}' for c in total[2:-1]):>38} | "
          f"{total[-1]:13d} |")


if __name__ == "__main__":
    main()
