"""Pole-residue fits of measured FRFs, and which of their modes are real.

Three stages, as in experimental modal analysis practice (the whole chain to a
:class:`~oma.modal.ModalModel` is :func:`oma.modal_fit.fit_modal_model`):

1. Poles. The stabilisation diagram of least-squares complex-frequency (LSCF) fits at increasing
   model order (:mod:`oma.lscf`): poles stable over many orders are the candidate modes.
2. Refinement. Nonlinear least squares on the complex FRFs, weighted by the inverse random error
   of the estimate (from the coherence, Bendat & Piersol), by variable projection (Golub & Pereyra
   2003): the natural frequencies and damping ratios are the nonlinear unknowns; residues and the
   residual compliance of out-of-band modes are solved linearly at each step, and the Jacobian is
   analytic. A final pass fits the :class:`~oma.modal.ModalModel` form itself (rank-one residues
   ``u u^T / m``).
3. Selection. A mode is kept when it is a resonance of the band (natural frequency inside the
   fitted lines, damping not pinned at its bound), has a real mode shape where several entries
   share it (modal phase collinearity, Pappa et al. 1993), and lowers the Bayesian information
   criterion counted with the effective number of independent residuals (their autocorrelation
   along frequency, Geyer 1992), not every line as if the errors were white.

Model of entry ``(o, i)``, ``w`` in rad/s::

    H_oi(w) = sum_r (A_r,oi + i w B_r,oi) / (w_r^2 - w^2 + 2 i zeta_r w_r w) + R_oi - L_oi / w^2

with real ``A`` (``B = 0`` for proportionally damped, real modes, the ModalModel form),
residual compliance ``R`` (modes above the band) and optional residual mass ``L`` (modes below).

References
----------
G. Golub, V. Pereyra, "The differentiation of pseudo-inverses and nonlinear least squares problems
whose variables separate", SIAM J. Numer. Anal. 10 (1973) 413-432.
G. Golub, V. Pereyra, "Separable nonlinear least squares: the variable projection method and its
applications", Inverse Problems 19 (2003) R1-R26.
R. S. Pappa, K. B. Elliott, A. Schenk, "Consistent-mode indicator for the eigensystem realization
algorithm", J. Guidance, Control, and Dynamics 16 (1993) 852-858.
C. J. Geyer, "Practical Markov chain Monte Carlo", Statistical Science 7 (1992) 473-483.
G. Schwarz, "Estimating the dimension of a model", Ann. Statist. 6 (1978) 461-464.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import optimize

from ._arrays import readonly as _ro
from ._linalg import blas_single_threaded
from .modal import hz_to_rad_s

__all__ = [
    "PoleResidueFit",
    "fit_poles_residues",
    "prune_modes",
    "modal_phase_collinearity",
    "modal_basis",
    "relative_fit_error",
]


def modal_basis(freq_hz, natural_frequency_hz, damping_ratio) -> np.ndarray:
    """``1 / (w_r^2 - w^2 + 2 i zeta_r w_r w)``, shape (n_modes, n_freq), s^2 (per unit mass)."""
    w = hz_to_rad_s(freq_hz)[None, :]
    wr = hz_to_rad_s(np.atleast_1d(natural_frequency_hz))[:, None]
    z = np.atleast_1d(np.asarray(damping_ratio, dtype=float))[:, None]
    return 1.0 / (wr**2 - w**2 + 2j * z * wr * w)


# =============================================================================== pole-residue NLLS
@dataclass(frozen=True)
class PoleResidueFit:
    """Result of :func:`fit_poles_residues`.

    Attributes
    ----------
    natural_frequency_hz, damping_ratio : ndarray, shape (n_modes,)
    residues : ndarray, shape (n_modes, n_entries)
        Real residues ``A_r,e`` (m/N s^-2 for receptance): ``A = u_o u_i / m_r`` for real modes.
    residues_imag : ndarray, shape (n_modes, n_entries)
        ``B_r,e`` (the ``i w`` numerator term of non-proportionally damped modes; zero unless asked).
    upper_residual : ndarray, shape (n_entries,)
        Residual compliance ``R_e``.
    lower_residual : ndarray, shape (n_entries,)
        Residual mass term ``L_e`` (the model has ``- L / w^2``).
    fit_error : ndarray, shape (n_entries,)
        Weighted relative error ``||W (H - H_fit)|| / ||W H||`` per entry.
    rss : float
        Weighted residual sum of squares (real and imaginary parts).
    n_data : int
        Number of real data values fitted.
    n_parameters : int
    success : bool
    message : str
    """

    natural_frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    residues: np.ndarray
    residues_imag: np.ndarray
    upper_residual: np.ndarray
    lower_residual: np.ndarray
    fit_error: np.ndarray
    rss: float
    n_data: int
    n_parameters: int
    success: bool = True
    message: str = ""

    def __post_init__(self):
        for name in ("natural_frequency_hz", "damping_ratio", "residues", "residues_imag", "upper_residual",
                     "lower_residual", "fit_error"):
            object.__setattr__(self, name, _ro(getattr(self, name)))

    @property
    def n_modes(self) -> int:
        return int(self.natural_frequency_hz.size)

    @property
    def bic(self) -> float:
        """Bayesian information criterion of the weighted fit (Gaussian errors)."""
        return float(self.n_data * np.log(max(self.rss, 1e-300) / self.n_data) + self.n_parameters * np.log(self.n_data))

    def evaluate(self, freq_hz) -> np.ndarray:
        """The fitted FRFs at ``freq_hz``, shape (n_entries, n_freq)."""
        basis = modal_basis(freq_hz, self.natural_frequency_hz, self.damping_ratio)
        w = hz_to_rad_s(freq_hz)
        num = self.residues[:, :, None] + 1j * w[None, None, :] * self.residues_imag[:, :, None]
        with np.errstate(divide="ignore"):
            lower = -self.lower_residual[:, None] / w[None, :] ** 2
        lower = np.where(np.isfinite(lower), lower, 0.0)
        return np.einsum("ref,rf->ef", num, basis) + self.upper_residual[:, None] + lower


def relative_fit_error(data, model, weights=None) -> np.ndarray:
    """``||W (data - model)|| / ||W data||`` along the last axis."""
    d = np.asarray(data)
    m = np.asarray(model)
    w = np.ones(d.shape) if weights is None else np.broadcast_to(weights, d.shape)
    num = np.sqrt(np.sum(np.abs(w * (d - m)) ** 2, axis=-1))
    den = np.sqrt(np.sum(np.abs(w * d) ** 2, axis=-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return num / den


class _PoleResidueProblem:
    """Variable-projection least squares: poles nonlinear, residues and residual terms linear.

    All entries share the column functions of the design (the modal basis and the residual
    terms); entries differ only in their weights. The linear problem therefore splits into one
    small problem per slot (entries sharing residues), whose normal matrix
    ``Re(G^H diag(sum_e w_e^2) G)`` costs one ``(p x n_freq) (n_freq x p)`` product.
    :meth:`jacobian_theta` is the exact variable-projection Jacobian
    ``-(P_perp dA c + A (A^T A)^-1 dA^T r)`` (Golub & Pereyra 1973), with the derivatives of the
    modal basis in closed form: one Jacobian costs about as much as one residual, where finite
    differences cost ``2 n_modes`` residuals.

    The stacked residual is ``[Re(r).ravel(), Im(r).ravel()]`` with ``r`` of shape
    (n_entries, n_freq), ``r_e = w_e (h_e - G c_slot(e)) / scale``.
    """

    def __init__(self, freq_hz, frf, weights, slots, *, upper, lower, complex_modes):
        self.f = np.asarray(freq_hz, dtype=float)
        self.w_rad = hz_to_rad_s(self.f)
        self.h = np.asarray(frf, dtype=complex)
        wt = np.asarray(weights, dtype=float)
        self.slots = np.asarray(slots, dtype=int)
        self.n_slots = int(self.slots.max()) + 1
        self.upper, self.lower, self.complex_modes = upper, lower, complex_modes
        y = np.concatenate([(wt * self.h).real.ravel(), (wt * self.h).imag.ravel()])
        # residuals relative to the data's rms keep the optimiser's tolerances meaningful
        self.scale = float(np.sqrt(np.mean(y**2))) or 1.0
        self.wt = wt / self.scale
        self.y = y / self.scale
        self.n_data = int(y.size)
        self.per_mode = 2 if complex_modes else 1
        w2 = self.wt**2
        # one-hot (n_slots, n_entries): sums over the entries of each slot
        self._slot_sum = (self.slots[None, :] == np.arange(self.n_slots)[:, None]).astype(float)
        # per slot: summed squared weights, and weighted data, shape (n_slots, n_freq)
        self._w2_slot = self._slot_sum @ w2
        self._w2h_slot = self._slot_sum @ (w2 * self.h)
        fixed = []
        if upper:
            fixed.append(np.ones(self.f.size))
        if lower:
            with np.errstate(divide="ignore"):
                fixed.append(np.where(self.w_rad > 0, -1.0 / self.w_rad**2, 0.0))
        self._fixed = np.array(fixed, dtype=complex).reshape(len(fixed), self.f.size).T  # (n_freq, n_fixed)
        self._cache_key = None
        self._cache = None

    # ------------------------------------------------------------------ linear part
    def _columns(self, basis):
        """Design columns shared by all entries, shape (n_freq, p): per mode basis (and i w basis)."""
        n = basis.shape[0]
        cols = np.empty((self.f.size, n * self.per_mode + self._fixed.shape[1]), dtype=complex)
        if self.complex_modes:
            cols[:, 0 : 2 * n : 2] = basis.T
            cols[:, 1 : 2 * n : 2] = (1j * self.w_rad)[:, None] * basis.T
        else:
            cols[:, :n] = basis.T
        cols[:, n * self.per_mode :] = self._fixed
        return cols

    def _state(self, fn, zeta):
        """Columns, coefficients, factorisations and residual at (fn, zeta), cached."""
        fn = np.atleast_1d(np.asarray(fn, dtype=float))
        zeta = np.atleast_1d(np.asarray(zeta, dtype=float))
        key = (fn.tobytes(), zeta.tobytes())
        if key == self._cache_key:
            return self._cache
        from scipy.linalg import cho_factor

        basis = modal_basis(self.f, fn, zeta)
        g = self._columns(basis)
        gr, gi = np.ascontiguousarray(g.real), np.ascontiguousarray(g.imag)
        # Re(G^H W G) and Re(G^H W h) in real arithmetic (BLAS does not mix real and complex)
        normal = (self._w2_slot[:, None, :] * gr.T[None]) @ gr + (self._w2_slot[:, None, :] * gi.T[None]) @ gi
        rhs = self._w2h_slot.real @ gr + self._w2h_slot.imag @ gi  # (n_slots, p)
        p = g.shape[1]
        if p == 0:  # no mode and no residual term: the model is zero
            state = dict(basis=basis, gr=gr, gi=gi, coef=np.zeros((self.n_slots, 0)), factors=[],
                         col_scale=np.ones((self.n_slots, 0)), r=self.wt * self.h, fn=fn, zeta=zeta)
            self._cache_key, self._cache = key, state
            return state
        scale = np.sqrt(np.maximum(np.einsum("spp->sp", normal), 0.0))
        scale[scale == 0] = 1.0
        factors, coef = [], np.zeros((self.n_slots, p))
        for s in range(self.n_slots):
            ns = normal[s] / np.outer(scale[s], scale[s])
            ns[np.diag_indices(p)] += 1e-12  # relative ridge (the scaled diagonal is one)
            try:
                fac = ("chol", cho_factor(ns, check_finite=False))
            except np.linalg.LinAlgError:
                fac = ("pinv", np.linalg.pinv(ns))
            factors.append(fac)
            coef[s] = self._apply(fac, rhs[s] / scale[s]) / scale[s]
        model = coef[self.slots] @ gr.T + 1j * (coef[self.slots] @ gi.T)  # (n_e, n_freq)
        r = self.wt * (self.h - model)
        state = dict(basis=basis, gr=gr, gi=gi, coef=coef, factors=factors, col_scale=scale, r=r, fn=fn, zeta=zeta)
        self._cache_key, self._cache = key, state
        return state

    @staticmethod
    def _apply(fac, b):
        from scipy.linalg import cho_solve

        kind, m = fac
        return cho_solve(m, b, check_finite=False) if kind == "chol" else m @ b

    def _solve_normal(self, st, rhs):
        """``N_s^-1 rhs[..., s, :]`` for every slot; rhs shape (k, n_slots, p)."""
        out = np.empty_like(rhs)
        for s in range(self.n_slots):
            sc = st["col_scale"][s]
            out[:, s, :] = (self._apply(st["factors"][s], (rhs[:, s, :] / sc).T).T) / sc
        return out

    def solve(self, fn, zeta):
        """Linear coefficients (flat, size n_slots * p) and the stacked residual at the poles."""
        st = self._state(fn, zeta)
        r = st["r"]
        return st["coef"].ravel(), np.concatenate([r.real.ravel(), r.imag.ravel()])

    def residual_theta(self, theta):
        return self.solve(*_untheta(theta))[1]

    def jacobian_theta(self, theta):
        """Exact variable-projection Jacobian of the stacked residual w.r.t. (log fn, log zeta)."""
        fn, zeta = _untheta(theta)
        st = self._state(fn, zeta)
        n = fn.size
        basis, gr, gi, coef, r = st["basis"], st["gr"], st["gi"], st["coef"], st["r"]
        n_e, nf = r.shape
        wr = hz_to_rad_s(fn)[:, None]
        w = self.w_rad[None, :]
        b2 = basis**2
        # d basis / d log fn = -basis^2 (2 wr^2 + 2 i zeta wr w); d basis / d log zeta = -basis^2 (2 i zeta wr w)
        d_damp = -b2 * (2j * zeta[:, None] * wr * w)
        d_freq = -b2 * (2.0 * wr**2) + d_damp
        dbasis = np.concatenate([d_freq, d_damp])  # (2n, n_freq)
        mode = np.concatenate([np.arange(n), np.arange(n)])
        pm = self.per_mode
        # numerator of mode m in each slot: A + i w B, shape (2n, n_slots, n_freq)
        a_es = coef[self.slots][:, mode * pm].T  # (2n, n_e)
        if self.complex_modes:
            num = a_es[:, :, None] + coef[self.slots][:, mode * pm + 1].T[:, :, None] * (1j * self.w_rad)
        else:
            num = a_es[:, :, None]
        # v = (dA/dtheta) c, per entry: w_e * dbasis * num_slot(e); shape (2n, n_e, n_freq)
        v = (self.wt[None, :, :] * dbasis[:, None, :]) * num
        # A^T v per slot: sum_e Re(G^H w_e v_e)
        wv = (self._slot_sum @ (self.wt[None] * v)).reshape(-1, nf)  # (2n * n_slots, n_freq)
        atv = (wv.real @ gr + wv.imag @ gi).reshape(2 * n, self.n_slots, -1)  # (2n, n_slots, p)
        # (dA/dtheta)^T r per slot: only the columns of mode m are non-zero
        wrr = self._slot_sum @ (self.wt * r)
        dtr = np.zeros_like(atv)
        k_all = np.arange(2 * n)
        dtr[k_all, :, mode * pm] = dbasis.real @ wrr.real.T + dbasis.imag @ wrr.imag.T
        if self.complex_modes:
            db = 1j * self.w_rad * dbasis
            dtr[k_all, :, mode * pm + 1] = db.real @ wrr.real.T + db.imag @ wrr.imag.T
        x = self._solve_normal(st, atv - dtr)[:, self.slots, :].reshape(2 * n * n_e, -1)  # (2n n_e, p)
        proj = (x @ gr.T + 1j * (x @ gi.T)).reshape(2 * n, n_e, nf)
        jac_c = (-v + self.wt[None] * proj).reshape(2 * n, -1)
        return np.concatenate([jac_c.real, jac_c.imag], axis=1).T

    def unpack(self, coef, n_modes):
        coef = np.asarray(coef).reshape(self.n_slots, -1)
        pm = self.per_mode
        res = coef[:, 0 : n_modes * pm : pm].T
        res_i = coef[:, 1 : n_modes * pm : pm].T if self.complex_modes else np.zeros((n_modes, self.n_slots))
        k = n_modes * pm
        up = coef[:, k] if self.upper else np.zeros(self.n_slots)
        lo = coef[:, k + int(self.upper)] if self.lower else np.zeros(self.n_slots)
        return res[:, self.slots], res_i[:, self.slots], up[self.slots], lo[self.slots]

    def n_parameters(self, n_modes):
        """Linear and nonlinear parameters of a fit with ``n_modes`` modes."""
        return self.n_slots * (n_modes * self.per_mode + self._fixed.shape[1]) + 2 * n_modes


def _fit_inputs(freq_hz, frf, weights, slots):
    """Lines, FRFs (n_entries, n_freq), finite non-negative weights and slot indices as arrays."""
    h = np.array(frf, dtype=complex, ndmin=2)
    wt = np.ones(h.shape) if weights is None else np.array(np.broadcast_to(weights, h.shape), dtype=float)
    slots = np.arange(h.shape[0]) if slots is None else np.asarray(slots, dtype=int)
    return np.asarray(freq_hz, dtype=float), h, np.where(np.isfinite(wt), wt, 0.0), slots


def _theta(fn, zeta):
    return np.concatenate([np.log(fn), np.log(zeta)])


def _untheta(theta):
    n = theta.size // 2
    return np.exp(theta[:n]), np.exp(theta[n:])


@blas_single_threaded
def fit_poles_residues(
    freq_hz,
    frf,
    natural_frequency_hz,
    damping_ratio,
    *,
    weights=None,
    slots: Sequence[int] | None = None,
    upper_residual: bool = True,
    lower_residual: bool = False,
    complex_modes: bool = False,
    max_damping: float = 0.5,
) -> PoleResidueFit:
    """Refine poles and residues of FRFs by weighted nonlinear least squares (variable projection).

    The natural frequencies stay inside the band of ``freq_hz``: a resonance is identified from
    the lines around it, and dynamics outside the band are what the residual terms are for.

    Parameters
    ----------
    freq_hz : array_like, shape (n_freq,)
    frf : array_like, shape (n_entries, n_freq), complex
    natural_frequency_hz, damping_ratio : array_like, shape (n_modes,)
        Starting poles (e.g. from :func:`stabilisation_diagram`).
    weights : array_like, shape (n_entries, n_freq), optional
        Weights of the complex residuals, ideally ``1 / std(H)``; default 1.
    slots : sequence of int, shape (n_entries,), optional
        Entries with the same slot share their residues (reciprocity ``H_oi = H_io``); default all
        distinct.
    upper_residual, lower_residual : bool
        Fit a residual compliance ``R`` / a residual mass term ``-L/w^2`` per slot.
    complex_modes : bool
        Allow the ``i w B`` numerator (non-proportional damping).
    max_damping : float
        Upper bound of the damping ratio.

    Returns
    -------
    PoleResidueFit
    """
    f, h, wt, slots = _fit_inputs(freq_hz, frf, weights, slots)
    prob = _PoleResidueProblem(f, h, wt, slots, upper=upper_residual, lower=lower_residual,
                               complex_modes=complex_modes)
    fn0 = np.atleast_1d(np.asarray(natural_frequency_hz, dtype=float))
    z0 = np.clip(np.atleast_1d(np.asarray(damping_ratio, dtype=float)), 1e-4, max_damping * 0.99)
    n_modes = fn0.size
    if n_modes:
        f_lo = max(float(f.min()), 1e-3)
        lo = np.concatenate([np.full(n_modes, np.log(f_lo)), np.full(n_modes, np.log(1e-4))])
        hi = np.concatenate([np.full(n_modes, np.log(max(float(f.max()), f_lo * (1 + 1e-6)))),
                             np.full(n_modes, np.log(max_damping))])
        th0 = np.clip(_theta(np.maximum(fn0, 1e-3), z0), lo + 1e-9, hi - 1e-9)
        sol = optimize.least_squares(prob.residual_theta, th0, jac=prob.jacobian_theta, bounds=(lo, hi),
                                     x_scale=np.concatenate([np.full(n_modes, 0.01), np.full(n_modes, 0.1)]),
                                     xtol=1e-10, ftol=1e-12, max_nfev=40 * (n_modes + 1))
        fn, zeta = _untheta(sol.x)
        success, message = bool(sol.status > 0), str(sol.message)
    else:
        fn, zeta = fn0, z0
        success, message = True, "no modes"
    return _pole_residue_result(prob, h, wt, fn, zeta, success, message)


def _pole_residue_result(prob, h, wt, fn, zeta, success, message) -> PoleResidueFit:
    order = np.argsort(fn)
    fn, zeta = fn[order], zeta[order]
    coef, resid = prob.solve(fn, zeta)
    res, res_i, up, low = prob.unpack(coef, fn.size)
    fit = PoleResidueFit(
        natural_frequency_hz=fn, damping_ratio=zeta, residues=res, residues_imag=res_i,
        upper_residual=up, lower_residual=low, fit_error=np.zeros(h.shape[0]),
        rss=float(resid @ resid), n_data=int(2 * h.size), n_parameters=prob.n_parameters(fn.size),
        success=success, message=message,
    )
    err = relative_fit_error(h, fit.evaluate(prob.f), wt)
    return PoleResidueFit(**{**fit.__dict__, "fit_error": err})


# =============================================================================== which modes are real
def modal_phase_collinearity(residues) -> np.ndarray:
    """Modal phase collinearity (MPC) of complex residue (or mode-shape) vectors.

    ``MPC = ((l1 - l2) / (l1 + l2))^2`` with ``l1 >= l2`` the eigenvalues of the 2 x 2 matrix of
    the real and imaginary parts' inner products (Pappa, Elliott & Schenk 1993): 1 when every
    component has the same phase up to 180 degrees (a real mode shape, whatever its common phase),
    towards 0 when the phases scatter, which the residues of a lightly damped structure's mode do
    not do.

    Parameters
    ----------
    residues : array_like, shape (n_modes, n_components), complex

    Returns
    -------
    ndarray, shape (n_modes,)
    """
    r = np.array(residues, dtype=complex, ndmin=2)
    x = np.stack([r.real, r.imag], axis=-1)  # (n_modes, n_components, 2)
    s2 = np.linalg.svd(x, compute_uv=False) ** 2
    total = s2.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mpc = ((s2[:, 0] - s2[:, -1]) / total) ** 2
    return np.where(total > 0, mpc, 1.0)


def _effective_fraction(resid, n_sequences) -> float:
    """``1 / tau``: the share of independent values in residual sequences along frequency.

    ``tau = 1 + 2 sum_k rho_k`` is the integrated autocorrelation time of the residuals (their
    autocorrelation ``rho_k`` pooled over the sequences), summed by Geyer's initial positive
    sequence: pairs ``rho_2m + rho_2m+1`` up to the first that is not positive, where the
    estimate turns to noise (Geyer 1992). White residuals give ``tau = 1``; residuals of a
    windowed spectral estimate (adjacent Welch lines are correlated) or of a model that misses a
    smooth systematic error give ``tau > 1``, and an information criterion that counted every
    line as independent would buy modes with them.

    References
    ----------
    C. J. Geyer, "Practical Markov chain Monte Carlo", Statistical Science 7 (1992) 473-483.
    """
    x = np.asarray(resid, dtype=float).reshape(n_sequences, -1)
    n = x.shape[1]
    if n < 4:
        return 1.0
    x = x - x.mean(axis=1, keepdims=True)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    spec = np.fft.rfft(x, nfft, axis=1)
    acov = np.fft.irfft(np.abs(spec) ** 2, nfft, axis=1)[:, :n].sum(axis=0)
    if acov[0] <= 0:
        return 1.0
    rho = acov / acov[0]
    pairs = rho[: 2 * (n // 2)].reshape(-1, 2).sum(axis=1)  # rho_2m + rho_2m+1
    stop = np.flatnonzero(pairs <= 0)
    pairs = pairs[: stop[0]] if stop.size else pairs
    tau = -1.0 + 2.0 * float(np.sum(pairs))
    return float(1.0 / min(max(tau, 1.0), n))


def _bic(rss, n_parameters, n_data, fraction=1.0) -> float:
    """BIC of a Gaussian fit with ``fraction * n_data`` independent values (Schwarz 1978)."""
    n_eff = max(fraction * n_data, 1.0)
    return float(n_eff * np.log(max(rss, 1e-300) / n_data) + n_parameters * np.log(n_eff))


def _unphysical(fit: PoleResidueFit, f, slots, *, min_mpc: float, max_damping: float) -> np.ndarray:
    """Modes that are no resonance of the band's data, as a boolean mask.

    - out of band: the natural frequency is not at least half a line inside the fitted lines
      (a pole pinned at the band's edge models out-of-band dynamics, the residual terms' job);
    - pinned at the damping bound (within 1 %): an optimum on the bound is no estimate, and a
      pole that damped has no resonance peak; it stands in for a smooth trend;
    - complex residues whose phases scatter (MPC below ``min_mpc``, where two or more distinct
      slots are fitted): no real mode shape produces them; such a pole absorbs model error.
    """
    fn = fit.natural_frequency_hz
    df = float(np.median(np.diff(f))) if f.size > 1 else 0.0
    bad = (fn <= f.min() + 0.5 * df) | (fn >= f.max() - 0.5 * df) | (fit.damping_ratio >= 0.99 * max_damping)
    _, first = np.unique(slots, return_index=True)
    if first.size >= 2 and np.any(fit.residues_imag):
        wr = hz_to_rad_s(fn)[:, None]
        res = fit.residues[:, first] + 1j * wr * fit.residues_imag[:, first]
        bad |= modal_phase_collinearity(res) < min_mpc
    return bad


def _select_modes(f, h, wt, slots, fit: PoleResidueFit, *, upper_residual, lower_residual, complex_modes,
                  max_damping, min_mpc):
    """Drop unphysical modes, then modes that do not lower the BIC; returns (fit, dropped_hz)."""
    prob = _PoleResidueProblem(f, h, wt, slots, upper=upper_residual, lower=lower_residual,
                               complex_modes=complex_modes)
    opts = dict(weights=wt, slots=slots, upper_residual=upper_residual, lower_residual=lower_residual,
                complex_modes=complex_modes, max_damping=max_damping)
    n_data = prob.n_data
    dropped = []
    fraction = None
    while fit.n_modes:
        bad = _unphysical(fit, f, slots, min_mpc=min_mpc, max_damping=max_damping)
        if np.all(bad):
            # nothing in the band passes: keep the fit, and say it is not a physical one
            fit = dataclasses.replace(fit, success=False, message=(
                "no mode passes the checks (resonance inside the band, damping below its bound, "
                "collinear residues): the poles are not physical modes"))
            break
        if np.any(bad):
            dropped.extend(float(x) for x in fit.natural_frequency_hz[bad])
            fit = fit_poles_residues(f, h, fit.natural_frequency_hz[~bad], fit.damping_ratio[~bad], **opts)
            continue
        if fraction is None:
            # the noise model: correlation of the residuals of the largest physical fit
            fraction = _effective_fraction(prob.solve(fit.natural_frequency_hz, fit.damping_ratio)[1],
                                           2 * h.shape[0])
        current = _bic(fit.rss, fit.n_parameters, n_data, fraction)
        if fit.n_modes < 2:
            # the last mode must beat the residual terms alone; if it does not, it is kept (a
            # model needs a mode) and the fit says it is not significant
            _, resid = prob.solve(np.zeros(0), np.zeros(0))
            if _bic(float(resid @ resid), prob.n_parameters(0), n_data, fraction) <= current:
                fit = dataclasses.replace(fit, success=False, message=(
                    "the only mode left does not lower the information criterion below that of the "
                    "residual terms alone: it is not significant"))
            break
        # screen every removal with the other (refined) poles held, then refit the best one
        scores = []
        for r in range(fit.n_modes):
            keep = np.arange(fit.n_modes) != r
            _, resid = prob.solve(fit.natural_frequency_hz[keep], fit.damping_ratio[keep])
            scores.append(_bic(float(resid @ resid), prob.n_parameters(fit.n_modes - 1), n_data, fraction))
        r = int(np.argmin(scores))
        if scores[r] >= current:
            break
        keep = np.arange(fit.n_modes) != r
        cand = fit_poles_residues(f, h, fit.natural_frequency_hz[keep], fit.damping_ratio[keep], **opts)
        if _bic(cand.rss, cand.n_parameters, n_data, fraction) >= current:
            break
        dropped.append(float(fit.natural_frequency_hz[r]))
        fit = cand
    return fit, dropped


@blas_single_threaded
def prune_modes(freq_hz, frf, fit: PoleResidueFit, *, weights=None, slots=None, upper_residual: bool = True,
                lower_residual: bool = False, complex_modes: bool = False, max_damping: float = 0.5,
                min_mpc: float = 0.5) -> PoleResidueFit:
    """Keep the modes of a :func:`fit_poles_residues` result that the data support.

    A mode must be a resonance of the band (natural frequency inside the fitted lines), have a
    real mode shape where several slots share its pole (modal phase collinearity of its complex
    residues at least ``min_mpc``, see :func:`modal_phase_collinearity`), and earn its parameters:
    removing it must raise the Bayesian information criterion, counted with the effective number
    of independent residuals (their autocorrelation along frequency, see
    :func:`_effective_fraction`), not every line as if the errors were white. Each round screens
    every removal with the other poles held (linear least squares only), refits the best
    candidate by nonlinear least squares and keeps it if its BIC is lower.

    At least one mode is returned: when no mode passes the checks, or the last one does not beat
    the residual terms alone, it is kept and the result has ``success=False`` and says why in
    ``message``. Other arguments as in :func:`fit_poles_residues`.

    Returns
    -------
    PoleResidueFit
    """
    f, h, wt, slots = _fit_inputs(freq_hz, frf, weights, slots)
    fit, _ = _select_modes(f, h, wt, slots, fit, upper_residual=upper_residual, lower_residual=lower_residual,
                           complex_modes=complex_modes, max_damping=max_damping, min_mpc=min_mpc)
    return fit
