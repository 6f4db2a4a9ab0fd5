"""Modal fit of measured FRFs: model order from a stabilisation diagram, then nonlinear least squares.

Two stages, as in experimental modal analysis practice:

1. Poles. A least-squares complex-frequency (LSCF) common-denominator fit of all measured FRFs at
   increasing model order (Guillaume et al. 2003; Peeters et al. 2004 "PolyMAX"). Poles that come
   back at successive orders with the same frequency and damping are stable; those that are stable
   over many orders are the physical modes (the stabilisation diagram).
2. Refinement. Nonlinear least squares on the complex FRFs, weighted by the inverse random error
   of the estimate (from the coherence, Bendat & Piersol), by variable projection (Golub & Pereyra
   2003): the natural frequencies and damping ratios are the nonlinear unknowns; residues and the
   residual compliance of out-of-band modes are solved linearly at each step. A final pass fits
   the :class:`~oma.modal.ModalModel` form itself (rank-one residues ``u u^T / m``). Modes the data
   do not support are dropped by the Bayesian information criterion.

Model of entry ``(o, i)``, ``w`` in rad/s::

    H_oi(w) = sum_r (A_r,oi + i w B_r,oi) / (w_r^2 - w^2 + 2 i zeta_r w_r w) + R_oi - L_oi / w^2

with real ``A`` (``B = 0`` for proportionally damped, real modes, the ModalModel form),
residual compliance ``R`` (modes above the band) and optional residual mass ``L`` (modes below).

References
----------
P. Guillaume, P. Verboven, S. Vanlanduit, H. Van der Auweraer, B. Peeters, "A poly-reference
implementation of the least-squares complex frequency-domain estimator", Proc. IMAC XXI (2003).
B. Peeters, H. Van der Auweraer, P. Guillaume, J. Leuridan, "The PolyMAX frequency-domain method:
a new standard for modal parameter estimation?", Shock and Vibration 11 (2004) 395-409.
G. Golub, V. Pereyra, "Separable nonlinear least squares: the variable projection method and its
applications", Inverse Problems 19 (2003) R1-R26.
G. Schwarz, "Estimating the dimension of a model", Ann. Statist. 6 (1978) 461-464.
"""

from __future__ import annotations

import contextlib
import functools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ._arrays import readonly as _ro
from scipy import optimize

from .frf_table import AXES, FRFTable
from .modal import ModalModel, hz_to_rad_s

__all__ = [
    "StabilisationDiagram",
    "PoleResidueFit",
    "ModalFit",
    "lscf_poles",
    "stabilisation_diagram",
    "fit_poles_residues",
    "fit_modal_model",
    "prune_modes",
    "lstsq_normal",
    "single_threaded_blas",
    "blas_single_threaded",
    "modal_basis",
    "relative_fit_error",
]


def _openblas_thread_controls():
    """(get, set) thread-count functions of the OpenBLAS builds bundled in NumPy and SciPy wheels."""
    import ctypes
    import glob
    import os

    import scipy

    out = []
    for package, pattern, suffix in ((np, "numpy.libs", "64_"), (scipy, "scipy.libs", "")):
        root = os.path.join(os.path.dirname(os.path.dirname(package.__file__)), pattern)
        for path in glob.glob(os.path.join(root, "libscipy_openblas*")):
            try:
                lib = ctypes.CDLL(path)  # the already-loaded library: same handle
                get = getattr(lib, f"scipy_openblas_get_num_threads{suffix}")
                set_ = getattr(lib, f"scipy_openblas_set_num_threads{suffix}")
            except (OSError, AttributeError):
                continue
            get.restype = ctypes.c_int
            set_.argtypes = [ctypes.c_int]
            out.append((get, set_))
    return out


@contextlib.contextmanager
def single_threaded_blas():
    """Run the enclosed code with the bundled OpenBLAS limited to one thread, then restore it.

    The identification solves thousands of small least-squares problems (tens of columns). On a
    loaded machine OpenBLAS's worker threads spin-wait for cores and slow such products down by
    one to two orders of magnitude (measured here: a 1800 x 36 normal-equation product takes
    70 ms threaded, 0.14 ms single-threaded). Nothing happens where the controls are not found
    (other BLAS builds). Process-wide while it lasts: other threads' BLAS calls run single-threaded too.
    """
    controls = []
    for get, set_ in _openblas_thread_controls():
        try:
            controls.append((set_, int(get())))
            set_(1)
        except Exception:  # noqa: BLE001 - a foreign library's call: never let it break the fit
            continue
    try:
        yield
    finally:
        for set_, old in controls:
            set_(old)

def blas_single_threaded(func):
    """Decorator: run ``func`` inside :func:`single_threaded_blas`."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with single_threaded_blas():
            return func(*args, **kwargs)

    return wrapper


def lstsq_normal(a, y, *, ridge: float = 1e-12):
    """Least-squares solution of ``a c = y`` through the column-scaled normal equations.

    For the small, well-scaled designs of this package (tens of columns) this is as accurate as
    an SVD solve and, unlike LAPACK's threaded ``gelsd``, does not slow down by two orders of
    magnitude on a loaded multi-core machine. A relative ``ridge`` guards rank-deficient designs.

    Parameters
    ----------
    a : ndarray, shape (n, p)
    y : ndarray, shape (n,) or (n, k)

    Returns
    -------
    ndarray, shape (p,) or (p, k)
    """
    from scipy.linalg import cho_factor, cho_solve

    scale = np.sqrt(np.sum(a * a, axis=0))
    scale[scale == 0] = 1.0
    a_s = a / scale
    g = a_s.T @ a_s
    g[np.diag_indices_from(g)] += ridge * max(float(np.trace(g)) / max(g.shape[0], 1), 1e-300)
    rhs = a_s.T @ y
    try:
        c = cho_solve(cho_factor(g, check_finite=False), rhs, check_finite=False)
    except np.linalg.LinAlgError:
        c = np.linalg.pinv(g) @ rhs
    return c / (scale if c.ndim == 1 else scale[:, None])


def modal_basis(freq_hz, natural_frequency_hz, damping_ratio) -> np.ndarray:
    """``1 / (w_r^2 - w^2 + 2 i zeta_r w_r w)``, shape (n_modes, n_freq), s^2 (per unit mass)."""
    w = hz_to_rad_s(freq_hz)[None, :]
    wr = hz_to_rad_s(np.atleast_1d(natural_frequency_hz))[:, None]
    z = np.atleast_1d(np.asarray(damping_ratio, dtype=float))[:, None]
    return 1.0 / (wr**2 - w**2 + 2j * z * wr * w)


# =============================================================================== LSCF
def lscf_poles(freq_hz, frf, order: int, *, weights=None, max_damping: float = 0.3):
    """Poles of a real-coefficient LSCF common-denominator fit of order ``order``.

    Parameters
    ----------
    freq_hz : array_like, shape (n_freq,)
        Lines of the band to fit, Hz.
    frf : array_like, shape (n_entries, n_freq), complex
        The FRFs (any consistent units).
    order : int
        Denominator order (up to ``order / 2`` complex pole pairs).
    weights : array_like, shape (n_entries, n_freq), optional
        Non-negative weights of the equation errors (default 1).
    max_damping : float
        Poles with larger damping ratio are dropped.

    Returns
    -------
    natural_frequency_hz, damping_ratio : ndarray
        Physical poles (positive damping below ``max_damping``, inside the band), sorted.
    """
    f = np.asarray(freq_hz, dtype=float)
    h = np.array(frf, dtype=complex, ndmin=2)
    w = np.ones(h.shape) if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), h.shape)
    f_max = f.max()
    dt = 1.0 / (2.0 * f_max * 1.05)
    omega = 2.0 * np.pi * f
    basis = np.exp(1j * np.outer(omega * dt, np.arange(order + 1)))  # (nf, p+1)
    m = np.zeros((order + 1, order + 1))
    for he, we in zip(h, w):
        x = we[:, None] * basis
        y = -(we * he)[:, None] * basis
        r = np.real(x.conj().T @ x)
        s = np.real(x.conj().T @ y)
        t = np.real(y.conj().T @ y)
        m += t - s.T @ np.linalg.solve(r + 1e-14 * np.trace(r) * np.eye(order + 1), s)
    alpha = np.ones(order + 1)
    alpha[:order] = np.linalg.lstsq(m[:order, :order], -m[:order, order], rcond=None)[0]
    roots = np.roots(alpha[::-1])
    roots = roots[np.abs(roots) > 0]
    s = np.log(roots.astype(complex)) / dt
    s = s[np.imag(s) > 0]
    wn = np.abs(s)
    zeta = -np.real(s) / wn
    fn = wn / (2.0 * np.pi)
    ok = (zeta > 0) & (zeta < max_damping) & (fn > f.min()) & (fn < f_max)
    idx = np.argsort(fn[ok])
    return fn[ok][idx], zeta[ok][idx]


@dataclass(frozen=True)
class StabilisationDiagram:
    """Poles of LSCF fits at increasing order and the modes picked from them.

    Attributes
    ----------
    orders : tuple of int
    poles : tuple of (freq_hz, damping_ratio, stable) arrays, one per order
        ``stable`` is True where the pole matches one of the previous order within the tolerances.
    natural_frequency_hz, damping_ratio : ndarray
        The selected modes (medians of their clusters of stable poles), strongest first.
    counts : ndarray of int
        Number of orders at which each selected mode was stable.
    freq_tol, damping_tol : float
        Relative tolerances used.
    """

    orders: tuple
    poles: tuple
    natural_frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    counts: np.ndarray
    freq_tol: float
    damping_tol: float

    def __post_init__(self):
        object.__setattr__(self, "natural_frequency_hz", _ro(self.natural_frequency_hz))
        object.__setattr__(self, "damping_ratio", _ro(self.damping_ratio))
        object.__setattr__(self, "counts", _ro(self.counts, int))

    def plot(self, ax=None, **kwargs):
        """Stabilisation diagram (see :func:`oma.plots.plot_stabilisation`)."""
        from .plots import plot_stabilisation

        return plot_stabilisation(self, ax=ax, **kwargs)


def stabilisation_diagram(
    freq_hz,
    frf,
    *,
    weights=None,
    max_order: int = 40,
    min_order: int = 2,
    freq_tol: float = 0.01,
    damping_tol: float = 0.10,
    min_stable_fraction: float = 0.3,
    max_damping: float = 0.3,
) -> StabilisationDiagram:
    """LSCF poles at orders ``min_order .. max_order`` (step 2) and the modes stable across them.

    A pole is stable at an order when the previous order has one within ``freq_tol`` in frequency
    and ``damping_tol`` in damping (relative; 1 % and 10 % are the usual choices for noisy data).
    Stable poles are clustered by frequency (within ``2 freq_tol``); a cluster that is stable at
    no fewer than ``min_stable_fraction`` of the orders above the one where it first appeared is a
    mode.
    """
    orders = tuple(range(max(min_order, 2), max_order + 1, 2))
    poles = []
    prev = (np.zeros(0), np.zeros(0))
    for p in orders:
        fn, z = lscf_poles(freq_hz, frf, p, weights=weights, max_damping=max_damping)
        stable = np.zeros(fn.size, dtype=bool)
        if prev[0].size and fn.size:
            df = np.abs(fn[:, None] - prev[0][None, :]) / fn[:, None]
            dz = np.abs(z[:, None] - prev[1][None, :]) / z[:, None]
            stable = np.any((df < freq_tol) & (dz < damping_tol), axis=1)
        poles.append((_ro(fn), _ro(z), _ro(stable, bool)))
        prev = (fn, z)
    # cluster the stable poles
    all_f = np.concatenate([p[0][p[2]] for p in poles]) if poles else np.zeros(0)
    all_z = np.concatenate([p[1][p[2]] for p in poles]) if poles else np.zeros(0)
    all_o = np.concatenate([np.full(int(np.sum(p[2])), k) for k, p in enumerate(poles)]) if poles else np.zeros(0)
    sel_f, sel_z, sel_c = [], [], []
    if all_f.size:
        order_idx = np.argsort(all_f)
        fs, zs, os_ = all_f[order_idx], all_z[order_idx], all_o[order_idx]
        groups = np.split(np.arange(fs.size), np.flatnonzero(np.diff(fs) / fs[1:] > 2 * freq_tol) + 1)
        for g in groups:
            n_orders = np.unique(os_[g]).size
            first = int(np.min(os_[g]))
            possible = len(orders) - first
            if n_orders >= max(2, min_stable_fraction * possible):
                sel_f.append(np.median(fs[g]))
                sel_z.append(np.median(zs[g]))
                sel_c.append(n_orders)
    idx = np.argsort(sel_c)[::-1]
    return StabilisationDiagram(
        orders=orders,
        poles=tuple(poles),
        natural_frequency_hz=np.asarray(sel_f)[idx] if sel_f else np.zeros(0),
        damping_ratio=np.asarray(sel_z)[idx] if sel_z else np.zeros(0),
        counts=np.asarray(sel_c)[idx] if sel_c else np.zeros(0, int),
        freq_tol=freq_tol,
        damping_tol=damping_tol,
    )


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
    """Variable-projection least squares: poles nonlinear, everything else linear."""

    def __init__(self, freq_hz, frf, weights, slots, *, upper, lower, complex_modes):
        self.f = np.asarray(freq_hz, dtype=float)
        self.w_rad = hz_to_rad_s(self.f)
        self.h = np.asarray(frf, dtype=complex)
        self.wt = np.asarray(weights, dtype=float)
        self.slots = np.asarray(slots, dtype=int)
        self.n_slots = int(self.slots.max()) + 1
        self.upper, self.lower, self.complex_modes = upper, lower, complex_modes
        y = np.concatenate([(self.wt * self.h).real.ravel(), (self.wt * self.h).imag.ravel()])
        # residuals relative to the data's rms keep the optimiser's tolerances meaningful
        self.scale = float(np.sqrt(np.mean(y**2))) or 1.0
        self.wt = self.wt / self.scale
        self.y = y / self.scale

    def design(self, fn, zeta):
        n_e, nf = self.h.shape
        basis = modal_basis(self.f, fn, zeta)  # (n_modes, nf)
        n_modes = basis.shape[0]
        per_mode = 2 if self.complex_modes else 1
        n_cols = n_modes * self.n_slots * per_mode + self.n_slots * (int(self.upper) + int(self.lower))
        a = np.zeros((n_e, nf, n_cols), dtype=complex)
        for e in range(n_e):
            s = self.slots[e]
            col = 0
            for r in range(n_modes):
                a[e, :, col + s] = basis[r]
                col += self.n_slots
                if self.complex_modes:
                    a[e, :, col + s] = 1j * self.w_rad * basis[r]
                    col += self.n_slots
            if self.upper:
                a[e, :, col + s] = 1.0
                col += self.n_slots
            if self.lower:
                a[e, :, col + s] = -1.0 / self.w_rad**2
        a *= self.wt[:, :, None]
        a = a.reshape(n_e * nf, n_cols)
        return np.vstack([a.real, a.imag])

    def solve(self, fn, zeta):
        a = self.design(fn, zeta)
        coef = lstsq_normal(a, self.y)
        return coef, self.y - a @ coef

    def unpack(self, coef, n_modes):
        per_mode = 2 if self.complex_modes else 1
        k = 0
        res = np.zeros((n_modes, self.n_slots))
        res_i = np.zeros((n_modes, self.n_slots))
        for r in range(n_modes):
            res[r] = coef[k : k + self.n_slots]
            k += self.n_slots
            if self.complex_modes:
                res_i[r] = coef[k : k + self.n_slots]
                k += self.n_slots
        up = np.zeros(self.n_slots)
        lo = np.zeros(self.n_slots)
        if self.upper:
            up = coef[k : k + self.n_slots]
            k += self.n_slots
        if self.lower:
            lo = coef[k : k + self.n_slots]
        return res[:, self.slots], res_i[:, self.slots], up[self.slots], lo[self.slots]


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
    f = np.asarray(freq_hz, dtype=float)
    h = np.array(frf, dtype=complex, ndmin=2)
    wt = np.ones(h.shape) if weights is None else np.array(np.broadcast_to(weights, h.shape), dtype=float)
    wt = np.where(np.isfinite(wt), wt, 0.0)
    slots = np.arange(h.shape[0]) if slots is None else np.asarray(slots, dtype=int)
    prob = _PoleResidueProblem(f, h, wt, slots, upper=upper_residual, lower=lower_residual,
                               complex_modes=complex_modes)
    fn0 = np.atleast_1d(np.asarray(natural_frequency_hz, dtype=float))
    z0 = np.clip(np.atleast_1d(np.asarray(damping_ratio, dtype=float)), 1e-4, max_damping * 0.99)
    n_modes = fn0.size
    if n_modes:
        lo = np.concatenate([np.full(n_modes, np.log(max(f.min(), 1e-3) * 0.5)), np.full(n_modes, np.log(1e-4))])
        hi = np.concatenate([np.full(n_modes, np.log(f.max() * 2.0)), np.full(n_modes, np.log(max_damping))])
        th0 = np.clip(_theta(fn0, z0), lo + 1e-9, hi - 1e-9)
        sol = optimize.least_squares(lambda th: prob.solve(*_untheta(th))[1], th0, bounds=(lo, hi),
                                     x_scale=np.concatenate([np.full(n_modes, 0.01), np.full(n_modes, 0.1)]),
                                     xtol=1e-10, ftol=1e-12, max_nfev=40 * (n_modes + 1))
        fn, zeta = _untheta(sol.x)
        success, message = bool(sol.success), str(sol.message)
    else:
        fn, zeta = fn0, z0
        success, message = True, "no modes"
    order = np.argsort(fn)
    fn, zeta = fn[order], zeta[order]
    coef, resid = prob.solve(fn, zeta)
    res, res_i, up, low = prob.unpack(coef, fn.size)
    n_lin = coef.size
    fit = PoleResidueFit(
        natural_frequency_hz=fn, damping_ratio=zeta, residues=res, residues_imag=res_i,
        upper_residual=up, lower_residual=low, fit_error=np.zeros(h.shape[0]),
        rss=float(resid @ resid), n_data=int(2 * h.size), n_parameters=int(n_lin + 2 * fn.size),
        success=success, message=message,
    )
    err = relative_fit_error(h, fit.evaluate(f), wt)
    return PoleResidueFit(**{**fit.__dict__, "fit_error": err})


@blas_single_threaded
def prune_modes(freq_hz, frf, fit: PoleResidueFit, *, weights=None, slots=None, upper_residual: bool = True,
                lower_residual: bool = False, complex_modes: bool = False, max_damping: float = 0.5) -> PoleResidueFit:
    """Drop modes of a :func:`fit_poles_residues` result that do not lower the BIC.

    Each round screens every removal with the other poles held (linear least squares only),
    refits the best candidate by nonlinear least squares and keeps it if its BIC is lower.
    Arguments as in :func:`fit_poles_residues`.
    """
    f = np.asarray(freq_hz, dtype=float)
    h = np.array(frf, dtype=complex, ndmin=2)
    wt = np.ones(h.shape) if weights is None else np.array(np.broadcast_to(weights, h.shape), dtype=float)
    slots = np.arange(h.shape[0]) if slots is None else np.asarray(slots, dtype=int)
    prob = _PoleResidueProblem(f, h, wt, slots, upper=upper_residual, lower=lower_residual, complex_modes=complex_modes)
    n_data = 2 * h.size
    while fit.n_modes > 1:
        scores = []
        for r in range(fit.n_modes):
            keep = np.arange(fit.n_modes) != r
            coef, resid = prob.solve(fit.natural_frequency_hz[keep], fit.damping_ratio[keep])
            rss = float(resid @ resid)
            scores.append(n_data * np.log(max(rss, 1e-300) / n_data) + (coef.size + 2 * int(keep.sum())) * np.log(n_data))
        r = int(np.argmin(scores))
        if scores[r] >= fit.bic:
            break
        keep = np.arange(fit.n_modes) != r
        cand = fit_poles_residues(f, h, fit.natural_frequency_hz[keep], fit.damping_ratio[keep], weights=weights,
                                  slots=slots, upper_residual=upper_residual, lower_residual=lower_residual,
                                  complex_modes=complex_modes, max_damping=max_damping)
        if cand.bic >= fit.bic:
            break
        fit = cand
    return fit


# =============================================================================== modal model
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
        Candidate modes removed by the information criterion.
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


def _modal_nlls(freq, h, wt, entries, slots, model0: ModalModel, *, residual: bool, max_damping: float):
    """Fit the ModalModel form (rank-one residues) by variable projection over (fn, zeta, phi)."""
    n = model0.n_modes
    rows = sorted({o for o, _ in entries} | {i for _, i in entries})
    phi0 = model0.directions / np.sqrt(model0.modal_mass_kg)[:, None]  # u / sqrt(m)
    n_e = len(entries)
    y = np.concatenate([(wt * h).real.ravel(), (wt * h).imag.ravel()])
    y_scale = float(np.sqrt(np.mean(y**2))) or 1.0
    wt = wt / y_scale
    y = y / y_scale
    n_slots = int(slots.max()) + 1

    def split(th):
        fn = np.exp(th[:n])
        z = np.exp(th[n : 2 * n])
        phi = np.zeros((n, 3))
        phi[:, rows] = th[2 * n :].reshape(n, len(rows))
        return fn, z, phi

    def model_part(fn, z, phi):
        basis = modal_basis(freq, fn, z)
        out = np.zeros((n_e, freq.size), dtype=complex)
        for e, (o, i) in enumerate(entries):
            out[e] = np.sum((phi[:, o] * phi[:, i])[:, None] * basis, axis=0)
        return out

    design_res = np.zeros((n_e, freq.size, n_slots))
    for e in range(n_e):
        design_res[e, :, slots[e]] = 1.0
    design_res *= wt[:, :, None]
    a_res = np.vstack([design_res.reshape(-1, n_slots), np.zeros((n_e * freq.size, n_slots))])

    def resid(th, return_coef=False):
        fn, z, phi = split(th)
        m = wt * model_part(fn, z, phi)
        r = y - np.concatenate([m.real.ravel(), m.imag.ravel()])
        coef = np.zeros(n_slots)
        if residual:
            coef = lstsq_normal(a_res, r)
            r = r - a_res @ coef
        return (r, coef) if return_coef else r

    th0 = np.concatenate([np.log(model0.natural_frequency_hz), np.log(np.clip(model0.damping_ratio, 1e-4, max_damping * 0.99)),
                          phi0[:, rows].ravel()])
    lo = np.concatenate([np.log(model0.natural_frequency_hz) - 0.5, np.full(n, np.log(1e-4)), np.full(n * len(rows), -np.inf)])
    hi = np.concatenate([np.log(model0.natural_frequency_hz) + 0.5, np.full(n, np.log(max_damping)), np.full(n * len(rows), np.inf)])
    pscale = np.max(np.abs(phi0[:, rows])) if n else 1.0
    x_scale = np.concatenate([np.full(n, 0.01), np.full(n, 0.1), np.full(n * len(rows), 0.1 * pscale)])
    sol = optimize.least_squares(resid, np.clip(th0, lo + 1e-12, hi - 1e-12), bounds=(lo, hi), x_scale=x_scale,
                                 xtol=1e-10, ftol=1e-12, max_nfev=100 * (len(th0) + 1))
    r, coef = resid(sol.x, return_coef=True)
    fn, z, phi = split(sol.x)
    return fn, z, phi, coef, float(r @ r), sol


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
        Drop modes that do not lower the BIC.
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
        prob = _PoleResidueProblem(f, h, wt, slots, upper=residual, lower=False, complex_modes=False)
        n_data = 2 * h.size
        while pr.n_modes > 1:
            # screen removals with the other (refined) poles held, then refit the best one
            scores = []
            for r in range(pr.n_modes):
                keep = np.arange(pr.n_modes) != r
                coef, resid = prob.solve(pr.natural_frequency_hz[keep], pr.damping_ratio[keep])
                rss = float(resid @ resid)
                n_par = coef.size + 2 * int(np.sum(keep))
                scores.append(n_data * np.log(max(rss, 1e-300) / n_data) + n_par * np.log(n_data))
            r = int(np.argmin(scores))
            if scores[r] >= pr.bic:
                break
            keep = np.arange(pr.n_modes) != r
            cand = fit_poles_residues(f, h, pr.natural_frequency_hz[keep], pr.damping_ratio[keep], weights=wt,
                                      slots=slots, upper_residual=residual, max_damping=max_damping)
            dropped.append(float(pr.natural_frequency_hz[r]))
            pr = cand
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
    fn, z, phi, coef, rss, sol = _modal_nlls(f, h, wt, entries, slots, model0, residual=residual, max_damping=max_damping)
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
        message=str(sol.message),
    )
