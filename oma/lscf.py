"""Poles of measured FRFs: least-squares complex-frequency (LSCF) fits and the stabilisation diagram.

A common-denominator fit of all measured FRFs at increasing model order (Guillaume et al. 2003;
Peeters et al. 2004, "PolyMAX"): poles that come back at successive orders with the same
frequency and damping are stable; those stable over many orders are the physical modes. The
refinement and selection of the modes is :mod:`oma.fit`.

References
----------
P. Guillaume, P. Verboven, S. Vanlanduit, H. Van der Auweraer, B. Peeters, "A poly-reference
implementation of the least-squares complex frequency-domain estimator", Proc. IMAC XXI (2003).
B. Peeters, H. Van der Auweraer, P. Guillaume, J. Leuridan, "The PolyMAX frequency-domain method:
a new standard for modal parameter estimation?", Shock and Vibration 11 (2004) 395-409.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._arrays import readonly as _ro
from ._linalg import blas_single_threaded

__all__ = ["StabilisationDiagram", "lscf_poles", "stabilisation_diagram"]


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
    return _lscf_poles_from_blocks(_lscf_blocks(f, frf, weights, order), f, order, max_damping=max_damping)


def _lscf_blocks(f, frf, weights, max_order: int):
    """The per-entry LSCF matrices ``R, S, T`` (Guillaume et al. 2003) up to ``max_order``.

    Those of a lower order are their leading blocks, so a stabilisation diagram computes them once.
    Returns an array of shape (3, n_entries, max_order + 1, max_order + 1).
    """
    h = np.array(frf, dtype=complex, ndmin=2)
    w = np.ones(h.shape) if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), h.shape)
    dt = 1.0 / (2.0 * f.max() * 1.05)
    basis = np.exp(1j * np.outer(2.0 * np.pi * f * dt, np.arange(max_order + 1)))  # (nf, p+1)
    br, bi = np.ascontiguousarray(basis.real), np.ascontiguousarray(basis.imag)
    n = max_order + 1
    out = np.empty((3, h.shape[0], n, n))
    for e, (he, we) in enumerate(zip(h, w)):
        # R = Re(X^H X), S = Re(X^H Y), T = Re(Y^H Y) with X = w basis, Y = -w h basis, in real
        # arithmetic: Re(conj(b_p) b_q c) = (br_p br_q + bi_p bi_q) Re(c) - (br_p bi_q - bi_p br_q) Im(c)
        w2 = we * we
        hw = w2 * he
        sym = lambda c: (c[:, None] * br).T @ br + (c[:, None] * bi).T @ bi  # noqa: E731
        anti = lambda c: (c[:, None] * br).T @ bi - (c[:, None] * bi).T @ br  # noqa: E731
        out[0, e] = sym(w2)
        out[1, e] = -(sym(hw.real) - anti(hw.imag))
        out[2, e] = sym(w2 * np.abs(he) ** 2)
    return out, dt


def _lscf_poles_from_blocks(blocks, f, order: int, *, max_damping: float):
    (rst, dt) = blocks
    k = order + 1
    r, s_, t = rst[0][:, :k, :k], rst[1][:, :k, :k], rst[2][:, :k, :k]
    ridge = 1e-14 * np.trace(r, axis1=1, axis2=2)[:, None, None] * np.eye(k)
    m = np.sum(t - np.transpose(s_, (0, 2, 1)) @ np.linalg.solve(r + ridge, s_), axis=0)
    alpha = np.ones(order + 1)
    alpha[:order] = np.linalg.lstsq(m[:order, :order], -m[:order, order], rcond=None)[0]
    roots = np.roots(alpha[::-1])
    roots = roots[np.abs(roots) > 0]
    s = np.log(roots.astype(complex)) / dt
    s = s[np.imag(s) > 0]
    wn = np.abs(s)
    zeta = -np.real(s) / wn
    fn = wn / (2.0 * np.pi)
    ok = (zeta > 0) & (zeta < max_damping) & (fn > f.min()) & (fn < f.max())
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


@blas_single_threaded
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
    f = np.asarray(freq_hz, dtype=float)
    blocks = _lscf_blocks(f, frf, weights, max(orders) if orders else 2)
    for p in orders:
        fn, z = _lscf_poles_from_blocks(blocks, f, p, max_damping=max_damping)
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
