"""The numerical kernels of the semi-discretization (:mod:`stability.sdm`): a batched small-matrix
exponential, the monodromy assembly loop and the Arnoldi estimate of the dominant multiplier,
the loops compiled by numba on first use (so that importing them does not import numba)."""

from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger("stability.sdm")


# ------------------------------------------------------------------------------ small expm batch
def _expm_batch(a: np.ndarray) -> np.ndarray:
    """``exp`` of a stack of small matrices (..., k, k): Pade [6/6] with scaling and squaring.

    With ``||A / 2^s||_1 <= 1/2`` the [6/6] Pade remainder is ``6!^2 / (12! 13!) 2^-13 < 1e-17``.
    Written here because ``scipy.linalg.expm`` on a stack of 4x4 matrices spends most of its time
    in per-matrix overhead (measured ~50x slower in the step loop of the semi-discretization).
    """
    a = np.asarray(a, dtype=float)
    norm = np.max(np.sum(np.abs(a), axis=-2), axis=-1)
    s = np.maximum(0, np.ceil(np.log2(np.maximum(norm, 1e-300) / 0.5))).astype(int)
    x = a / (2.0**s)[..., None, None]
    eye = np.broadcast_to(np.eye(a.shape[-1]), a.shape)
    # Pade [6/6] coefficients c_j = (12-j)! 6! / (12! j! (6-j)!)
    c = [1.0, 1 / 2, 5 / 44, 1 / 66, 1 / 792, 1 / 15840, 1 / 665280]
    x2 = x @ x
    x4 = x2 @ x2
    x6 = x4 @ x2
    even = c[0] * eye + c[2] * x2 + c[4] * x4 + c[6] * x6
    odd = x @ (c[1] * eye + c[3] * x2 + c[5] * x4)
    r = np.linalg.solve(even - odd, even + odd)
    for k in range(int(s.max(initial=0))):
        more = s > k
        r = r @ r if more.all() else np.where(more[..., None, None], r @ r, r)
    return r


# -------------------------------------------------------------------------- monodromy assembly
def _assemble_loop(phi, gd, lam, cutting, col_of, row_of, s_mat, size):
    """Propagate the ``2n x N`` state block through the steps (plain loops, compiled by numba).

    ``Y_{i+1} = Phi_i Y_i``, then the step's reads of the history add ``Gd_i`` to the columns of
    slot ``i`` and ``Lam_i`` to those of slot ``i + 1`` (slot ``m`` is ``xi_0 = S eta_0``: the
    columns of ``y_0``). Before step ``i`` the rows ``S eta_i`` are recorded as the new history of
    slot ``i``. Returns ``[[Y_m], [history rows]]`` for each batch member, (B, N, N).
    """
    bsz, m, n2 = phi.shape[0], phi.shape[1], phi.shape[2]
    d, nn = gd.shape[3], s_mat.shape[1]
    out = np.zeros((bsz, size, size))
    y = np.zeros((n2, size))
    tmp = np.zeros((n2, size))
    for b in range(bsz):
        y[:, :] = 0.0
        for r in range(n2):
            y[r, r] = 1.0
        width = n2  # columns of y that can be non-zero so far
        for i in range(m):
            r0 = row_of[i]
            if r0 >= 0:
                for a in range(d):
                    for c in range(width):
                        acc = 0.0
                        for q in range(nn):
                            acc += s_mat[a, q] * y[q, c]
                        out[b, n2 + r0 + a, c] = acc
            for r in range(n2):
                for c in range(width):
                    acc = 0.0
                    for q in range(n2):
                        acc += phi[b, i, r, q] * y[q, c]
                    tmp[r, c] = acc
            y, tmp = tmp, y
            if cutting[i]:
                c0 = col_of[i]
                c_end = c0 + d if i + 1 == m else col_of[i + 1] + d
                for c in range(width, c_end):  # newly reached columns: clear stale values
                    for r in range(n2):
                        y[r, c] = 0.0
                width = max(width, c_end)
                for r in range(n2):
                    for a in range(d):
                        y[r, c0 + a] += gd[b, i, r, a]
                if i + 1 < m:
                    c1 = col_of[i + 1]
                    for r in range(n2):
                        for a in range(d):
                            y[r, c1 + a] += lam[b, i, r, a]
                else:
                    for r in range(n2):
                        for q in range(nn):
                            acc = 0.0
                            for a in range(d):
                                acc += lam[b, i, r, a] * s_mat[a, q]
                            y[r, q] += acc
        for r in range(n2):
            for c in range(width):
                out[b, r, c] = y[r, c]
    return out


_KERNELS: dict = {}


#: The plain functions the loops call: compiled first and bound in their names' place, so that
#: numba, compiling a loop, finds compiled functions there.
_CALLEES = ("_gram_schmidt", "_apply_monodromy")


def _compiled(loop):
    """``loop`` compiled by numba on first use (cached on disk), so that importing this module
    does not import numba. :func:`_assemble_loop`, measured at 224 steps (1-DOF): 0.5 ms compiled
    against 4 ms for the same loop as NumPy calls per step."""
    if loop.__name__ not in _KERNELS:
        import numba

        for name in _CALLEES:
            if name not in _KERNELS:
                _KERNELS[name] = globals()[name] = numba.njit(cache=True)(globals()[name])
        _KERNELS[loop.__name__] = numba.njit(cache=True)(loop)
    return _KERNELS[loop.__name__]


# ------------------------------------------------------------------------------- eigenvalues
# Krylov dimension of the Arnoldi estimate of the dominant multiplier, and the relative residual
# ||M x - mu x|| / |mu| below which it is accepted (otherwise twice the dimension, then LAPACK).
_KRYLOV = 20
_RESIDUAL_RTOL = 1e-9


def _gram_schmidt(basis, hess, w, h, bi, j):
    """One Arnoldi step's orthogonalisation (plain loops, compiled by numba): ``w = M v_j`` made
    orthogonal to ``basis[bi, :j + 1]`` by two passes of classical Gram-Schmidt, the coefficients
    into column ``j`` of ``hess[bi]``, the normalised rest into ``basis[bi, j + 1]``. Returns
    whether the basis broke down (``w`` in the span: an invariant subspace); ``h`` is scratch."""
    n = w.shape[0]
    for l in range(j + 1):
        hess[bi, l, j] = 0.0
    for _ in range(2):
        for l in range(j + 1):
            acc = 0.0
            for i in range(n):
                acc += basis[bi, l, i] * w[i]
            h[l] = acc
        for l in range(j + 1):
            hess[bi, l, j] += h[l]
            for i in range(n):
                w[i] -= h[l] * basis[bi, l, i]
    beta = 0.0
    for i in range(n):
        beta += w[i] * w[i]
    beta = np.sqrt(beta)
    hn = 0.0
    for l in range(j + 1):
        hn += hess[bi, l, j] * hess[bi, l, j]
    if beta <= 1e-13 * max(np.sqrt(hn), 1e-300):
        return True
    hess[bi, j + 1, j] = beta
    for i in range(n):
        basis[bi, j + 1, i] = w[i] / beta
    return False


def _arnoldi_loop(mono, k, v0, basis, hess):
    """``k`` Arnoldi steps per matrix of a stack (plain loops, compiled by numba): fills ``basis``
    (B, k + 1, n; rows are the orthonormal vectors) and ``hess`` (B, k + 1, k), two-pass classical
    Gram-Schmidt from the unit start vector ``v0``. Returns, per matrix, whether the basis broke
    down (an invariant subspace: the caller redoes those with :func:`_arnoldi_numpy`)."""
    b, n = mono.shape[0], mono.shape[1]
    broke = np.zeros(b, dtype=np.bool_)
    w = np.empty(n)
    h = np.empty(k + 1)
    for bi in range(b):
        for i in range(n):
            basis[bi, 0, i] = v0[i]
        for j in range(k):
            for r in range(n):
                acc = 0.0
                for c in range(n):
                    acc += mono[bi, r, c] * basis[bi, j, c]
                w[r] = acc
            if _gram_schmidt(basis, hess, w, h, bi, j):
                broke[bi] = True
                break
    return broke


def _ritz(basis, hess, k: int, vectors: bool):
    """Dominant Ritz value, its Ritz vector (or None) and residual from an Arnoldi factorisation
    (``basis`` (B, k + 1, n), ``hess`` (B, k + 1, k))."""
    vals, yvec = np.linalg.eig(hess[:, :k, :k])
    idx = np.argmax(np.abs(vals), axis=1)
    rows = np.arange(hess.shape[0])
    y = yvec[rows, :, idx]  # (b, k), unit norm
    resid = np.abs(hess[:, k, k - 1] * y[:, -1])
    vec = np.einsum("bkn,bk->bn", basis[:, :k, :], y) if vectors else None
    return vals[rows, idx], vec, resid


def _start_vector(n: int) -> np.ndarray:
    v0 = np.random.default_rng(20040117).standard_normal(n)
    return v0 / np.linalg.norm(v0)


def _arnoldi(mono: np.ndarray, k: int, vectors: bool):
    """``k`` Arnoldi steps on each matrix of a stack (B, N, N): dominant Ritz value, its Ritz
    vector (or None) and its residual ``||M x - mu x||`` (unit ``x``).

    Compiled loops (:func:`_arnoldi_loop`): the batches of the limit search are small (a median of
    5 matrices of ~50 rows in the tables of ``learn``), where NumPy's stacked products spend most
    of their time in per-call overhead (measured 0.5 ms per 50-row matrix against ~0.05 ms). A
    matrix whose basis breaks down is redone by :func:`_arnoldi_numpy`, which continues it."""
    b, n, _ = mono.shape
    basis = np.zeros((b, k + 1, n))
    hess = np.zeros((b, k + 1, k))
    broke = _compiled(_arnoldi_loop)(np.ascontiguousarray(mono, dtype=float), int(k), _start_vector(n), basis, hess)
    mu, vec, resid = _ritz(basis, hess, k, vectors)
    if broke.any():
        # LAPACK returns real Ritz values when all of a batch's are real: complex before the
        # redone rows go in, or their imaginary parts (and so their moduli) would be dropped
        mu2, vec2, resid2 = _arnoldi_numpy(mono[broke], k, vectors)
        mu = mu.astype(complex)
        mu[broke], resid[broke] = mu2, resid2
        if vectors:
            vec = vec.astype(complex)
            vec[broke] = vec2
    return mu, vec, resid


def _arnoldi_numpy(mono: np.ndarray, k: int, vectors: bool):
    """:func:`_arnoldi` in NumPy, continuing a broken-down basis with a fresh direction."""
    b, n, _ = mono.shape
    rng = np.random.default_rng(20040117)
    basis = np.zeros((b, n, k + 1))
    hess = np.zeros((b, k + 1, k))
    basis[:, :, 0] = _start_vector(n)
    for j in range(k):
        w = mono @ basis[:, :, j : j + 1]  # (b, n, 1)
        vj = basis[:, :, : j + 1]
        h = np.swapaxes(vj, 1, 2) @ w
        w -= vj @ h
        h2 = np.swapaxes(vj, 1, 2) @ w  # second Gram-Schmidt pass
        w -= vj @ h2
        h += h2
        hess[:, : j + 1, j] = h[:, :, 0]
        beta = np.linalg.norm(w[:, :, 0], axis=1)
        dead = beta <= 1e-13 * np.maximum(np.linalg.norm(hess[:, : j + 1, j], axis=1), 1e-300)
        if dead.any():  # invariant subspace found: continue the basis with a fresh direction
            fresh = rng.standard_normal((int(dead.sum()), n, 1))
            for _ in range(2):
                fresh -= vj[dead] @ (np.swapaxes(vj[dead], 1, 2) @ fresh)
            w[dead] = fresh
            beta[dead] = 0.0
        hess[:, j + 1, j] = beta
        basis[:, :, j + 1] = w[:, :, 0] / np.linalg.norm(w[:, :, 0], axis=1)[:, None]
    return _ritz(np.swapaxes(basis, 1, 2), hess, k, vectors)


def _dominant(mono: np.ndarray, *, vectors: bool = False):
    """Multiplier of largest modulus of each matrix of a stack (B, N, N), and its eigenvector.

    Small matrices: LAPACK. Larger: ``_KRYLOV`` steps of Arnoldi (two-pass Gram-Schmidt, a fixed
    seeded start vector); the Ritz value of largest modulus is accepted when its residual is below
    ``_RESIDUAL_RTOL`` relative; otherwise Arnoldi with twice the steps, and then LAPACK.
    """
    b, n, _ = mono.shape
    mu = np.zeros(b, dtype=complex)
    vec = np.zeros((b, n), dtype=complex) if vectors else None
    todo = np.arange(b)
    for k in (_KRYLOV, 2 * _KRYLOV):
        if todo.size == 0 or n <= k + 4:
            break
        m_, v_, r_ = _arnoldi(mono[todo], k, vectors)
        ok = r_ <= _RESIDUAL_RTOL * np.maximum(np.abs(m_), 1e-12)
        mu[todo[ok]] = m_[ok]
        if vectors:
            vec[todo[ok]] = v_[ok]
        todo = todo[~ok]
    if todo.size:
        if n > 2 * _KRYLOV + 4:
            log.debug("Arnoldi did not converge on %d %d-monodromies; using LAPACK", todo.size, n)
        if vectors:
            vals, vecs = np.linalg.eig(mono[todo])
            j = np.argmax(np.abs(vals), axis=1)
            mu[todo], vec[todo] = vals[np.arange(todo.size), j], vecs[np.arange(todo.size), :, j]
        else:
            vals = np.linalg.eigvals(mono[todo])
            mu[todo] = vals[np.arange(todo.size), np.argmax(np.abs(vals), axis=1)]
    return mu, vec


# ------------------------------------------------------------------- the multiplier matrix-free
# Krylov dimensions tried in turn matrix-free: a product costs O(m n^2), not O(N^2), so the
# factorization is continued past the dense path's two before LAPACK (at lobe cusps and at high
# damping two multipliers of nearly equal modulus need more vectors).
_KRYLOV_FREE = (_KRYLOV, 2 * _KRYLOV, 4 * _KRYLOV, 8 * _KRYLOV)


def _apply_monodromy(phi, gd, lam, cutting, col_of, row_of, s_mat, bi, v, w, y, tmp):
    """``w = M v`` for batch member ``bi``, step by step (plain loops, compiled by numba): the
    state ``y_0 = v[:2n]`` propagated through the ``m`` step maps, ``y <- Phi_i y + Gd_i xi_i +
    Lam_i xi_{i+1}`` with the history read from ``v`` at the slots ``col_of`` (slot ``m`` is
    ``xi_0 = S eta_0``), the rows ``S eta_i`` recorded at ``row_of`` before step ``i``, and
    ``w[:2n] = y_m``: the map :func:`_assemble_loop` builds column by column, in ``O(m n^2)``."""
    m, n2, d, nn = phi.shape[1], phi.shape[2], gd.shape[3], s_mat.shape[1]
    for r in range(n2):
        y[r] = v[r]
    for i in range(m):
        r0 = row_of[i]
        if r0 >= 0:
            for a in range(d):
                acc = 0.0
                for q in range(nn):
                    acc += s_mat[a, q] * y[q]
                w[n2 + r0 + a] = acc
        for r in range(n2):
            acc = 0.0
            for q in range(n2):
                acc += phi[bi, i, r, q] * y[q]
            tmp[r] = acc
        if cutting[i]:
            c0 = col_of[i]
            for r in range(n2):
                acc = 0.0
                for a in range(d):
                    acc += gd[bi, i, r, a] * v[c0 + a]
                tmp[r] += acc
            if i + 1 < m:
                c1 = col_of[i + 1]
                for r in range(n2):
                    acc = 0.0
                    for a in range(d):
                        acc += lam[bi, i, r, a] * v[c1 + a]
                    tmp[r] += acc
            else:  # slot m: xi_0 = S eta_0, from the state's part of v
                for r in range(n2):
                    acc = 0.0
                    for a in range(d):
                        xi = 0.0
                        for q in range(nn):
                            xi += s_mat[a, q] * v[q]
                        acc += lam[bi, i, r, a] * xi
                    tmp[r] += acc
        for r in range(n2):
            y[r] = tmp[r]
    for r in range(n2):
        w[r] = y[r]


def _arnoldi_free_loop(phi, gd, lam, cutting, col_of, row_of, s_mat, first, k, basis, hess, skip):
    """Arnoldi steps ``first .. k - 1`` for each batch member not ``skip``-ped (plain loops,
    compiled by numba), continuing ``basis`` (B, >= k + 1, N) and ``hess`` (B, >= k + 1, >= k):
    :func:`_arnoldi_loop` with ``M v`` from :func:`_apply_monodromy`. A member whose basis breaks
    down is marked in ``skip``."""
    n, n2 = basis.shape[2], phi.shape[2]
    w = np.zeros(n)
    h = np.empty(k + 1)
    y = np.empty(n2)
    tmp = np.empty(n2)
    for bi in range(basis.shape[0]):
        if skip[bi]:
            continue
        for j in range(first, k):
            _apply_monodromy(phi, gd, lam, cutting, col_of, row_of, s_mat, bi, basis[bi, j], w, y, tmp)
            if _gram_schmidt(basis, hess, w, h, bi, j):
                skip[bi] = True
                break


def _dominant_matrix_free(phi, gd, lam, cutting, col_of, row_of, s_mat, size: int) -> np.ndarray:
    """Dominant multiplier of each reduced monodromy of a batch (``size`` rows), never formed.

    The Arnoldi iteration of :func:`_dominant` (the same seeded start vector, Gram-Schmidt and
    residual test) on ``M v`` applied step by step, so the multiplier equals the dense path's to
    rounding where 20 vectors converge; otherwise continued to the larger :data:`_KRYLOV_FREE`
    dimensions (there it equals LAPACK's to the residual test). NaN for a member still not
    converged or whose basis broke down (the caller forms those)."""
    bsz = phi.shape[0]
    mu = np.full(bsz, np.nan, dtype=complex)
    dims = [k for k in _KRYLOV_FREE if k + 4 < size]
    if not dims:  # too small for the Krylov steps
        return mu
    basis = np.zeros((bsz, dims[-1] + 1, size))
    hess = np.zeros((bsz, dims[-1] + 1, dims[-1]))
    basis[:, 0] = _start_vector(size)
    args = (np.ascontiguousarray(phi), np.ascontiguousarray(gd), np.ascontiguousarray(lam),
            np.asarray(cutting, dtype=np.bool_), col_of, row_of, np.ascontiguousarray(s_mat, dtype=float))
    broke = np.zeros(bsz, dtype=np.bool_)
    todo, first = np.arange(bsz), 0
    for k in dims:
        skip = np.ones(bsz, dtype=np.bool_)
        skip[todo] = False
        _compiled(_arnoldi_free_loop)(*args, first, k, basis, hess, skip)
        broke[todo] = skip[todo]
        live = todo[~broke[todo]]
        if live.size:
            m_, _, r_ = _ritz(basis[live, : k + 1], hess[live, : k + 1, :k], k, False)
            ok = r_ <= _RESIDUAL_RTOL * np.maximum(np.abs(m_), 1e-12)
            mu[live[ok]] = m_[ok]
            todo = np.setdiff1d(todo, live[ok])
        todo = todo[~broke[todo]]
        first = k
        if todo.size == 0:
            break
    return mu
