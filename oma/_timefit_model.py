"""The time-domain fit's model: the response of a unit-mass mode, the records prepared for the
fit, and the stacked variable-projection problem over records and outputs (:mod:`oma.timefit`).

Private module: :func:`modal_response` is imported from :mod:`oma.timefit`.
"""

from __future__ import annotations

import numpy as np
from scipy import signal as sps

from ._linalg import orthonormal_basis
from .harmonics import fit_harmonic_signal, harmonic_basis
from .synthetic import hold_equalised, mode_filter

__all__ = ["modal_response"]


def modal_response(p, f0, z0, fs, derivative=0, held=None):
    """Response of a unit-mass mode to the measured (band-limited) forces ``p`` (rows).

    The mode is discretised with a first-order hold (:func:`oma.synthetic.mode_filter`) and driven
    by the samples equalised for it (:func:`oma.synthetic.hold_equalised`; ``held``, when given, is
    that of ``p``): without, a mode at 0.15 fs came out 6.6 % soft from a record of a continuous
    structure (session 20). ``derivative`` 0, 1, 2: displacement, velocity, acceleration. The
    acceleration follows from the equation of motion, ``q'' = p - 2 zeta w q' - w^2 q``, its direct
    term the force itself.
    """
    held = hold_equalised(p) if held is None else held
    if derivative < 2:
        return sps.lfilter(*mode_filter(f0, z0, fs, derivative=derivative), held, axis=-1)
    w = 2.0 * np.pi * f0
    q = sps.lfilter(*mode_filter(f0, z0, fs), held, axis=-1)
    qd = sps.lfilter(*mode_filter(f0, z0, fs, derivative=1), held, axis=-1)
    return p - 2.0 * z0 * w * qd - w * w * q


class _Problem:
    """The stacked variable-projection problem over records and outputs."""

    def __init__(self, records, *, residual: bool, band_hz=(0.0, np.inf)):
        self.records = records  # list of dicts with p (n_in, n), y (n_out_all, n), t, nuis (n, k)
        self.residual = residual
        self.fs = records[0]["fs"]
        # lowest and highest natural frequency a refinement may move a mode to (the band the
        # records resolve)
        self.min_frequency_hz, self.max_frequency_hz = float(band_hz[0]), float(band_hz[1])
        self.n_in = records[0]["p"].shape[0]
        self.outputs = records[0]["outputs"]
        self.derivative = records[0]["derivative"]  # output: displacement (0), velocity (1), acceleration (2)
        # residuals in units of each output's rms (keeps the optimiser's tolerances meaningful)
        ms = np.array([np.mean(np.concatenate([r["y_proj"][k] for r in records]) ** 2)
                       for k in range(len(self.outputs))])
        self.out_weight = 1.0 / np.sqrt(np.where(ms > 0, ms, 1.0))

    def frequency_bounds(self, fn, step):
        """Bounds of ``log fn`` for one refinement: ``+-step`` around ``fn``, inside the band.

        Returns the start and the bounds; a start on or beyond an end of the band is moved just
        inside it.
        """
        with np.errstate(divide="ignore"):
            lo_cap, hi_cap = np.log(self.min_frequency_hz), np.log(self.max_frequency_hz)
        th = np.clip(np.log(fn), lo_cap + 1e-6, hi_cap - 1e-6)
        return th, np.maximum(th - step, lo_cap), np.minimum(th + step, hi_cap)

    def mode_columns(self, rec, f0, z0):
        """Columns of one mode: its forced responses ``(n, n_in)`` and free responses ``(n, 2)``
        (zero on the samples left out of the fit)."""
        p, t = rec["p"], rec["t"]
        forced = modal_response(p, f0, z0, self.fs, self.derivative, held=rec["p_held"]).T
        w = 2 * np.pi * f0
        wd = w * np.sqrt(max(1 - z0 * z0, 1e-12))
        env = np.exp(-z0 * w * t)
        free = np.column_stack([env * np.cos(wd * t), env * np.sin(wd * t)])
        if rec.get("w") is not None:
            forced, free = forced * rec["w"][:, None], free * rec["w"][:, None]
        return forced, free

    def regressors(self, rec, fn, zeta):
        """Columns shared across records (residues, residual) and the record's own (free response)."""
        p, t = rec["p"], rec["t"]
        shared = []
        for f0, z0 in zip(fn, zeta):
            shared.append(modal_response(p, f0, z0, self.fs, self.derivative, held=rec["p_held"]))  # (n_in, n)
        shared = np.concatenate(shared, axis=0) if shared else np.zeros((0, t.size))
        if self.residual:
            shared = np.concatenate([shared, p], axis=0)
        own = []
        for f0, z0 in zip(fn, zeta):
            w = 2 * np.pi * f0
            wd = w * np.sqrt(max(1 - z0 * z0, 1e-12))
            env = np.exp(-z0 * w * t)
            own += [env * np.cos(wd * t), env * np.sin(wd * t)]
        own = np.array(own) if own else np.zeros((0, t.size))
        if rec.get("w") is not None:  # samples left out of the fit: their rows are zero
            return shared.T * rec["w"][:, None], own.T * rec["w"][:, None]
        return shared.T, own.T

    def solve(self, fn, zeta, *, full=False):
        """Linear least squares for all outputs; returns the weighted residual vector.

        The static and forced-response columns (``nuis``) do not depend on the poles and are
        projected out once per record (an orthonormal basis ``Q``); the rest is solved through
        the normal equations of the projected columns. With ``full`` also returns, per output,
        the coefficients of the shared columns and per record the dynamic and nuisance parts.

        The projected columns ``(I - Q Q^T) A`` are never formed: their Gram matrix is
        ``A^T A - (Q^T A)^T (Q^T A)``, their product with the projected output ``A^T y_proj``
        (``Q^T y_proj = 0``), and the fit ``A c - Q (Q^T A c)``. That is one product with the
        ``(n, k)`` basis instead of two (a 20 s record at 5 kHz has ``k`` = 112 nuisance columns
        against 18 of the modes).
        """
        blocks = [self.regressors(rec, fn, zeta) for rec in self.records]
        n_shared = blocks[0][0].shape[1]
        n_own = [b[1].shape[1] for b in blocks]
        n_cols = n_shared + sum(n_own)
        cols, in_span = [], []
        for (sh, own), rec in zip(blocks, self.records):
            a = np.hstack([sh, own])
            cols.append(a)
            in_span.append(rec["q_nuis"].T @ a)
        gram = np.zeros((n_cols, n_cols))
        col = n_shared
        slices = []
        for a, qa, k in zip(cols, in_span, n_own):
            idx = np.r_[0:n_shared, col : col + k]
            gram[np.ix_(idx, idx)] += a.T @ a - qa.T @ qa
            slices.append(idx)
            col += k
        scale = np.sqrt(np.clip(np.diag(gram), 1e-300, None))
        gs = gram / np.outer(scale, scale)
        gs[np.diag_indices_from(gs)] += 1e-12
        n_out = len(self.outputs)
        rhs = np.zeros((n_cols, n_out))
        for a, idx, rec in zip(cols, slices, self.records):
            rhs[idx] += a.T @ rec["y_proj"].T
        coef = np.linalg.solve(gs, rhs / scale[:, None]) / scale[:, None]
        # every output's fit at once: one pass over the basis, not one per output
        fits = [a @ coef[idx] - rec["q_nuis"] @ (qa @ coef[idx])
                for a, qa, idx, rec in zip(cols, in_span, slices, self.records)]
        resid = np.concatenate([self.out_weight[k] * (rec["y_proj"][k] - fit[:, k])
                                for k in range(n_out) for fit, rec in zip(fits, self.records)])
        dyn_all = [[coef[idx, k] for idx in slices] for k in range(n_out)]
        if not full:
            return resid
        coefs = [parts[0][:n_shared] for parts in dyn_all]
        preds = []
        for k in range(len(self.outputs)):
            per = []
            for (sh, own), idx, rec, cc in zip(blocks, slices, self.records, dyn_all[k]):
                dyn = np.hstack([sh, own]) @ cc
                rest = rec["y"][k] - dyn
                nuis = rec["q_nuis"] @ (rec["q_nuis"].T @ rest)
                per.append((dyn, nuis))
            preds.append(per)
        return resid, coefs, preds

    def sweep(self, fn, zeta, grid_hz, zeta0, *, output=None):
        """Residual sum of squares after adding one mode ``(f, zeta0)`` for each ``f`` of a grid.

        The current modes and the nuisance columns are projected out once; each candidate's
        columns are orthogonalised against them, so a candidate costs one small projection.
        """
        x, _ = self.full_design(fn, zeta)
        n_rows = x.shape[0]
        qx = orthonormal_basis(x)
        y = np.concatenate([r["y"] for r in self.records], axis=1) * self.out_weight[:, None]
        if output is not None:
            y = y[output : output + 1]
        r0 = y - (y @ qx) @ qx.T
        base = float(np.sum(r0**2))
        out = np.empty(len(grid_hz))
        for g, f0 in enumerate(grid_hz):
            cols = []
            row = 0
            for i_rec, rec in enumerate(self.records):
                forced, free = self.mode_columns(rec, f0, zeta0)
                n = forced.shape[0]
                c = np.zeros((n_rows, forced.shape[1] + 2 * len(self.records)))
                c[row : row + n, : forced.shape[1]] = forced
                j = forced.shape[1] + 2 * i_rec
                c[row : row + n, j : j + 2] = free
                cols.append(c)
                row += n
            c = np.sum(cols, axis=0)
            c = c - qx @ (qx.T @ c)
            gram = c.T @ c
            gram[np.diag_indices_from(gram)] += 1e-12 * np.trace(gram) + 1e-300
            proj = r0 @ c  # (n_out, k)
            out[g] = base - float(np.sum(proj * np.linalg.solve(gram, proj.T).T))
        return out

    def full_design(self, fn, zeta, *, nuisance: bool = True):
        """Design matrix of all records stacked, ``(n_total, K)``, and the nuisance column mask
        ``(K,)``.

        Columns: the shared ones (residues, residual), then per record its free-response and
        nuisance columns (zero on the other records' rows). With ``nuisance=False`` the nuisance
        columns are left out (the columns that depend on the poles, ``~mask`` of the full design):
        the block sandwich differences only those.
        """
        blocks = [self.regressors(rec, fn, zeta) for rec in self.records]
        n_shared = blocks[0][0].shape[1]
        own = [np.hstack([b[1], rec["nuis"]]) if nuisance else b[1] for b, rec in zip(blocks, self.records)]
        mask = np.concatenate([np.zeros(n_shared, dtype=bool)] + [
            np.r_[np.zeros(b[1].shape[1], dtype=bool), np.ones(rec["nuis"].shape[1], dtype=bool)]
            for b, rec in zip(blocks, self.records)])
        x = np.zeros((sum(o.shape[0] for o in own), n_shared + sum(o.shape[1] for o in own)))
        row, col = 0, n_shared
        for b, o in zip(blocks, own):
            n = o.shape[0]
            x[row : row + n, :n_shared] = b[0]
            x[row : row + n, col : col + o.shape[1]] = o
            row += n
            col += o.shape[1]
        return x, mask

    def unpack_residues(self, coefs, n_modes):
        a = np.zeros((n_modes, 3, 3))
        r = np.zeros((3, 3))
        ins = self.records[0]["inputs"]
        for k, o in enumerate(self.outputs):
            c = coefs[k]
            for m in range(n_modes):
                a[m, o, ins] = c[m * self.n_in : (m + 1) * self.n_in]
            if self.residual:
                r[o, ins] = c[n_modes * self.n_in : (n_modes + 1) * self.n_in]
        return a, r


def _prepare(signals, harmonics, inputs, outputs, derivative=0, keep=None):
    """Per record: background force ``p``, output ``y`` (the measured quantity of order
    ``derivative``), the nuisance basis (trend and harmonics) and its orthonormal basis.

    ``keep`` (one boolean array per record, or None) leaves samples out of the fit: their rows of
    ``y`` and of every column are zero (``rec["w"]``), while the force still drives the model
    through them (the structure's state runs on).
    """
    recs = []
    for i, (s, h) in enumerate(zip(signals, harmonics)):
        fs = s.sample_rate_hz
        n = s.n_samples
        t = np.arange(n) / fs
        f = s.force_N[inputs]
        hz = h.freq_hz if h is not None else np.zeros(0)
        p = f - fit_harmonic_signal(f, fs, hz, trend=True)
        nuis = harmonic_basis(t, hz, trend=True)
        y = np.array(s.motion[outputs] if derivative else s.displacement_m[outputs])
        w = None if keep is None or keep[i] is None or np.all(keep[i]) else np.asarray(keep[i], dtype=float)
        if w is not None:
            nuis, y = nuis * w[:, None], y * w
        q_nuis = orthonormal_basis(nuis)
        recs.append({"p": p, "p_held": hold_equalised(p), "y": y, "y_proj": y - (y @ q_nuis) @ q_nuis.T, "t": t,
                     "nuis": nuis, "q_nuis": q_nuis, "fs": fs, "outputs": list(outputs), "inputs": list(inputs),
                     "step": s.quantisation_step_m, "derivative": derivative, "w": w})
    return recs

