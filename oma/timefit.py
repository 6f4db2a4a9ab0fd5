"""Time-domain input-output fit of the modal model: robomill's default OMA estimator.

Why: the paper's estimator (Welch H1, then a fit) needs segments long enough to resolve a mode's
half-power band ``2 zeta f_n`` (about 1 Hz for a 10 Hz robot mode at 5 %). A 1.1 s cut gives at
most a few short segments: the peak is smeared by the window (bias) and barely averaged (scatter).
Here the measured force drives the modal model sample by sample, exactly discretised, and the
parameters are chosen so that the simulated displacement matches the measured one (an
output-error fit; L. Ljung, System Identification, 2nd ed. 1999; R. Pintelon, J. Schoukens,
System Identification: a Frequency Domain Approach, 2012, on why a fit that models the initial
transient has no leakage). No window, no leakage, every sample used; the
unknown state at the start of the window is estimated (free-response terms), so a short record is
no handicap beyond its information content.

Model of output ``o`` of a record (``p_j`` the background force along input ``j``, i.e. the
measured force minus its fitted harmonics, mean and trend)::

    x_o[n] = sum_r sum_j A_r,oj (g_r * p_j)[n] + sum_j R_oj p_j[n]
             + sum_r e^{-zeta_r w_r t}(c_or cos w_dr t + d_or sin w_dr t)    (initial state)
             + b_o0 + b_o1 t + sum_h (a_oh cos 2 pi f_h t + s_oh sin 2 pi f_h t)  (static and forced part)

``g_r`` the unit-mass response of mode ``r`` (:func:`oma.synthetic.mode_filter`, first-order hold).
Natural frequencies and damping ratios are the nonlinear unknowns; everything else is linear and
solved at each step (variable projection, Golub & Pereyra 2003). The residues ``A_r`` (3 x 3 per
mode) are then made reciprocal and rank one, ``u_r u_r^T / m_r``, which gives the
:class:`~oma.modal.ModalModel`.

Quantised displacement. A laser tracker rounds the displacement to its resolution (15 um) while
the robot's background response is a few um rms; least squares (and H1) on such data are biased
by the rounding (Bussgang). When the samples of every record lie on a grid, the parameters are
therefore re-estimated by maximum likelihood of the rounded samples (:mod:`oma.quantised`), in the
ModalModel form itself (rank-one residues), which also lets the likelihood tell two close modes
along different axes (a robot's X and Z modes, 5 % apart) from one. Model order: greedy forward
selection of modes, splitting and pruning, scored by the BIC of the likelihood actually maximised.

References
----------
G. Golub, V. Pereyra, "Separable nonlinear least squares: the variable projection method and its
applications", Inverse Problems 19 (2003) R1-R26. R. E. Kass, A. E. Raftery, "Bayes factors",
J. Amer. Statist. Assoc. 90 (1995) 773-795. G. Schwarz, Ann. Statist. 6 (1978) 461-464.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ._arrays import readonly as _ro
from scipy import optimize
from scipy import signal as sps

from ._linalg import blas_single_threaded, lstsq_normal
from .modal_fit import _residue_modes
from .harmonics import Harmonics, fit_harmonic_signal, harmonic_basis
from .modal import ModalModel
from .quantised import MIN_BLOCKS, MIN_DAMPING, block_labels, free_residue_ml, modal_form_ml, sandwich_se
from .signals import PreparedSignals
from .synthetic import mode_filter

__all__ = ["TimeFit", "fit_time_domain", "NoModeFound"]


class NoModeFound(ValueError):
    """The records support no mode (nothing but rounding noise and forced response)."""


@dataclass(frozen=True)
class TimeFit:
    """Result of :func:`fit_time_domain`.

    Attributes
    ----------
    model : ModalModel
    residues : ndarray, shape (n_modes, 3, 3)
        Residue matrices ``A_r`` of the modes, m/N s^-2 (rows outputs, columns inputs): the free
        least-squares residues of the mode's pole, or ``phi_r phi_r^T`` in the modal form.
    residual_rms_m : ndarray, shape (3,)
        RMS of the displacement residual per output, m (NaN where not measured).
    fit_error : ndarray, shape (3,)
        Relative misfit of the dynamic response per output: ``sqrt((||y - x_fit||^2 - N q^2/12) /
        (||y_dyn||^2 - N q^2/12))``, the rounding noise ``q^2/12`` of quantised displacement taken
        out of both (plain ``||y - x_fit|| / ||y_dyn||`` otherwise).
    noise_scale_m : ndarray, shape (3,)
        Scale ``s`` of the Gaussian error inside the rounding, per output, m (NaN when the
        displacement was not quantised and least squares was used).
    quantised : bool
        Whether the quantised-output likelihood was used.
    dropped_modes_hz, split_modes_hz : tuple
        Modes removed, and modes split in two, by the information criterion.
    success : bool
    message : str
    frequency_se_hz, damping_se : ndarray, shape (n_modes,)
        Standard errors of the model's natural frequencies and damping ratios from a block
        sandwich (the residuals' own correlation counted) of the modal-form likelihood
        (:func:`oma.quantised._block_sandwich`) or of the least squares
        (:func:`_ls_block_sandwich`); NaN where not available (the free-residue likelihood of
        rounded data with different input and output axes, or fewer than
        :data:`oma.quantised.MIN_BLOCKS` blocks of data).
    n_blocks : int
        Blocks behind those standard errors (their intervals use ``n_blocks - 1`` degrees of
        freedom).
    """

    model: ModalModel
    residues: np.ndarray
    residual_rms_m: np.ndarray
    fit_error: np.ndarray
    noise_scale_m: np.ndarray
    quantised: bool = False
    dropped_modes_hz: tuple = ()
    split_modes_hz: tuple = ()
    success: bool = True
    message: str = ""
    frequency_se_hz: np.ndarray | None = None
    damping_se: np.ndarray | None = None
    n_blocks: int = 0

    def __post_init__(self):
        for name in ("frequency_se_hz", "damping_se"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(self.model.n_modes, np.nan))
        for name in ("residues", "residual_rms_m", "fit_error", "noise_scale_m", "frequency_se_hz", "damping_se"):
            object.__setattr__(self, name, _ro(getattr(self, name)))


def modal_response(p, f0, z0, fs, derivative=0):
    """Response of a unit-mass mode to sampled forces ``p`` (rows), first-order hold.

    ``derivative`` 0, 1, 2: displacement, velocity, acceleration. The acceleration follows from the
    equation of motion, ``q'' = p - 2 zeta w q' - w^2 q``, exact like the other two.
    """
    if derivative < 2:
        return sps.lfilter(*mode_filter(f0, z0, fs, derivative=derivative), p, axis=-1)
    w = 2.0 * np.pi * f0
    q = sps.lfilter(*mode_filter(f0, z0, fs), p, axis=-1)
    qd = sps.lfilter(*mode_filter(f0, z0, fs, derivative=1), p, axis=-1)
    return p - 2.0 * z0 * w * qd - w * w * q


class _Problem:
    """The stacked variable-projection problem over records and outputs."""

    def __init__(self, records, *, residual: bool):
        self.records = records  # list of dicts with p (n_in, n), y (n_out_all, n), t, nuis (n, k)
        self.residual = residual
        self.fs = records[0]["fs"]
        self.n_in = records[0]["p"].shape[0]
        self.outputs = records[0]["outputs"]
        self.derivative = records[0]["derivative"]  # output: displacement (0), velocity (1), acceleration (2)
        # residuals in units of each output's rms (keeps the optimiser's tolerances meaningful)
        ms = np.array([np.mean(np.concatenate([r["y_proj"][k] for r in records]) ** 2)
                       for k in range(len(self.outputs))])
        self.out_weight = 1.0 / np.sqrt(np.where(ms > 0, ms, 1.0))

    def mode_columns(self, rec, f0, z0):
        """Columns of one mode: its forced responses ``(n, n_in)`` and free responses ``(n, 2)``."""
        p, t = rec["p"], rec["t"]
        forced = modal_response(p, f0, z0, self.fs, self.derivative).T
        w = 2 * np.pi * f0
        wd = w * np.sqrt(max(1 - z0 * z0, 1e-12))
        env = np.exp(-z0 * w * t)
        return forced, np.column_stack([env * np.cos(wd * t), env * np.sin(wd * t)])

    def regressors(self, rec, fn, zeta):
        """Columns shared across records (residues, residual) and the record's own (free response)."""
        p, t = rec["p"], rec["t"]
        shared = []
        for f0, z0 in zip(fn, zeta):
            shared.append(modal_response(p, f0, z0, self.fs, self.derivative))  # (n_in, n)
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
        return shared.T, own.T

    def solve(self, fn, zeta, *, full=False):
        """Linear least squares for all outputs; returns the weighted residual vector.

        The static and forced-response columns (``nuis``) do not depend on the poles and are
        projected out once per record (an orthonormal basis ``Q``); the rest is solved through
        the normal equations of the projected columns. With ``full`` also returns, per output,
        the coefficients of the shared columns and per record the dynamic and nuisance parts.
        """
        blocks = [self.regressors(rec, fn, zeta) for rec in self.records]
        n_shared = blocks[0][0].shape[1]
        n_own = [b[1].shape[1] for b in blocks]
        n_cols = n_shared + sum(n_own)
        proj = []
        for (sh, own), rec in zip(blocks, self.records):
            a = np.hstack([sh, own])
            qn = rec["q_nuis"]
            proj.append(a - qn @ (qn.T @ a))
        gram = np.zeros((n_cols, n_cols))
        col = n_shared
        slices = []
        for a, k in zip(proj, n_own):
            idx = np.r_[0:n_shared, col : col + k]
            gram[np.ix_(idx, idx)] += a.T @ a
            slices.append(idx)
            col += k
        scale = np.sqrt(np.clip(np.diag(gram), 1e-300, None))
        gs = gram / np.outer(scale, scale)
        gs[np.diag_indices_from(gs)] += 1e-12
        resid_all, dyn_all = [], []
        for k in range(len(self.outputs)):
            rhs = np.zeros(n_cols)
            for a, idx, rec in zip(proj, slices, self.records):
                rhs[idx] += a.T @ rec["y_proj"][k]
            c = np.linalg.solve(gs, rhs / scale) / scale
            parts = []
            for a, idx, rec in zip(proj, slices, self.records):
                fit = a @ c[idx]
                resid_all.append(self.out_weight[k] * (rec["y_proj"][k] - fit))
                parts.append(c[idx])
            dyn_all.append(parts)
        resid = np.concatenate(resid_all)
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
        qx = np.linalg.qr(x)[0] if x.shape[1] else np.zeros((n_rows, 0))
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

    def full_design(self, fn, zeta):
        """Design matrix of all records stacked, ``(n_total, K)``, and the nuisance column mask.

        Columns: the shared ones (residues, residual), then per record its free-response and
        nuisance columns (zero on the other records' rows).
        """
        blocks = [self.regressors(rec, fn, zeta) for rec in self.records]
        n_shared = blocks[0][0].shape[1]
        own = [np.hstack([b[1], rec["nuis"]]) for b, rec in zip(blocks, self.records)]
        cols = n_shared + sum(o.shape[1] for o in own)
        n_total = sum(o.shape[0] for o in own)
        x = np.zeros((n_total, cols))
        nuis = np.zeros(cols, dtype=bool)
        row, col = 0, n_shared
        for b, o, rec in zip(blocks, own, self.records):
            n = o.shape[0]
            x[row : row + n, :n_shared] = b[0]
            x[row : row + n, col : col + o.shape[1]] = o
            nuis[col + b[1].shape[1] : col + o.shape[1]] = True
            row += n
            col += o.shape[1]
        return x, nuis

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


def _bic(rss, n, p):
    return n * np.log(max(rss, 1e-300) / n) + p * np.log(n)


logger = logging.getLogger(__name__)

def _rank_one_start(prob, fn, zeta):
    """Modes (fn, zeta, phi) for :func:`oma.quantised.modal_form_ml` from a least-squares fit with free residues.

    Each pole's symmetric residue is split into its significant rank-one parts
    (:func:`oma.modal_fit._residue_modes`); the parts of a rank-two residue of a pole with no other pole
    within 10 % start 1.5 % apart in frequency (two close modes the least squares merged).
    """
    _, coefs, _ = prob.solve(fn, zeta, full=True)
    a, _ = prob.unpack_residues(coefs, fn.size)
    ins = prob.records[0]["inputs"]
    entries = [(o, i) for o in prob.outputs for i in ins]
    out_f, out_z, out_phi = [], [], []
    for m in range(fn.size):
        w = 2 * np.pi * fn[m]
        alone = fn.size == 1 or np.min(np.abs(np.log(np.delete(fn, m) / fn[m]))) > 0.1
        modes = _residue_modes(entries, [a[m, o, i] for o, i in entries], w, max_modes=3 if alone else 1)
        offsets = [0.0] if len(modes) == 1 else np.linspace(-0.015, 0.015, len(modes))
        for (u, k), off in zip(modes, offsets):
            out_f.append(fn[m] * (1 + off))
            out_z.append(zeta[m])
            out_phi.append(u[ins] * w / np.sqrt(k))
    return np.array(out_f), np.array(out_z), np.array(out_phi).reshape(len(out_f), len(ins))


def _directional_proposals(prob, pred, grid, zeta0):
    """Per output axis, the best new mode along that axis alone, on top of a modal-form fit.

    A mode with participation ``phi e_o`` adds ``phi^2 (g * p_o)`` and a free response to output
    ``o`` only. For each output the residual of the current fit (``pred``, all records stacked) is
    regressed on those columns for every frequency of ``grid`` (damping ``zeta0``); the frequency
    that explains most of it, with its participation from the fitted gain, is proposed. Outputs
    whose best gain is not positive (no physical mode) propose nothing.

    Returns
    -------
    list of (frequency_hz, phi) with ``phi`` shaped ``(1, n_in)``.
    """
    recs = prob.records
    y = np.concatenate([r["y_raw"] for r in recs], axis=1)
    res = y - pred
    ins = list(recs[0]["inputs"])
    n_tot = y.shape[1]
    out = []
    for k, o in enumerate(prob.outputs):
        j = ins.index(o)
        best, best_f, best_gain = 0.0, None, 0.0
        for f0 in grid:
            c = np.zeros((n_tot, 1 + 2 * len(recs)))
            row = 0
            for i_rec, rec in enumerate(recs):
                forced, free = prob.mode_columns(rec, f0, zeta0)
                n = forced.shape[0]
                c[row : row + n, 0] = forced[:, j]
                c[row : row + n, 1 + 2 * i_rec : 3 + 2 * i_rec] = free
                row += n
            gram = c.T @ c
            gram[np.diag_indices_from(gram)] += 1e-12 * np.trace(gram) + 1e-300
            rhs = c.T @ res[k]
            coef = np.linalg.solve(gram, rhs)
            gain = float(rhs @ coef)
            if gain > best and coef[0] > 0:
                best, best_f, best_gain = gain, f0, float(coef[0])
        if best_f is not None:
            phi = np.zeros((1, len(ins)))
            phi[0, j] = np.sqrt(best_gain)
            out.append((float(best_f), phi))
    return out


def _prepare(signals, harmonics, inputs, outputs, derivative=0):
    """Per record: background force ``p``, output ``y`` (the measured quantity of order
    ``derivative``), the nuisance basis (trend and harmonics) and its orthonormal basis."""
    recs = []
    for s, h in zip(signals, harmonics):
        fs = s.sample_rate_hz
        n = s.n_samples
        t = np.arange(n) / fs
        f = s.force_N[inputs]
        hz = h.freq_hz if h is not None else np.zeros(0)
        p = f - fit_harmonic_signal(f, fs, hz, trend=True)
        nuis = harmonic_basis(t, hz, trend=True)
        q_nuis = np.linalg.qr(nuis)[0] if nuis.shape[1] else np.zeros((n, 0))
        y = np.array(s.motion[outputs] if derivative else s.displacement_m[outputs])
        recs.append({"p": p, "y": y, "y_proj": y - (y @ q_nuis) @ q_nuis.T, "t": t, "nuis": nuis, "q_nuis": q_nuis,
                     "fs": fs, "outputs": list(outputs), "inputs": list(inputs), "step": s.quantisation_step_m,
                     "derivative": derivative})
    return recs


def _nls(prob, fn, zeta, max_damping, *, rough=False):
    n = fn.size
    th0 = np.concatenate([np.log(fn), np.log(np.clip(zeta, MIN_DAMPING * 1.01, max_damping * 0.99))])
    lo = np.concatenate([np.log(fn) - 0.3, np.full(n, np.log(MIN_DAMPING))])
    hi = np.concatenate([np.log(fn) + 0.3, np.full(n, np.log(max_damping))])
    sol = optimize.least_squares(
        lambda th: prob.solve(np.exp(th[:n]), np.exp(th[n:])), th0, bounds=(lo, hi),
        x_scale=np.concatenate([np.full(n, 0.005), np.full(n, 0.05)]),
        xtol=1e-4 if rough else 1e-7, ftol=1e-4 if rough else 1e-8, max_nfev=(6 if rough else 25) * (n + 1),
        diff_step=1e-6,
    )
    return np.exp(sol.x[:n]), np.exp(sol.x[n:]), sol


@blas_single_threaded
def fit_time_domain(
    signals: Sequence[PreparedSignals],
    harmonics: Sequence[Harmonics | None],
    initial: ModalModel | None = None,
    *,
    residual: bool = False,
    quantisation: bool = True,
    split: bool = True,
    prune: bool = True,
    search: bool = True,
    modal_form: bool = True,
    evidence: float = 10.0,
    max_modes: int = 8,
    scan_damping: float = 0.05,
    scan_spacing: float = 0.04,
    max_damping: float = 0.3,
    force_noise_variance_N2=None,
    source: dict | None = None,
) -> TimeFit:
    """Fit a modal model to force and displacement records in the time domain.

    Parameters
    ----------
    signals : sequence of PreparedSignals
        Records of the same pose (force and displacement in the cut window), same sampling rate,
        same recorded axes.
    harmonics : sequence of Harmonics or None
        One per record: the lines taken out of the force and fitted as forced response.
    initial : ModalModel, optional
        Starting natural frequencies and damping ratios (e.g. the H1 fit); its number of modes is
        the starting model order. Modes are then added by greedy forward selection (``search``;
        essential for records too short for a Welch estimate to resolve the modes): a mode of damping
        ``scan_damping`` swept over a log grid of frequencies (relative step ``scan_spacing``, about
        half a half-power bandwidth) on top of the modes already chosen, the best one added while
        the information criterion improves, up to ``max_modes``.
    residual : bool
        Fit a residual compliance (feed-through) too.
    quantisation : bool
        Correct the gain bias of rounded displacement (see module notes) when the samples of a
        record lie on a grid.
    split : bool
        Try splitting a mode whose residue matrix has a second significant direction (two close
        modes the starting fit merged); kept when the BIC improves.
    prune : bool
        Drop modes that do not improve the BIC.
    search : bool
        Add modes by greedy forward selection (always when ``initial`` is None).
    modal_form : bool
        For quantised displacement with the same input and output axes, maximise the likelihood
        in the ModalModel form itself (rank-one residues, :func:`oma.quantised.modal_form_ml`), where close modes
        along different axes must be separate poles; otherwise free 3 x 3 residues per pole.
    evidence : float
        BIC difference a mode (added, split or kept) must earn: 10 is "very strong evidence"
        (Kass & Raftery 1995); it keeps modes that merely fit the rounding of short records out.
    max_modes, scan_damping, scan_spacing :
        Of the greedy search.
    max_damping : float
    force_noise_variance_N2 : float or sequence of float, optional
        Variance of the measured force's own error per sample (sensor noise and rounding), N^2,
        one value or one per record. The model's response to it is the smallest error scale the
        quantised-output likelihood may use (:func:`oma.quantised.input_noise_scale`).
    source : dict, optional
        Provenance for the model.

    The information criterion is the BIC of the likelihood actually maximised: Gaussian least
    squares for continuous displacement, the rounded-sample likelihood for quantised displacement
    (least-squares residuals of rounded data are neither white nor independent of the signal, and
    their BIC keeps adding modes that fit the rounding).

    Returns
    -------
    TimeFit
    """
    sigs = list(signals)
    harm = list(harmonics)
    if len(sigs) != len(harm):
        raise ValueError(f"{len(harm)} harmonics for {len(sigs)} records")
    search = search or initial is None
    inputs = np.flatnonzero(np.logical_and.reduce([s.force_axes for s in sigs]))
    outputs = np.flatnonzero(np.logical_and.reduce([s.displacement_axes for s in sigs]))
    if inputs.size == 0 or outputs.size == 0:
        raise ValueError("the records share no recorded force axis or no recorded displacement axis")
    # velocity or acceleration records are fitted as measured (the model's derivative), not through
    # their frequency-domain integral, whose edge and low-frequency errors the fit would take for
    # dynamics; records of mixed kinds are fitted as displacement
    kinds = {s.motion_quantity if s.motion is not None else "displacement" for s in sigs}
    derivative = {"velocity": 1, "acceleration": 2}.get(kinds.pop(), 0) if len(kinds) == 1 else 0
    residual = residual and derivative == 0  # a residual compliance's derivative needs dp/dt: not fitted
    recs = _prepare(sigs, harm, inputs, outputs, derivative)
    noise = np.broadcast_to(np.asarray(force_noise_variance_N2 if force_noise_variance_N2 is not None else 0.0,
                                       dtype=float), (len(recs),))
    for rec, v in zip(recs, noise):
        rec["force_noise"] = float(v)
    prob = _Problem(recs, residual=residual)
    n_total = sum(r["y"].shape[1] for r in recs) * outputs.size

    quantised = quantisation and all(rec["step"] for rec in recs)
    rank_one = modal_form and set(inputs.tolist()) == set(outputs.tolist())
    if quantised:
        for rec in recs:
            rec["y_raw"] = np.array(rec["y"])

    def n_lin(nm):
        return nm * inputs.size + (inputs.size if residual else 0) + sum(2 * nm + rec["nuis"].shape[1] for rec in recs)

    def evaluate(fn_, z_):
        """Refine a set of modes (least squares, then the quantised likelihood) and score it (BIC)."""
        if fn_.size:
            # with quantised data the least squares only starts the likelihood fit: a rough one does
            fn_, z_, sol_ = _nls(prob, fn_, z_, max_damping, rough=quantised)
            # two poles closer than a quarter of a half-power band are one pole fitted twice (their
            # columns are nearly collinear and the residues blow up in opposite directions); a
            # mode pair along different directions is represented by a rank-two residue instead
            while fn_.size > 1:
                d = np.abs(np.log(fn_[:, None] / fn_[None, :])) + np.eye(fn_.size) * 10
                i, j = np.unravel_index(np.argmin(d), d.shape)
                if d[i, j] >= 0.5 * min(z_[i], z_[j]):
                    break
                fn_, z_ = np.delete(fn_, j), np.delete(z_, j)
                fn_, z_, sol_ = _nls(prob, fn_, z_, max_damping, rough=quantised)
            ok, msg = bool(sol_.success), str(sol_.message)
            stuck = z_ < 1.05 * MIN_DAMPING
            if np.any(stuck) and np.any(~stuck):
                fn_, z_, sol_ = _nls(prob, fn_[~stuck], z_[~stuck], max_damping, rough=quantised)
        else:
            ok, msg = True, "no modes"
        out = {"fn": fn_, "zeta": z_, "ok": ok, "message": msg, "beta": None, "sigma": None, "r1": None}
        if quantised and rank_one and fn_.size:
            f1, z1, p1 = _rank_one_start(prob, fn_, z_)
            if f1.size:
                return evaluate_modal_form(f1, z1, p1)
        if quantised:
            fm, zm, beta, sig, conv, nll = free_residue_ml(prob, fn_, z_, max_damping)
            n_par = (n_lin(fm.size) + 1) * outputs.size + 2 * fm.size
            out.update(fn=fm, zeta=zm, beta=beta, sigma=sig, ok=conv,
                       message="quantised-output maximum likelihood " + ("converged" if conv else "stopped at its iteration limit"),
                       bic=2.0 * nll + n_par * np.log(n_total))
        else:
            rr = prob.solve(fn_, z_)
            out["bic"] = _bic(float(rr @ rr), n_total, n_lin(fn_.size) * outputs.size + 2 * fn_.size)
        return out

    def evaluate_modal_form(fn_, z_, phi_):
        """The modal-form likelihood fit started from ``(fn_, z_, phi_)``, scored by its BIC."""
        r1 = modal_form_ml(prob, fn_, z_, phi_, max_damping)
        return {"fn": r1["fn"], "zeta": r1["zeta"], "sigma": r1["sigma"], "ok": r1["converged"], "r1": r1,
                "beta": None, "bic": 2.0 * r1["nll"] + r1["n_par"] * np.log(n_total),
                "message": "quantised-output maximum likelihood (modal form) "
                + ("converged" if r1["converged"] else "stopped at its iteration limit")}

    def ls_rss(fn_, z_):
        rr = prob.solve(fn_, z_)
        return float(rr @ rr)

    split_hz, dropped = [], []
    if initial is None:
        cur = evaluate(np.zeros(0), np.zeros(0))
    else:
        cur = evaluate(np.array(initial.natural_frequency_hz, dtype=float), np.array(initial.damping_ratio, dtype=float))
    dur = min(r["t"][-1] for r in recs)
    # a mode needs a few cycles in the record to be told from a trend: at least 4
    grid = np.exp(np.arange(np.log(max(4.0 / dur, 0.5)), np.log(0.3 * prob.fs), scan_spacing))
    if search:
        # greedy forward selection: propose by a least-squares sweep, accept by the likelihood
        for _ in range(max(max_modes - cur["fn"].size, 0)):
            rss = prob.sweep(cur["fn"], cur["zeta"], grid, scan_damping)
            if cur["fn"].size:
                near = np.min(np.abs(np.log(grid[:, None] / cur["fn"][None, :])), axis=1) < 2 * scan_spacing
                rss[near] = np.inf
            f_new = grid[int(np.argmin(rss))]
            cands = [evaluate(np.append(cur["fn"], f_new), np.append(cur["zeta"], scan_damping))]
            if cur["r1"] is not None:
                # in the modal form a mode along one axis is not explained by a close mode along
                # another (a robot's X and Z modes 5 % apart), which the free-residue sweep above
                # cannot see: propose, per output, the best mode along that axis alone
                r1 = cur["r1"]
                for f_ax, phi_ax in _directional_proposals(prob, r1["pred"], grid, scan_damping):
                    cands.append(evaluate_modal_form(np.append(r1["fn"], f_ax), np.append(r1["zeta"], scan_damping),
                                                     np.vstack([r1["phi"], phi_ax])))
            cand = min(cands, key=lambda c: c["bic"])
            logger.debug("greedy: candidates %s -> modes %s, BIC %.1f (was %.1f)",
                         [np.round(c["fn"], 2) for c in cands], cand["fn"], cand["bic"], cur["bic"])
            if cand["bic"] > cur["bic"] - evidence or cand["fn"].size <= cur["fn"].size:
                break
            cur = cand
    if split and outputs.size > 1 and inputs.size > 1 and not (quantised and rank_one):
        for _ in range(cur["fn"].size):
            fn, zeta = cur["fn"], cur["zeta"]
            _, coefs, _ = prob.solve(fn, zeta, full=True)
            a, _ = prob.unpack_residues(coefs, fn.size)
            cands = []
            for m in range(fn.size):
                sym = 0.5 * (a[m] + a[m].T)
                ev = np.linalg.eigvalsh(sym)
                ev = ev[np.argsort(np.abs(ev))[::-1]]
                if ev[0] != 0 and ev[1] / ev[0] > 0.2:
                    cands.append((ev[1] / ev[0], m))
            if not cands:
                break
            _, m = max(cands)
            cand = evaluate(np.concatenate([np.delete(fn, m), fn[m] * np.array([0.97, 1.03])]),
                            np.concatenate([np.delete(zeta, m), [zeta[m], zeta[m]]]))
            # the free 3 x 3 residues count (n_in + 2) n_out + 2 parameters per pole, but a split
            # replaces a rank-two residue (already two modes' worth of directions) by two rank-one
            # ones: in the modal model it adds only a pole (2) and one mode's initial state (2)
            extra = (inputs.size + 2) * outputs.size + 2 - 4
            if cand["bic"] - extra * np.log(n_total) < cur["bic"] and cand["fn"].size > fn.size:
                split_hz.append(float(fn[m]))
                cur = cand
            else:
                break
    if prune:
        while cur["fn"].size > 1:
            fn, zeta = cur["fn"], cur["zeta"]
            base_rss = ls_rss(fn, zeta)
            best = None
            for m in range(fn.size):
                keep = np.arange(fn.size) != m
                # a mode whose removal raises the residual by more than 10 % is plainly needed
                if ls_rss(fn[keep], zeta[keep]) > 1.1 * base_rss:
                    continue
                if cur["r1"] is not None:
                    # the modal form's BIC counts every parameter of the mode: no adjustment
                    r1 = cur["r1"]
                    cand = evaluate_modal_form(r1["fn"][keep], r1["zeta"][keep], r1["phi"][keep])
                    adj = cand["bic"]
                else:
                    cand = evaluate(fn[keep], zeta[keep])
                    # removing one of two close poles leaves their directions to a rank-two
                    # residue: in the modal model that saves only the pole and one initial state
                    close = np.min(np.abs(np.log(fn[keep] / fn[m]))) < 0.1 if keep.any() else False
                    saved = 4 if close else (inputs.size + 2) * outputs.size + 2
                    full = (inputs.size + 2) * outputs.size + 2
                    adj = cand["bic"] + (full - saved) * np.log(n_total)
                if (adj < cur["bic"] + evidence and cand["fn"].size < fn.size
                        and (best is None or adj < best[2])):
                    best = (cand, fn[m], adj)
            if best is None:
                break
            dropped.append(float(best[1]))
            cur = best[0]
    fn, zeta = cur["fn"], cur["zeta"]
    if fn.size == 0:
        raise NoModeFound("the time-domain fit found no mode")
    converged, message = cur["ok"], cur["message"]
    if cur.get("r1") is not None:
        return _time_fit_from_rank_one(cur["r1"], recs, inputs, outputs, dropped, split_hz, source, message)
    sigma_v = np.full(3, np.nan)
    beta = cur["beta"]
    if quantised:
        sigma_v[outputs] = cur["sigma"]
    xd, nuis_cols = prob.full_design(fn, zeta)
    y_all = np.concatenate([rec["y"] for rec in recs], axis=1)
    if not quantised:
        beta = lstsq_normal(xd, y_all.T).T
    pred = beta @ xd.T
    nuis_part = beta[:, nuis_cols] @ xd[:, nuis_cols].T
    rms, ferr = _misfit(y_all, pred, nuis_part, recs, outputs, quantised)
    a, res_c = prob.unpack_residues(list(beta), fn.size)
    pole_se, n_blocks = (np.full(2 * fn.size, np.nan), 0) if quantised else \
        _ls_block_sandwich(prob, fn, zeta, beta, xd, y_all - pred)

    freqs, zetas, ks, dirs, keep = [], [], [], [], []
    measured = np.zeros((3, 3), dtype=bool)
    measured[np.ix_(outputs, inputs)] = True
    entries = [(o, i) for o in range(3) for i in range(3) if measured[o, i]]
    for m in range(fn.size):
        modes = _residue_modes(entries, [a[m, o, i] for o, i in entries], 2 * np.pi * fn[m])
        if not modes:
            dropped.append(float(fn[m]))
            continue
        for u, k in modes:
            freqs.append(fn[m])
            zetas.append(zeta[m])
            ks.append(k)
            dirs.append(u)
            keep.append(m)
    if not freqs:
        raise NoModeFound("the time-domain fit left no mode with a positive residue")
    # a mode whose resonant peak u_a^2 / (k zeta) is below 1 % of the largest on every axis carries
    # no measurable response (a pole the fit parked far from the data); it is dropped
    u2 = np.array(dirs) ** 2 / (np.array(ks) * np.array(zetas))[:, None]
    visible = np.any(u2 >= 0.01 * np.max(u2, axis=0, keepdims=True), axis=1)
    for j in np.flatnonzero(~visible):
        dropped.append(float(freqs[j]))
    freqs, zetas, ks = [np.asarray(v)[visible] for v in (freqs, zetas, ks)]
    dirs, keep = np.asarray(dirs)[visible], np.asarray(keep)[visible]
    res_sym = 0.5 * (res_c + res_c.T) if residual else np.zeros((3, 3))
    order = np.argsort(freqs)
    model = ModalModel(
        natural_frequency_hz=np.array(freqs)[order], damping_ratio=np.array(zetas)[order],
        stiffness_N_m=np.array(ks)[order], directions=np.array(dirs)[order],
        residual_compliance_m_N=res_sym, source=source,
    )
    pole = keep[order]
    return TimeFit(
        model=model, residues=a[pole], residual_rms_m=rms, fit_error=ferr,
        noise_scale_m=sigma_v, quantised=bool(quantised),
        dropped_modes_hz=tuple(dropped), split_modes_hz=tuple(split_hz), success=bool(converged),
        message=message, frequency_se_hz=fn[pole] * pole_se[pole], damping_se=zeta[pole] * pole_se[fn.size + pole],
        n_blocks=n_blocks,
    )


def _ls_block_sandwich(prob, fn, zeta, beta, xd, resid, *, step=1e-6):
    """Block-sandwich standard errors of ``(log fn, log zeta)`` of the least-squares fit.

    The poles solve ``sum_o w_o^2 d_o^T r_o = 0`` with ``d_o`` the derivative of output ``o``'s
    prediction projected off the linear columns (variable projection) and ``w_o`` the fit's output
    weights; their influence is ``S^-1 sum_o w_o^2 d_o^T r_o`` with ``S = sum_o w_o^2 d_o^T d_o``,
    and the scores summed over blocks (:func:`oma.quantised.block_labels`) give the sandwich, as
    for the likelihood (:func:`oma.quantised._block_sandwich`), with the white-residual standard
    error ``sigma_o^2 = rss_o / (N - K)`` as a floor. Returns the standard errors (2 n_modes,) and
    the number of blocks (NaN errors below :data:`oma.quantised.MIN_BLOCKS`).
    """
    n_m = fn.size
    _, starts = block_labels(prob.records, prob.fs, fn, zeta)
    g_count = starts.size
    nan = np.full(2 * n_m, np.nan)
    if g_count < MIN_BLOCKS or n_m == 0:
        return nan, g_count
    n_tot, k = xd.shape
    q_x, _ = np.linalg.qr(xd)
    w2 = prob.out_weight ** 2
    d = np.zeros((beta.shape[0], n_tot, 2 * n_m))
    for j in range(2 * n_m):
        f1, z1 = fn.copy(), zeta.copy()
        if j < n_m:
            f1[j] *= np.exp(step)
        else:
            z1[j - n_m] *= np.exp(step)
        dx = (prob.full_design(f1, z1)[0] - xd) / step
        d[:, :, j] = beta @ dx.T
    d -= np.einsum("nk,okj->onj", q_x, np.einsum("nk,onj->okj", q_x, d))  # projected off the linear columns
    s_mat = np.einsum("o,oni,onj->ij", w2, d, d)
    scores = np.add.reduceat(np.einsum("o,onj,on->nj", w2, d, resid), starts, axis=0)
    sigma2 = np.sum(resid ** 2, axis=1) / max(n_tot - k, 1)
    try:
        s_inv = np.linalg.inv(s_mat)
    except np.linalg.LinAlgError:
        return nan, g_count
    model = s_inv @ np.einsum("o,oni,onj->ij", w2 ** 2 * sigma2, d, d) @ s_inv
    return sandwich_se(s_inv, scores, model), g_count


def _misfit(y_all, pred, nuis_part, recs, outputs, quantised):
    """RMS residual and relative misfit of the dynamic response per output (see :class:`TimeFit`).

    What the rounding alone explains (``q^2 / 12`` per sample of quantised displacement) is not a
    misfit of the model and is taken out of both the residual and the dynamic response.
    """
    q_var = sum(rec["y"].shape[1] * (rec["step"] or 0.0) ** 2 / 12.0 for rec in recs) if quantised else 0.0
    rms = np.full(3, np.nan)
    ferr = np.full(3, np.nan)
    for k, o in enumerate(outputs):
        dyn_meas = y_all[k] - nuis_part[k]
        num = float(np.sum((y_all[k] - pred[k]) ** 2))
        den = float(np.sum((dyn_meas - dyn_meas.mean()) ** 2))
        rms[o] = np.sqrt(num / y_all.shape[1])
        excess = max(num - q_var, 0.0)
        ferr[o] = np.sqrt(excess / max(den - q_var, 1e-300)) if den > 0 else np.nan
    return rms, ferr


def _time_fit_from_rank_one(r1, recs, inputs, outputs, dropped, split_hz, source, message) -> TimeFit:
    """The :class:`TimeFit` of a modal-form likelihood fit (:func:`oma.quantised.modal_form_ml`)."""
    y_all = np.concatenate([rec["y_raw"] for rec in recs], axis=1)
    rms, ferr = _misfit(y_all, r1["pred"], r1["nuis_part"], recs, outputs, True)
    fn, zeta = r1["fn"], r1["zeta"]
    phi = np.zeros((fn.size, 3))
    phi[:, inputs] = r1["phi"]
    norm = np.linalg.norm(phi, axis=1)
    ok = norm > 0
    k = (2 * np.pi * fn) ** 2 / np.where(ok, norm, 1.0) ** 2
    u = phi / np.where(ok, norm, 1.0)[:, None]
    u = u * np.sign(u[np.arange(fn.size), np.argmax(np.abs(u), axis=1)])[:, None]
    # a mode whose resonant peak is below 1 % of the largest on every axis carries no measurable
    # response (a pole the fit parked far from the data): dropped
    u2 = u**2 / (k * zeta)[:, None]
    visible = ok & np.any(u2 >= 0.01 * np.max(u2[ok], axis=0, keepdims=True), axis=1)
    dropped = list(dropped) + [float(f) for f in fn[~visible]]
    order = np.argsort(fn[visible])
    sel = np.flatnonzero(visible)[order]
    if sel.size == 0:
        raise NoModeFound("the time-domain fit left no mode with a measurable response")
    model = ModalModel(natural_frequency_hz=fn[sel], damping_ratio=zeta[sel], stiffness_N_m=k[sel],
                       directions=u[sel], source=source)
    residues = np.einsum("mi,mj->mij", phi[sel], phi[sel])
    sigma = np.full(3, np.nan)
    sigma[outputs] = r1["sigma"]
    # standard errors of log fn, log zeta -> of fn, zeta (to first order)
    log_se, n_blocks = r1["uncertainty"]()
    se_f = fn[sel] * log_se[: fn.size][sel]
    se_z = zeta[sel] * log_se[fn.size:][sel]
    return TimeFit(model=model, residues=residues, residual_rms_m=rms, fit_error=ferr, noise_scale_m=sigma,
                   quantised=True, dropped_modes_hz=tuple(dropped), split_modes_hz=tuple(split_hz),
                   success=bool(r1["converged"]), message=message, frequency_se_hz=se_f, damping_se=se_z,
                   n_blocks=int(n_blocks))

