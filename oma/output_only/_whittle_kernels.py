"""Per-bin loops of the Whittle likelihood and its information (:mod:`oma.output_only.whittle`),
compiled by numba on first use (cached on disk), so that importing this module does not import numba.

Each bin's spectral matrix is ``l x l`` (``l``, the channels, at most a few): NumPy's stacked
``matmul``, ``cholesky`` and ``inv`` on ``(K, l, l)`` arrays spend most of their time on the
stacking, not the arithmetic. Measured on a group of a real record (Hurco, 530/543/585 Hz, 3 885
bins, 3 channels; session 19, one core): the likelihood with its gradient 10.3 -> 2.4 ms, the
information 41 -> 8.7 ms (its Gram product ``R^T R`` stays BLAS's). The loops do the arithmetic of
the NumPy expressions they replaced (the Cholesky factor and its inverse, ``S^-1 - y y^H``, the
whitened ``X Y^H + Y X^H``); over 312 random models (1-3 modes and channels, every tail and
background model, with and without the slope) value, gradient and information agree with them to
4e-13, 2e-12 and 7e-13 relative. Compiling all of them takes about 4 s, once per installation.
"""

from __future__ import annotations

import math

import numpy as np

__all__: list[str] = []


def _cholesky_inverse(s, k, min_ratio, linv, diag):
    """The inverse ``L^-1`` of the lower Cholesky factor of the Hermitian ``s[k]`` into
    ``linv[k]`` and the factor's diagonal into ``diag[k]``; False where ``s[k]`` is not positive
    definite to working precision (a pivot not positive and finite, or a diagonal ratio under
    ``min_ratio``: :func:`oma.output_only.whittle._whitener`'s test)."""
    l = s.shape[1]
    fac = np.zeros((l, l), dtype=np.complex128)
    for j in range(l):
        acc = s[k, j, j].real
        for p in range(j):
            acc -= fac[j, p].real ** 2 + fac[j, p].imag ** 2
        if not (acc > 0.0) or not math.isfinite(acc):
            return False
        djj = math.sqrt(acc)
        fac[j, j] = djj
        diag[k, j] = djj
        for i in range(j + 1, l):
            v = s[k, i, j]
            for p in range(j):
                v -= fac[i, p] * np.conj(fac[j, p])
            fac[i, j] = v / djj
    lo, hi = diag[k, 0], diag[k, 0]
    for j in range(1, l):
        lo = min(lo, diag[k, j])
        hi = max(hi, diag[k, j])
    if lo < min_ratio * hi:
        return False
    # forward substitution, column by column of the identity
    for c in range(l):
        for i in range(l):
            if i < c:
                linv[k, i, c] = 0.0
                continue
            v = 1.0 + 0.0j if i == c else 0.0j
            for p in range(c, i):
                v -= fac[i, p] * linv[k, p, c]
            linv[k, i, c] = v / fac[i, i].real
    return True


def _whiten_all(s, min_ratio):
    """``L^-1`` (K, l, l) and the factor's diagonal (K, l) of every bin; ``ok`` False when one bin
    is not positive definite."""
    n_k, l = s.shape[0], s.shape[1]
    linv = np.zeros((n_k, l, l), dtype=np.complex128)
    diag = np.zeros((n_k, l))
    for k in range(n_k):
        if not _cholesky_inverse(s, k, min_ratio, linv, diag):
            return False, linv, diag
    return True, linv, diag


def _model_spectrum(v, c, n, gain):
    """``gain V C V^H + N`` per bin, (K, l, l)."""
    n_k, l, mq = v.shape
    s = np.empty((n_k, l, l), dtype=np.complex128)
    vc = np.empty((l, mq), dtype=np.complex128)
    for k in range(n_k):
        for a in range(l):
            for j in range(mq):
                acc = 0.0j
                for i in range(mq):
                    acc += v[k, a, i] * c[i, j]
                vc[a, j] = acc
        for a in range(l):
            for b in range(a, l):
                acc = 0.0j
                for j in range(mq):
                    acc += vc[a, j] * np.conj(v[k, b, j])
                val = gain[k] * acc + n[a, b]
                s[k, a, b] = val
                s[k, b, a] = np.conj(val)
        for a in range(l):
            s[k, a, a] = s[k, a, a].real
    return s


def _likelihood_terms(v, c, n, gain, x, weight, u, d, log_w, min_ratio):
    """The sums the likelihood and its gradient need, in one pass over the bins.

    With ``S = gain V C V^H + N``, per bin (or block of ``weight`` bins whose summed periodogram
    matrix is ``X X^H``, ``x`` (K, l, r): a bin's is its DFT vector, r = 1) ``Y = S^-1 X`` and
    ``G = weight S^-1 - Y Y^H``: ``weight logdet S`` and ``tr(X^H S^-1 X)`` summed,
    ``Re sum gain V^H G V`` (mq, mq), ``Re sum G`` (l, l), per bin ``b.u`` with
    ``b = gain (C V^H G)[:m]`` (K, m), ``sum b / d`` (m, l) and ``sum log_w tr(Re(gain V^H G V) C)``.
    ``ok`` False where a bin's ``S`` is not positive definite.
    """
    n_k, l, mq = v.shape
    n_r = x.shape[2]
    m = u.shape[0]
    s = _model_spectrum(v, c, n, gain)
    linv = np.zeros((n_k, l, l), dtype=np.complex128)
    diag = np.zeros((n_k, l))
    ar = np.zeros((mq, mq))
    gr = np.zeros((l, l))
    bu = np.zeros((n_k, m), dtype=np.complex128)
    gv = np.zeros((m, l), dtype=np.complex128)
    logdet, quad, slope = 0.0, 0.0, 0.0
    w = np.empty((l, n_r), dtype=np.complex128)
    y = np.empty((l, n_r), dtype=np.complex128)
    sinv = np.empty((l, l), dtype=np.complex128)
    gmat = np.empty((l, l), dtype=np.complex128)
    gv_ = np.empty((l, mq), dtype=np.complex128)     # G V
    for k in range(n_k):
        if not _cholesky_inverse(s, k, min_ratio, linv, diag):
            return False, 0.0, 0.0, ar, gr, bu, gv, 0.0
        wk = weight[k]
        for a in range(l):
            logdet += wk * 2.0 * math.log(diag[k, a])
        for t in range(n_r):
            for a in range(l):
                acc = 0.0j
                for b in range(a + 1):
                    acc += linv[k, a, b] * x[k, b, t]
                w[a, t] = acc
                quad += acc.real ** 2 + acc.imag ** 2
        for a in range(l):
            for b in range(l):
                acc = 0.0j
                for p in range(max(a, b), l):
                    acc += np.conj(linv[k, p, a]) * linv[k, p, b]
                sinv[a, b] = acc
        for t in range(n_r):
            for a in range(l):
                acc = 0.0j
                for p in range(l):
                    acc += np.conj(linv[k, p, a]) * w[p, t]
                y[a, t] = acc
        for a in range(l):
            for b in range(l):
                yy = 0.0j
                for t in range(n_r):
                    yy += y[a, t] * np.conj(y[b, t])
                g_ab = wk * sinv[a, b] - yy
                gmat[a, b] = g_ab
                gr[a, b] += g_ab.real
        for a in range(l):
            for j in range(mq):
                acc = 0.0j
                for b in range(l):
                    acc += gmat[a, b] * v[k, b, j]
                gv_[a, j] = acc
        g_k = gain[k]
        tr = 0.0
        for i in range(mq):
            for j in range(mq):
                acc = 0.0j
                for a in range(l):
                    acc += np.conj(v[k, a, i]) * gv_[a, j]
                re = g_k * acc.real
                ar[i, j] += re
                tr += re * c[j, i]
        slope += log_w[k] * tr
        for r in range(m):
            bur = 0.0j
            for a in range(l):
                acc = 0.0j
                for i in range(mq):
                    # (V^H G)[i, a] = conj((G V)[a, i]): G is Hermitian to the bit (both of its terms
                    # are formed as conjugate pairs), so the product is not formed twice
                    acc += c[r, i] * np.conj(gv_[a, i])
                b_ra = g_k * acc
                bur += b_ra * u[r, a]
                gv[r, a] += b_ra / d[k, r]
            bu[k, r] = bur
    return True, logdet, quad, ar, gr, bu, gv, slope


def _hermitian_coordinates(xw, yw, r, row, col):
    """The real coordinates of ``X Y^H + Y X^H`` for whitened ``X``, ``Y`` (l,) into ``r[row:, col]``
    (the diagonal, and sqrt 2 times the real and imaginary parts of the upper triangle), added to
    what is there."""
    l = xw.size
    s2 = math.sqrt(2.0)
    for a in range(l):
        r[row, col] += 2.0 * (xw[a].real * yw[a].real + xw[a].imag * yw[a].imag)
        row += 1
        for b in range(a + 1, l):
            r[row, col] += s2 * (xw[a].real * yw[b].real + xw[a].imag * yw[b].imag
                                 + yw[a].real * xw[b].real + yw[a].imag * xw[b].imag)
            r[row + 1, col] += s2 * (xw[a].imag * yw[b].real - xw[a].real * yw[b].imag
                                     + yw[a].imag * xw[b].real - yw[a].real * xw[b].imag)
            row += 2


def _information_rows(v, vc, vl, d, dd_df, dd_dz, du, g, tm0, tm1, tl0, yn, half_log_w, slope, linv):
    """The information's Gram matrix factor ``R`` (K l^2, P), ``J = R^T R``
    (:func:`oma.output_only.whittle._fisher` documents the pairs ``X_i``, ``Y_i`` with ``dS_i =
    X_i Y_i^H + Y_i X_i^H``): per bin the whitened columns of ``V``, ``V C``, ``V L_C`` and the
    directions' ``(I - u u^T) / |v|`` once, each parameter's pair a multiple of two of them.
    Parameters in order: frequencies, damping, directions (m x l), ``L_C``'s entries ``(tm0,
    tm1)``, the background's ``tl0`` with ``Y`` rows ``yn``, and (``slope``) the slope's, the sum
    of one pair per column of ``V L_C``."""
    n_k, l, mq = v.shape
    m = d.shape[1]
    n_c, n_n = tm0.size, tl0.size
    n_p = 2 * m + m * l + n_c + n_n + (1 if slope else 0)
    r = np.zeros((n_k * l * l, n_p))
    wv = np.empty((l, mq), dtype=np.complex128)
    wvc = np.empty((l, mq), dtype=np.complex128)
    wvl = np.empty((l, mq), dtype=np.complex128)
    wdu = np.empty((m * l, l), dtype=np.complex128)
    wyn = np.empty((n_n, l), dtype=np.complex128)
    xw = np.empty(l, dtype=np.complex128)
    yw = np.empty(l, dtype=np.complex128)
    for k in range(n_k):
        for a in range(l):
            for j in range(mq):
                av, avc, avl = 0.0j, 0.0j, 0.0j
                for b in range(a + 1):
                    li = linv[k, a, b]
                    av += li * v[k, b, j]
                    avc += li * vc[k, b, j]
                    avl += li * vl[k, b, j]
                wv[a, j], wvc[a, j], wvl[a, j] = av, avc, avl
            for i in range(m * l):
                acc = 0.0j
                for b in range(a + 1):
                    acc += linv[k, a, b] * du[i, b]
                wdu[i, a] = acc
            for t in range(n_n):
                acc = 0.0j
                for b in range(a + 1):
                    acc += linv[k, a, b] * yn[t, b]
                wyn[t, a] = acc
        gk = g[k]
        row = k * l * l
        col = 0
        for dd in (dd_df, dd_dz):
            for r_ in range(m):
                f = -dd[k, r_] / d[k, r_] * gk
                for a in range(l):
                    xw[a] = wv[a, r_] * f
                    yw[a] = wvc[a, r_] * gk
                _hermitian_coordinates(xw, yw, r, row, col)
                col += 1
        for r_ in range(m):
            f = gk / d[k, r_]
            for j in range(l):
                for a in range(l):
                    xw[a] = wdu[r_ * l + j, a] * f
                    yw[a] = wvc[a, r_] * gk
                _hermitian_coordinates(xw, yw, r, row, col)
                col += 1
        for t in range(n_c):
            for a in range(l):
                xw[a] = wv[a, tm0[t]] * gk
                yw[a] = wvl[a, tm1[t]] * gk
            _hermitian_coordinates(xw, yw, r, row, col)
            col += 1
        for t in range(n_n):
            for a in range(l):
                xw[a] = linv[k, a, tl0[t]]
                yw[a] = wyn[t, a]
            _hermitian_coordinates(xw, yw, r, row, col)
            col += 1
        if slope:
            for j in range(mq):
                for a in range(l):
                    yw[a] = wvl[a, j] * gk
                    xw[a] = yw[a] * half_log_w[k]
                _hermitian_coordinates(xw, yw, r, row, col)
    return r


_KERNELS: dict = {}

#: The plain functions the loops call: compiled first and bound in their names' place, so that
#: numba, compiling a loop, finds compiled functions there.
_CALLEES = ("_cholesky_inverse", "_model_spectrum", "_hermitian_coordinates")


def compiled(name: str):
    """The loop ``name`` of this module compiled by numba on first use (cached on disk)."""
    if name not in _KERNELS:
        import numba

        for callee in _CALLEES:
            if callee not in _KERNELS:
                _KERNELS[callee] = globals()[callee] = numba.njit(cache=True)(globals()[callee])
        if name not in _KERNELS:
            _KERNELS[name] = numba.njit(cache=True)(globals()[name])
    return _KERNELS[name]
