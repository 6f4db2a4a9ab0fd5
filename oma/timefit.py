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

``g_r`` the unit-mass response of mode ``r`` (:func:`oma.synthetic.mode_filter`, first-order hold,
driven by ``p`` equalised for the hold, :func:`oma.synthetic.hold_equalised`: the measured force is
band-limited, and the hold alone answers ``sinc^2(f / fs)`` short).
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

The estimator is here; the model and the variable-projection problem are in
:mod:`oma._timefit_model`, the result and its standard errors in :mod:`oma._timefit_result`.
"""

from __future__ import annotations

import logging
from typing import Sequence

import numpy as np
from scipy import optimize

from ._linalg import blas_single_threaded, lstsq_normal
from .modal_fit import _residue_modes
from .harmonics import Harmonics
from .modal import ModalModel
from .quantised import MIN_DAMPING, free_residue_ml, modal_form_ml
from .signals import PreparedSignals
from ._timefit_model import _Problem, _prepare, modal_response  # noqa: F401 (modal_response: re-exported)
from ._timefit_result import (NoModeFound, TimeFit, _band_edges, _full_residual, _ls_block_sandwich, _misfit,
                              _time_fit_from_rank_one)

__all__ = ["TimeFit", "fit_time_domain", "NoModeFound", "RESOLVED_BAND_FRACTION", "MIN_CYCLES", "resolved_band_hz"]


#: Highest natural frequency a record resolves, as a fraction of its sample rate. Records are
#: low-pass filtered before sampling: robomill's simulator by a zero-phase 8th-order Butterworth at
#: 0.4 fs, flat to 1 % up to 0.3 fs (:mod:`stability.simulate`), and the anti-alias filter of a
#: data-acquisition system also starts to roll off between 0.3 and 0.45 fs. Above 0.3 fs the
#: recorded response is shaped by that filter (and folded), not by the structure, so no mode is
#: placed there; a mode pinned at this limit stands for response from modes above it.
RESOLVED_BAND_FRACTION = 0.3
#: Fewest cycles of a mode in the (longest) record for the fit to tell it from a trend and a free
#: response: the bottom of the band the records resolve is ``MIN_CYCLES / duration``, and not
#: below :data:`MIN_SCAN_HZ`.
MIN_CYCLES = 4.0
MIN_SCAN_HZ = 0.5


def resolved_band_hz(sample_rate_hz: float) -> float:
    """Highest natural frequency, Hz, that a record sampled at ``sample_rate_hz`` resolves
    (:data:`RESOLVED_BAND_FRACTION` of it)."""
    return RESOLVED_BAND_FRACTION * float(sample_rate_hz)


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



def _nls(prob, fn, zeta, max_damping, *, rough=False):
    n = fn.size
    # each refinement may move a frequency by +-0.3 in log, never out of the band the records resolve
    lf, lf_lo, lf_hi = prob.frequency_bounds(fn, 0.3)
    th0 = np.concatenate([lf, np.log(np.clip(zeta, MIN_DAMPING * 1.01, max_damping * 0.99))])
    lo = np.concatenate([lf_lo, np.full(n, np.log(MIN_DAMPING))])
    hi = np.concatenate([lf_hi, np.full(n, np.log(max_damping))])
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
    max_frequency_hz: float | None = None,
    force_noise_variance_N2=None,
    keep_samples=None,
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
    max_frequency_hz : float, optional
        Highest natural frequency fitted, Hz; :func:`resolved_band_hz` by default. (The lowest is
        :data:`MIN_CYCLES` cycles in the longest record.) A mode the fit pins at either end stands
        for response the band's modes cannot follow: kept in the fit, left out of the model
        (``TimeFit.above_band_hz``, ``below_band_hz``).
    keep_samples : sequence of (ndarray of bool or None), optional
        Per record, the samples compared with the model (True); the measured force still drives
        the model through those left out (spikes, edge artefacts: :mod:`oma._timefit_artefacts`).
        All by default.
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
    recs = _prepare(sigs, harm, inputs, outputs, derivative, keep=keep_samples)
    noise = np.broadcast_to(np.asarray(force_noise_variance_N2 if force_noise_variance_N2 is not None else 0.0,
                                       dtype=float), (len(recs),))
    for rec, v in zip(recs, noise):
        rec["force_noise"] = float(v)
    f_max = resolved_band_hz(recs[0]["fs"]) if max_frequency_hz is None else float(max_frequency_hz)
    # a mode needs a few cycles in the records to be told from a trend and a free response: at
    # least MIN_CYCLES in the longest (the records share their modes)
    f_min = max(MIN_CYCLES / max(r["t"][-1] for r in recs), MIN_SCAN_HZ)
    prob = _Problem(recs, residual=residual, band_hz=(f_min, f_max))
    used = np.concatenate([np.ones(r["y"].shape[1], dtype=bool) if r["w"] is None else r["w"] > 0 for r in recs])
    n_total = int(used.sum()) * outputs.size

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
    grid = np.exp(np.arange(np.log(f_min), np.log(f_max), scan_spacing))
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
        return _time_fit_from_rank_one(cur["r1"], recs, inputs, outputs, dropped, split_hz, source, message,
                                       band_hz=(f_min, f_max))
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
    rms, ferr = _misfit(y_all[:, used], pred[:, used], nuis_part[:, used], recs, outputs, quantised)
    a, res_c = prob.unpack_residues(list(beta), fn.size)
    pole_se, n_blocks = (np.full(2 * fn.size, np.nan), 0) if quantised else \
        _ls_block_sandwich(prob, fn, zeta, beta, xd, y_all - pred, n_used=int(used.sum()))

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
    # a mode pinned at an end of the resolved band stands for response the band's modes cannot
    # follow: kept in the fit, left out of the model (TimeFit.above_band_hz, below_band_hz)
    above, below, edge = _band_edges(np.asarray(freqs), visible, (f_min, f_max))
    visible = visible & ~edge
    if not np.any(visible):
        raise NoModeFound("the time-domain fit left no mode inside the band the records resolve")
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
        dropped_modes_hz=tuple(dropped), split_modes_hz=tuple(split_hz), above_band_hz=above,
        below_band_hz=below, band_hz=(f_min, f_max), success=bool(converged),
        message=message, frequency_se_hz=fn[pole] * pole_se[pole], damping_se=zeta[pole] * pole_se[fn.size + pole],
        n_blocks=n_blocks, residual=_full_residual(y_all - pred, outputs),
    )
