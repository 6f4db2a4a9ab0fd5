"""Small linear-algebra helpers of the estimators: BLAS thread control, normal-equation least squares.

The estimators solve many small problems; multi-threaded BLAS on them only adds overhead and, on a
shared machine, contention (measured: a stabilisation diagram 10 s with competing OpenBLAS threads,
0.5 s on one). :func:`single_threaded_blas` limits the BLAS libraries of NumPy and SciPy to one
thread for the duration of a call (threadpoolctl).
"""

from __future__ import annotations

import contextlib
import functools

import numpy as np

__all__ = ["single_threaded_blas", "blas_single_threaded", "lstsq_normal", "solve_normal", "orthonormal_basis"]


@functools.lru_cache(maxsize=1)
def _controller():
    """The thread-pool controller of the BLAS libraries loaded in this process (threadpoolctl).

    SciPy's LAPACK is loaded first: the controller sees only the libraries loaded when it is made.
    """
    import scipy.linalg  # noqa: F401 (loads SciPy's BLAS)
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@contextlib.contextmanager
def single_threaded_blas():
    """Run the enclosed code with the BLAS libraries limited to one thread, then restore them.

    The identification solves thousands of small least-squares problems (tens of columns). On a
    loaded machine OpenBLAS's worker threads spin-wait for cores and slow such products down by
    one to two orders of magnitude (measured here: a 1800 x 36 normal-equation product takes
    70 ms threaded, 0.14 ms single-threaded). Any BLAS threadpoolctl knows (OpenBLAS, MKL, BLIS)
    is limited. Process-wide while it lasts: other threads' BLAS calls run single-threaded too.
    """
    with _controller().limit(limits=1, user_api="blas"):
        yield


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
    scale = np.sqrt(np.sum(a * a, axis=0))
    scale[scale == 0] = 1.0
    a_s = a / scale
    c = _solve_scaled(a_s.T @ a_s, a_s.T @ y, ridge)
    return c / (scale if c.ndim == 1 else scale[:, None])


def solve_normal(gram, rhs, *, ridge: float = 1e-12):
    """:func:`lstsq_normal` from the normal equations themselves, ``gram = a^T a`` (p, p) and
    ``rhs = a^T y`` (p,) or (p, k): for designs whose products have closed forms cheaper than the
    design (:func:`oma.harmonics.fit_angle_orders`)."""
    gram = np.asarray(gram, dtype=float)
    rhs = np.asarray(rhs, dtype=float)
    scale = np.sqrt(np.maximum(np.diag(gram), 0.0))
    scale[scale == 0] = 1.0
    per_row = scale if rhs.ndim == 1 else scale[:, None]
    c = _solve_scaled(gram / np.outer(scale, scale), rhs / per_row, ridge)
    return c / per_row


def _solve_scaled(g, rhs, ridge):
    """The column-scaled normal equations ``g c = rhs``, ``g`` with a relative ``ridge`` on its
    diagonal (its pseudo-inverse where even that is not positive definite)."""
    from scipy.linalg import cho_factor, cho_solve

    g = np.array(g, dtype=float)
    g[np.diag_indices_from(g)] += ridge * max(float(np.trace(g)) / max(g.shape[0], 1), 1e-300)
    try:
        return cho_solve(cho_factor(g, check_finite=False), rhs, check_finite=False)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(g) @ rhs


def orthonormal_basis(a) -> np.ndarray:
    """An orthonormal basis ``Q`` (n, k) of the columns of ``a`` (n, k), n much larger than k.

    Cholesky QR (Fukaya, Nakatsukasa, Yanagisawa & Yamamoto 2014): ``Q = A R^-1`` with ``R`` the
    Cholesky factor of ``A^T A`` (the columns' scales taken out of it, so that ``R`` carries only
    their angles). Its loss of orthogonality is about ``cond(R)^2`` roundings, so a second pass on
    the first ``Q`` (CholeskyQR2, orthogonal to rounding up to a condition number of about 1e8) is
    made when ``cond(R)`` exceeds 100. The milling lines' designs are conditioned about 1.001 and
    take one pass: one Gram product and one product with a k x k matrix, 0.3 s against 1.6 s for
    Householder QR (which also forms ``Q`` column by column) at 100 000 x 112 on one core. Worse
    conditioned or rank-deficient designs go to :func:`numpy.linalg.qr`.
    """
    from scipy.linalg import LinAlgError, cholesky, solve_triangular

    a = np.asarray(a, dtype=float)
    k = a.shape[1]
    if k == 0:
        return np.zeros((a.shape[0], 0))
    q = a
    for pass_ in range(2):
        g = q.T @ q
        d = np.diag(g)
        if not (np.all(d > 0) and np.all(np.isfinite(g))):
            break
        s = 1.0 / np.sqrt(d)
        try:
            r = cholesky(s[:, None] * g * s[None, :], lower=False, check_finite=False)
        except LinAlgError:
            break
        cond = np.linalg.cond(r)
        if not cond < 1e7:
            break
        q = q @ (s[:, None] * solve_triangular(r, np.eye(k), lower=False, check_finite=False))
        if cond <= 100.0 or pass_ == 1:
            return q
    return np.linalg.qr(a)[0]
