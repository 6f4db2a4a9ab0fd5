"""The modal model of measured FRFs: stabilisation diagram, pole-residue fit, then the ModalModel form.

:func:`fit_modal_model` is the frequency-domain modal fit of ``robomill identify`` (the paper's
estimator when ``--method h1``, the start of the time-domain fit otherwise): poles from the
stabilisation diagram (:mod:`oma.lscf`), refined and selected by the pole-residue fit of
:mod:`oma.fit`, then each pole's residue split into rank-one parts ``u u^T / k`` (real mode
shapes) and the whole refined in that form by nonlinear least squares, residual compliance of
out-of-band modes included.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from ._linalg import blas_single_threaded
from .fit import PoleResidueFit, _PoleResidueProblem, _select_modes, fit_poles_residues, modal_basis
from .fit import _bic, _effective_fraction, relative_fit_error
from .frf_table import AXES, FRFTable
from .lscf import StabilisationDiagram, stabilisation_diagram
from .modal import ModalModel, hz_to_rad_s

__all__ = ["ModalFit", "fit_modal_model"]


@dataclass(frozen=True)
class ModalFit:
    """A :class:`ModalModel` fitted to an FRF table, with how well it fits.

    Attributes
    ----------
    model : ModalModel
    fit_error : dict
        Weighted relative error ``||W (H - G)|| / ||W H||`` per measured entry (``"XX"`` ...) in the
        fitted band.
    band_hz : (float, float)
    diagram : StabilisationDiagram or None
    pole_residue : PoleResidueFit
        The unconstrained (free residue) fit that preceded the ModalModel fit.
    dropped_modes_hz : tuple of float
        Candidate modes removed by the selection (out of band, pinned at the damping bound, or
        not lowering the information criterion).
    success : bool
    message : str
    """

    model: ModalModel
    fit_error: dict
    band_hz: tuple
    diagram: StabilisationDiagram | None
    pole_residue: PoleResidueFit
    dropped_modes_hz: tuple = ()
    success: bool = True
    message: str = ""

    def axis_fit_error(self) -> dict:
        """Fit error of the direct entries, keyed by axis (``"X"`` ...)."""
        return {k[0]: v for k, v in self.fit_error.items() if k[0] == k[1]}


def _entries_and_slots(measured):
    entries = [(o, i) for o in range(3) for i in range(3) if measured[o, i]]
    slot_of = {}
    slots = []
    for o, i in entries:
        key = (min(o, i), max(o, i))
        slot_of.setdefault(key, len(slot_of))
        slots.append(slot_of[key])
    return entries, np.array(slots)


def _residue_matrix(entries, residues_r):
    """Symmetric 3 x 3 residue of one mode from its measured entries, and whether cross terms were seen."""
    a = np.zeros((3, 3))
    seen = np.zeros((3, 3), dtype=bool)
    for (o, i), v in zip(entries, residues_r):
        a[o, i] += v
        seen[o, i] = True
    both = seen & seen.T
    sym = np.where(both, 0.5 * (a + a.T), np.where(seen, a, a.T))
    return sym, bool(np.any(seen & ~np.eye(3, dtype=bool)))


def _residue_modes(entries, residues_r, omega_r, *, max_modes: int = 3, min_ratio: float = 0.2):
    """Modes ``(u, k)`` sharing one pole whose residues sum to the fitted residue matrix.

    The ModalModel form has rank-one residues ``u u^T / m``. A fitted symmetric residue of rank
    two or three means as many modes at (nearly) the same frequency along different directions
    (e.g. robot modes along X and Z a few percent apart, which a short record cannot separate in
    frequency): every positive eigenvalue of at least ``min_ratio`` times the largest becomes a
    mode with that eigenvector. Without measured cross terms only one mode is formed, along
    ``sqrt(diag)`` (the signs of its components are then unknown and taken positive).
    """
    sym, cross = _residue_matrix(entries, residues_r)
    out = []
    if cross:
        evals, evecs = np.linalg.eigh(sym)
        order = np.argsort(evals)[::-1]
        lam_max = evals[order[0]]
        if lam_max <= 0 and evals[order[-1]] < 0:
            # the fit flipped the sign of the whole residue; keep the magnitude
            evals, order = -evals, order[::-1]
            lam_max = evals[order[0]]
        for j in order[:max_modes]:
            lam = evals[j]
            if lam <= 0 or lam < min_ratio * lam_max:
                continue
            u = evecs[:, j] / np.linalg.norm(evecs[:, j])
            u = u * np.sign(u[np.argmax(np.abs(u))])
            out.append((u, omega_r**2 / lam))
    else:
        diag = np.abs(np.diag(sym))
        lam = float(np.sum(diag))
        if lam > 0:
            u = np.sqrt(diag) / np.sqrt(lam)
            out.append((u, omega_r**2 / lam))
    return out


def _modal_nlls(freq, h, wt, entries, slots, model0: ModalModel, *, residual: bool, max_damping: float,
                max_nfev: int | None = None):
    """Fit the ModalModel form (rank-one residues) by variable projection over (fn, zeta, phi).

    Entry ``(o, i)`` is ``sum_r phi_ro phi_ri / (w_r^2 - w^2 + 2 i zeta_r w_r w)`` plus a real
    residual compliance per slot, projected out exactly (it enters linearly and its column does
    not depend on the nonlinear parameters). The Jacobian is analytic. ``max_nfev`` caps the
    optimiser's evaluations (default 100 per parameter).
    """
    n = model0.n_modes
    rows = sorted({o for o, _ in entries} | {i for _, i in entries})
    nr = len(rows)
    o_idx = np.array([rows.index(o) for o, _ in entries])
    i_idx = np.array([rows.index(i) for _, i in entries])
    phi0 = model0.directions / np.sqrt(model0.modal_mass_kg)[:, None]  # u / sqrt(m)
    n_e = len(entries)
    y = np.concatenate([(wt * h).real.ravel(), (wt * h).imag.ravel()])
    y_scale = float(np.sqrt(np.mean(y**2))) or 1.0
    wt = wt / y_scale
    wh = wt * h
    n_slots = int(slots.max()) + 1
    slot_sum = (np.asarray(slots)[None, :] == np.arange(n_slots)[:, None]).astype(float)  # (n_slots, n_e)
    col_norm2 = slot_sum @ np.sum(wt**2, axis=1)
    col_norm2 = np.where(col_norm2 > 0, col_norm2, 1.0)
    # one-hot derivatives of phi_ro phi_ri with respect to phi_rj: (nr, n_e) masks
    at_o = (o_idx[None, :] == np.arange(nr)[:, None]).astype(float)
    at_i = (i_idx[None, :] == np.arange(nr)[:, None]).astype(float)

    def split(th):
        return np.exp(th[:n]), np.exp(th[n : 2 * n]), th[2 * n :].reshape(n, nr)

    def project(v_real):
        """Remove the residual-compliance columns from the real parts, shape (..., n_e, n_freq)."""
        coef = (np.sum(wt * v_real, axis=-1) @ slot_sum.T) / col_norm2  # (..., n_slots)
        return v_real - coef[..., slots][..., None] * wt, coef

    cache = {}

    def state(th):
        key = th.tobytes()
        if key not in cache:
            cache.clear()
            fn, z, ph = split(th)
            basis = modal_basis(freq, fn, z)  # (n, nf)
            prod = ph[:, o_idx] * ph[:, i_idx]  # (n, n_e)
            m = prod.T @ basis.real + 1j * (prod.T @ basis.imag)
            rc = wh - wt * m
            rr, coef = project(rc.real) if residual else (rc.real, np.zeros(n_slots))
            cache[key] = (fn, z, ph, basis, prod, rr, rc.imag, coef)
        return cache[key]

    def resid(th):
        *_, rr, ri, _ = state(th)
        return np.concatenate([rr.ravel(), ri.ravel()])

    def jac(th):
        fn, z, ph, basis, prod, *_ = state(th)
        wr = hz_to_rad_s(fn)[:, None]
        w = hz_to_rad_s(freq)[None, :]
        d_damp = -basis**2 * (2j * z[:, None] * wr * w)
        d_freq = -basis**2 * (2.0 * wr**2) + d_damp
        d = np.empty((n, 2 + nr, n_e, freq.size), dtype=complex)
        d[:, 0] = prod[:, :, None] * d_freq[:, None, :]
        d[:, 1] = prod[:, :, None] * d_damp[:, None, :]
        # d(phi_ro phi_ri)/d phi_rj = [o = j] phi_ri + [i = j] phi_ro
        dprod = at_o[None] * ph[:, i_idx][:, None, :] + at_i[None] * ph[:, o_idx][:, None, :]  # (n, nr, n_e)
        d[:, 2:] = dprod[:, :, :, None] * basis[:, None, None, :]
        # parameter order: log fn (n), log zeta (n), phi (n x nr)
        cols = np.concatenate([d[:, 0], d[:, 1], d[:, 2:].reshape(n * nr, n_e, freq.size)])
        cols = -wt[None] * cols
        jr = project(cols.real)[0] if residual else cols.real
        k = cols.shape[0]
        return np.concatenate([jr.reshape(k, -1), cols.imag.reshape(k, -1)], axis=1).T

    th0 = np.concatenate([np.log(model0.natural_frequency_hz), np.log(np.clip(model0.damping_ratio, 1e-4, max_damping * 0.99)),
                          phi0[:, rows].ravel()])
    lo = np.concatenate([np.log(model0.natural_frequency_hz) - 0.5, np.full(n, np.log(1e-4)), np.full(n * nr, -np.inf)])
    hi = np.concatenate([np.log(model0.natural_frequency_hz) + 0.5, np.full(n, np.log(max_damping)), np.full(n * nr, np.inf)])
    pscale = np.max(np.abs(phi0[:, rows])) if n else 1.0
    x_scale = np.concatenate([np.full(n, 0.01), np.full(n, 0.1), np.full(n * nr, 0.1 * pscale)])
    sol = optimize.least_squares(resid, np.clip(th0, lo + 1e-12, hi - 1e-12), jac=jac, bounds=(lo, hi),
                                 x_scale=x_scale, xtol=1e-10, ftol=1e-12, max_nfev=max_nfev or 100 * (len(th0) + 1))
    fn, z, ph, *_, coef = state(sol.x)
    r = resid(sol.x)
    phi = np.zeros((n, 3))
    phi[:, rows] = ph
    return _ModalNLLS(fn, z, phi, coef, float(r @ r), r, sol)


@dataclass(frozen=True)
class _ModalNLLS:
    """One fit of the ModalModel form: per mode ``fn``, ``zeta`` and ``phi = u / sqrt(m)`` (n, 3),
    the residual compliance per slot, the weighted residuals and the optimiser's result."""

    natural_frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    phi: np.ndarray
    residual_coef: np.ndarray
    rss: float
    resid: np.ndarray
    sol: optimize.OptimizeResult

    @property
    def n_modes(self) -> int:
        return int(self.natural_frequency_hz.size)

    def start(self, keep) -> ModalModel:
        """The modes ``keep`` as a ModalModel, the start of a refit without the others (and without
        any whose shape vanished: it has no mass to give)."""
        keep = np.asarray(keep) & (np.linalg.norm(self.phi, axis=1) > 0)
        phi = self.phi[keep]
        norms = np.linalg.norm(phi, axis=1)
        return ModalModel(self.natural_frequency_hz[keep], self.damping_ratio[keep],
                          hz_to_rad_s(self.natural_frequency_hz[keep]) ** 2 / norms**2, phi / norms[:, None])


#: Evaluations allowed to the refit of each candidate removal in :func:`_select_modal`. The removal
#: of a spurious mode converges in tens (4-48 in the traced 10 kHz record, where one other took 261
#: to reach the fit a 39-evaluation one had reached): the others only close the gap it leaves. A
#: removal the remaining modes cannot absorb (the only mode along an axis) wanders for thousands,
#: 2.5 s each at 10 kHz. A capped refit's misfit is an upper bound of its optimum's, so the cap can
#: only keep a mode, never drop one. 200 instead of 50: the same modes in 48 records at 1-10 kHz,
#: CPU median 0.4-0.9 s instead of 0.3-0.5 s.
REMOVAL_MAX_NFEV = 50


def _select_modal(f, h, wt, entries, slots, fit: _ModalNLLS, *, residual: bool, max_damping: float):
    """Backward elimination in the ModalModel form: drop the mode whose removal (the others refitted)
    lowers the BIC most, while one does; returns the fit kept and the frequencies dropped.

    The pole-residue selection (:func:`oma.fit.prune_modes`) judges poles with free residues. Its
    survivors are then split into rank-one modes (:func:`_residue_modes`), and a split of a pole
    that carried two close modes badly (the 10.0 / 10.5 Hz pair of the example cell read as one pole
    at 10.06 Hz with a rank-two residue and one at 10.54 Hz) starts the ModalModel fit with one mode
    too many. That fit has no use for it and parks it where it fits noise: a broad 13.7 Hz mode at
    21 % damping, or a 0.3 %-damped line. Each candidate removal is refitted in full (the remaining
    modes move into the gap), and the criterion counts the residuals' correlation along frequency as
    :func:`oma.fit._bic` does for the pole-residue fit.
    """
    n_data = 2 * h.size
    n_rows = len({o for o, _ in entries} | {i for _, i in entries})
    n_fixed = int(np.max(slots)) + 1 if residual else 0

    def bic(fit_):
        return _bic(fit_.rss, fit_.n_modes * (2 + n_rows) + n_fixed, n_data, fraction)

    fraction = _effective_fraction(fit.resid, 2 * h.shape[0])
    dropped = []
    while fit.n_modes > 1:
        current = bic(fit)
        cands = {}
        for r in range(fit.n_modes):
            start = fit.start(np.arange(fit.n_modes) != r)
            if start.n_modes:
                cands[r] = _modal_nlls(f, h, wt, entries, slots, start, residual=residual, max_damping=max_damping,
                                       max_nfev=REMOVAL_MAX_NFEV)
        if not cands:
            break
        r = min(cands, key=lambda j: bic(cands[j]))
        if bic(cands[r]) >= current:
            break
        dropped.append(float(fit.natural_frequency_hz[r]))
        fit = cands[r]
    return fit, dropped


@blas_single_threaded
def fit_modal_model(
    frf: FRFTable,
    *,
    weights=None,
    band_hz=None,
    n_modes: int | None = None,
    max_order: int = 40,
    residual: bool = True,
    select: bool = True,
    per_entry_poles: bool = True,
    max_damping: float = 0.3,
    source: dict | None = None,
) -> ModalFit:
    """Fit a :class:`ModalModel` to the measured entries of an FRF table.

    Parameters
    ----------
    frf : FRFTable
        Receptance, m/N. Cross entries measured in both directions are constrained reciprocal.
    weights : array_like, shape (3, 3, n_freq), optional
        Weights of the complex residuals, ideally ``1 / std(H)`` (see
        :attr:`oma.frf_estimate.FRFEstimate.std_m_N`); default: from the table's coherence,
        ``sqrt(gamma^2 / (1 - gamma^2)) / |H|`` (the inverse relative random error), or uniform
        when the table has no coherence.
    band_hz : (float, float), optional
        Lines used; default the whole table.
    n_modes : int, optional
        Force the number of modes (the strongest of the stabilisation diagram); by default it is
        chosen from the diagram and pruned by the BIC.
    max_order : int
        Highest LSCF order of the diagram.
    residual : bool
        Fit a residual compliance for the modes out of the band.
    select : bool
        Keep only modes that are resonances of the band and lower the BIC (counted with the
        residuals' autocorrelation, see :func:`prune_modes`). When no candidate passes, the best
        one is kept and the result has ``success=False`` with the reason in ``message``.
    per_entry_poles : bool
        Add the two most stable poles of each direct entry's own diagram to the candidates (close
        modes along different axes, merged by the common denominator).
    max_damping : float
    source : dict, optional
        Provenance stored in the model.

    Returns
    -------
    ModalFit
    """
    f_all = np.asarray(frf.freq_hz)
    sel = np.ones(f_all.size, dtype=bool) if band_hz is None else (f_all >= band_hz[0]) & (f_all <= band_hz[1])
    sel &= f_all > 0
    f = f_all[sel]
    entries, slots = _entries_and_slots(frf.measured)
    if not entries:
        raise ValueError("the FRF table has no measured entry")
    h = np.array([frf.receptance_m_N[o, i][sel] for o, i in entries])
    if weights is not None:
        wt = np.array([np.asarray(weights)[o, i][sel] for o, i in entries], dtype=float)
    elif frf.coherence is not None:
        c = np.clip(np.array([frf.coherence[o, i][sel] for o, i in entries]), 1e-3, 0.999)
        wt = np.sqrt(c / (1 - c)) / np.maximum(np.abs(h), 1e-300)
    else:
        wt = np.ones(h.shape)
    wt = np.where(np.isfinite(wt), wt, 0.0)
    wt = wt / np.max(wt)
    max_order = int(min(max_order, 2 * (f.size // 2) - 2))
    diagram = stabilisation_diagram(f, h, weights=wt, max_order=max_order, max_damping=max_damping)
    fn0, z0 = diagram.natural_frequency_hz, diagram.damping_ratio
    if n_modes is not None:
        fn0, z0 = fn0[:n_modes], z0[:n_modes]
    elif per_entry_poles:
        # modes that dominate one direct entry but merge with a neighbour in the common
        # denominator (close modes along different axes) come back from that entry alone
        fn0, z0 = list(fn0), list(z0)
        for e, (o, i) in enumerate(entries):
            if o != i:
                continue
            d1 = stabilisation_diagram(f, h[e : e + 1], weights=wt[e : e + 1], max_order=min(max_order, 16),
                                       max_damping=max_damping)
            for fc, zc in zip(d1.natural_frequency_hz[:2], d1.damping_ratio[:2]):
                if not fn0 or np.min(np.abs(np.asarray(fn0) - fc) / fc) > diagram.freq_tol:
                    fn0.append(fc)
                    z0.append(zc)
        fn0, z0 = np.asarray(fn0), np.asarray(z0)
    if len(fn0) == 0:
        # too few lines for a stabilisation diagram (short records): start from the peaks of the
        # direct entries, 5 % damping, and let the least squares and the BIC sort them out
        direct = [e for e, (o, i) in enumerate(entries) if o == i] or list(range(len(entries)))
        mag = np.abs(h[direct]) * (wt[direct] > 0)
        peaks = set()
        for row in mag:
            k = np.flatnonzero((row[1:-1] > row[:-2]) & (row[1:-1] >= row[2:])) + 1
            peaks.update(int(j) for j in k[np.argsort(row[k])[::-1][:2]])
        fn0 = np.array(sorted(f[j] for j in peaks))
        z0 = np.full(fn0.size, 0.05)
    dropped = []
    fn0, z0 = np.asarray(fn0, dtype=float), np.asarray(z0, dtype=float)
    if select and n_modes is None and fn0.size > 1:
        # backward elimination with the candidate poles held (linear least squares only): cheap,
        # and it leaves the nonlinear refinement few modes to move
        prob = _PoleResidueProblem(f, h, wt, slots, upper=residual, lower=False, complex_modes=False)
        n_data = 2 * h.size

        def bic_fixed(fn_, z_):
            coef, resid = prob.solve(fn_, z_)
            rss = float(resid @ resid)
            return n_data * np.log(max(rss, 1e-300) / n_data) + (coef.size + 2 * fn_.size) * np.log(n_data)

        current = bic_fixed(fn0, z0)
        while fn0.size > 1:
            scores = [bic_fixed(np.delete(fn0, r), np.delete(z0, r)) for r in range(fn0.size)]
            r = int(np.argmin(scores))
            if scores[r] >= current:
                break
            dropped.append(float(fn0[r]))
            fn0, z0, current = np.delete(fn0, r), np.delete(z0, r), scores[r]
    pr = fit_poles_residues(f, h, fn0, z0, weights=wt, slots=slots, upper_residual=residual, max_damping=max_damping)
    if select and n_modes is None:
        # out-of-band and damping-pinned poles, then the BIC with the residuals' correlation
        pr, more = _select_modes(f, h, wt, slots, pr, upper_residual=residual, lower_residual=False,
                                 complex_modes=False, max_damping=max_damping, min_mpc=0.0)
        dropped.extend(more)
    # initial ModalModel from the rank-one part of the residues
    freqs, zetas, ks, dirs = [], [], [], []
    for r in range(pr.n_modes):
        modes = _residue_modes(entries, pr.residues[r], 2 * np.pi * pr.natural_frequency_hz[r])
        if not modes:
            dropped.append(float(pr.natural_frequency_hz[r]))
            continue
        for j, (u, k) in enumerate(modes):
            # modes sharing a pole start a little apart so that the final fit can separate them
            freqs.append(pr.natural_frequency_hz[r] * (1.0 + 0.01 * j))
            zetas.append(pr.damping_ratio[r])
            ks.append(k)
            dirs.append(u)
    if not freqs:
        raise ValueError("no mode could be fitted to the FRF (no stable pole with a positive residue)")
    model0 = ModalModel(freqs, zetas, ks, np.array(dirs))
    nlls = _modal_nlls(f, h, wt, entries, slots, model0, residual=residual, max_damping=max_damping)
    if select and n_modes is None and nlls.n_modes > 1:
        nlls, more = _select_modal(f, h, wt, entries, slots, nlls, residual=residual, max_damping=max_damping)
        dropped.extend(more)
    fn, z, phi, coef, sol = nlls.natural_frequency_hz, nlls.damping_ratio, nlls.phi, nlls.residual_coef, nlls.sol
    norms = np.linalg.norm(phi, axis=1)
    good = norms > 0
    res_c = np.zeros((3, 3))
    for (o, i), s in zip(entries, slots):
        res_c[o, i] = coef[s]
    res_c = np.where(frf.measured & frf.measured.T, res_c, np.where(frf.measured, res_c, res_c.T))
    res_c = 0.5 * (res_c + res_c.T) if residual else np.zeros((3, 3))
    model = ModalModel(
        natural_frequency_hz=fn[good],
        damping_ratio=z[good],
        stiffness_N_m=(2 * np.pi * fn[good]) ** 2 / norms[good] ** 2,
        directions=phi[good] / norms[good, None],
        residual_compliance_m_N=res_c,
        source=source,
    )
    g = model.receptance(f)
    err = {AXES[o] + AXES[i]: float(relative_fit_error(h[e], g[o, i], wt[e])) for e, (o, i) in enumerate(entries)}
    return ModalFit(
        model=model, fit_error=err, band_hz=(float(f.min()), float(f.max())), diagram=diagram, pole_residue=pr,
        dropped_modes_hz=tuple(dropped), success=bool(sol.success and pr.success),
        message=str(sol.message) if pr.success else f"{pr.message}; {sol.message}",
    )
