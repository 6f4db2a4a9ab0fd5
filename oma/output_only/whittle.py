"""The Whittle likelihood of the output-only modal spectrum model, its analytic gradient and
Fisher information (:mod:`oma.output_only.ml` fits it; see there for the model and its
references). Parameters: frequencies ``f0 (1 + zeta0 p_f)``, damping ``exp(p_z)``, raw direction
vectors (normalised), the free entries of the Cholesky factors of the input covariance
``C`` (modes, then residual terms) and of the constant background ``N`` (or, with
``_Model.signed_background``, ``N``'s own entries), and (``_Model.slope``) the input's spectral
slope ``beta`` across the group's band: the input covariance at ``w`` is ``C (w / w_c)^beta``,
``w_c`` the band's geometric centre (a coloured background force: session 15).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from ._whittle_kernels import compiled

__all__: list[str] = []


@functools.lru_cache(maxsize=None)
def _tril(n):
    """The lower triangle's indices of an ``n x n`` matrix (read-only: shared by every call)."""
    rows, cols = np.tril_indices(n)
    rows.flags.writeable = cols.flags.writeable = False
    return rows, cols


_NO_ENTRIES = _tril(0)


class _Model(NamedTuple):
    """What a group's likelihood is evaluated on: ``m`` free modes, ``l`` channels, the bins'
    angular frequencies ``w`` (K,), the derivative gain ``w^(2d)`` normalised to mean 1, the fixed
    residual columns ``fx`` (K, l, q) (:func:`_residual_columns`; q = 0: none), whether a
    constant background ``N`` is fitted, the reference ``(f0, zeta0)`` of the parametrisation, and
    whether the residual terms' input may correlate with the modes' (``coherent``; else ``C`` is
    block diagonal and the residual terms are a frequency-dependent background), and whether the
    input's level has a fitted slope in log frequency (``slope``; the last parameter, ``beta``:
    the input covariance is ``C (w / w_c)^beta``), and whether ``N``'s parameters are its own
    lower triangle (``signed_background``: ``N`` symmetric, of either sign where the model spectrum
    stays positive definite; such a model is made from a fit's optimum by
    :func:`oma.output_only._ml_fit._signed` only) instead of its Cholesky factor's (``N`` positive
    semi-definite), and the bins each of ``w`` stands for (``weight`` (K,): pooled blocks,
    :mod:`oma.output_only.blocks`, whose data are the roots ``X`` (K, l, l) of their summed
    periodogram matrices; None: each ``w`` one bin, whose data are its DFT vector, (K, l)), and
    whether the directions are complex (``complex_directions``: the imaginary parts of the raw
    direction vectors are the last ``m l`` parameters, after ``beta``; session 27)."""

    m: int
    l: int
    w: np.ndarray
    gain: np.ndarray
    fx: np.ndarray
    noise: bool
    ref: tuple
    coherent: bool = True
    slope: bool = False
    signed_background: bool = False
    weight: np.ndarray | None = None
    complex_directions: bool = False

    @property
    def n_bins(self) -> int:
        """The periodogram bins the model is fitted to (the blocks' bins where pooled)."""
        return int(self.w.size if self.weight is None else round(float(np.sum(self.weight))))

    @property
    def w_c(self) -> float:
        """The geometric centre of the band's positive bins (rad/s; 1 without any)."""
        wp = self.w[self.w > 0]
        return float(np.sqrt(wp.min() * wp.max())) if wp.size else 1.0

    @property
    def log_w(self) -> np.ndarray:
        """``log(w / w_c)`` (K,); a 0 Hz bin taken at the lowest positive one."""
        wp = self.w[self.w > 0]
        return np.log(np.maximum(self.w, wp.min()) / self.w_c) if wp.size else np.zeros(self.w.size)

    @property
    def q(self) -> int:
        return int(self.fx.shape[2])

    @property
    def slope_index(self) -> int:
        """The index of ``beta`` in the parameters (counted from the end)."""
        return -1 - (self.m * self.l if self.complex_directions else 0)


class _Params(NamedTuple):
    """The decoded parameter vector: frequencies ``f`` (m,), damping ``z`` (m,), unit directions
    ``u`` (m, l) and the norms ``norm`` (m,) of their raw vectors, the Cholesky factors ``lc``
    (m + q, m + q) and ``ln`` (l, l) of the input covariance ``c`` (modes and residual terms) and
    the background ``n`` (with ``_Model.signed_background``, ``ln`` is ``n``'s lower triangle),
    the index sets ``tm``, ``tl`` of those factors' free entries and the input's slope ``beta``
    (0 without ``_Model.slope``)."""

    f: np.ndarray
    z: np.ndarray
    u: np.ndarray
    norm: np.ndarray
    lc: np.ndarray
    ln: np.ndarray
    c: np.ndarray
    n: np.ndarray
    tm: tuple
    tl: tuple
    beta: float = 0.0

#: Standard deviation of the Gaussian prior on the input's slope ``beta`` (the exponent of the
#: force's spectral density, ``S_F ~ f^beta``, across one group's band): a judgement, not a
#: measurement (cutting-force noise is neither white nor, over a mode's band of +-25 %, much
#: steeper than f^(+-1), two of these standard deviations). Where the band fixes ``beta`` well
#: (its standard error well under this) the prior changes nothing; where it does not (a single
#: mode in 20 s of accelerations: 0.6-1.0 without the prior) it keeps a white record's
#: frequencies from paying the slope's full price, and it enters the information, so the
#: intervals carry the slope's remaining uncertainty. Session 15: with 1.0 the paper cell's
#: 24.8 Hz mode scattered 0.57 % (mean |error|, white records; 0.30 % with a flat input), with
#: 0.5 0.45 %; the audit's blue and pink records came inside their intervals with both.
SLOPE_PRIOR_SD = 0.5
#: Largest magnitude of the input's slope ``beta`` (a band of +-25 % in frequency then spans a
#: factor e^10 in input level: far beyond any force spectrum, and no overflow).
MAX_SLOPE = 20.0


def _free_c(mod: _Model):
    """Free entries of the Cholesky factor of ``C``: all of its lower triangle, or without the
    block coupling the residual terms to the modes (then ``C`` is block diagonal)."""
    return _free_entries(mod.m, mod.q, mod.coherent or mod.q == 0)


@functools.lru_cache(maxsize=None)
def _free_entries(m: int, q: int, coupled: bool):
    tm = _tril(m + q)
    if coupled:
        return tm
    keep = ~((tm[0] >= m) & (tm[1] < m))
    rows, cols = tm[0][keep], tm[1][keep]
    rows.flags.writeable = cols.flags.writeable = False
    return rows, cols


def _unpack(p, mod: _Model) -> _Params:
    """Decode ``p``: ``f0 (1 + zeta0 p_f)``, ``exp(p_z)``, raw directions, the two Cholesky factors."""
    f0, z0 = mod.ref
    m, l, mq = mod.m, mod.l, mod.m + mod.q
    i = 0
    f = f0 * (1.0 + z0 * p[i:i + m]); i += m
    z = np.exp(np.minimum(p[i:i + m], 30.0)); i += m
    vraw = p[i:i + m * l].reshape(m, l); i += m * l
    norm = np.maximum(np.linalg.norm(vraw, axis=1), 1e-300)
    tm = _free_c(mod)
    tl = _tril(l) if mod.noise else _NO_ENTRIES
    lc = np.zeros((mq, mq)); lc[tm] = p[i:i + tm[0].size]; i += tm[0].size
    ln = np.zeros((l, l)); ln[tl] = p[i:i + tl[0].size]; i += tl[0].size
    n = ln + np.tril(ln, -1).T if mod.signed_background else ln @ ln.T
    beta = float(np.clip(p[i], -MAX_SLOPE, MAX_SLOPE)) if mod.slope else 0.0
    if mod.complex_directions:   # u = (v_re + i v_im) / |v|
        vraw = vraw + 1j * p[p.size - m * l:].reshape(m, l)
        norm = np.maximum(np.linalg.norm(vraw, axis=1), 1e-300)
    return _Params(f, z, vraw / norm[:, None], norm, lc, ln, lc @ lc.T, n, tm, tl, beta)


def _gain(pp: _Params, mod: _Model) -> np.ndarray:
    """The bins' weights of the modes' term (K,): the derivative gain times the input's slope,
    ``gain(w) (w / w_c)^beta``."""
    return mod.gain * np.exp(pp.beta * mod.log_w) if mod.slope else mod.gain


def _response(f, z, z0, w):
    """Normalised inverse modal response ``(1 - (w/w_r)^2 + 2 i zeta w/w_r) / (2 zeta0)``, shape
    (K, m) (the response ``1/d`` peaks at about 1: the input covariance is O(1), which the
    optimiser needs)."""
    q = w[:, None] / (2 * np.pi * f[None, :])
    return (1.0 - q ** 2 + 2j * z[None, :] * q) / (2 * z0[None, :])


def _residual_columns(w, l):
    """Residual terms of the modes outside the band, in displacement: ``(w_c / w)^2`` per channel
    (modes below: mass lines) and ``1`` per channel (modes above: stiffness lines), (K, l, 2 l).
    Their input covariance is fitted jointly with the modes' (the same white force drives the
    modes in the band and the tails of those outside, so the tails are coherent with the band's
    modes: a constant background cannot represent that)."""
    wc = np.sqrt(w.min() * w.max())
    eye = np.eye(l)
    lo = (wc / w)[:, None, None] ** 2 * eye[None]
    return np.concatenate([lo, np.broadcast_to(eye, lo.shape)], axis=2).astype(complex)


def _columns(pp: _Params, mod: _Model):
    """``d`` (K, m) and the spectrum's columns ``V`` (K, l, m + q): modes then residual terms."""
    d = _response(pp.f, pp.z, mod.ref[1], mod.w)
    v = pp.u.T[None, :, :] / d[:, None, :]
    return d, (np.concatenate([v, mod.fx], axis=2) if mod.q else v)


def _spectrum(p, mod: _Model):
    """The decoded parameters, ``q = w / w_r`` (K, m), ``d``, ``V``, ``V^H`` and the model
    spectral matrix ``S`` (K, l, l) at the parameters ``p``."""
    pp = _unpack(p, mod)
    q = mod.w[:, None] / (2 * np.pi * pp.f[None, :])
    d, v = _columns(pp, mod)
    vh = np.conj(np.swapaxes(v, 1, 2))
    return pp, q, d, v, vh, compiled("_model_spectrum")(np.ascontiguousarray(v), pp.c, pp.n, _gain(pp, mod))


def _whitener(s):
    """The inverse Cholesky factor ``L^-1`` (K, l, l) of the model spectrum ``s`` and the factor's
    diagonal (K, l); None when ``s`` is not positive definite to working precision (a factor with a
    diagonal ratio under :data:`MAX_CONDITION_ROOT` in a bin, or none at all): such a model is no
    fit, its likelihood is taken as 1e30 and it has no information."""
    ok, linv, diag = compiled("_whiten_all")(np.ascontiguousarray(s, dtype=complex), MAX_CONDITION_ROOT)
    return (linv, diag) if ok else None


#: Smallest ratio of the Cholesky factor's diagonal entries per bin (the square root of the
#: smallest reciprocal condition number, 1e-14) of a model spectrum taken for a fit.
MAX_CONDITION_ROOT = 1e-7


def _roots(x) -> np.ndarray:
    """The data as roots of the bins' (or blocks') periodogram matrices, (K, l, r): a bin's DFT
    vectors (K, l) as single columns."""
    return x[:, :, None] if x.ndim == 2 else x


def _weights(mod: _Model) -> np.ndarray:
    """The bins each of the model's ``w`` stands for (K,): ones where not pooled."""
    return np.ones(mod.w.size) if mod.weight is None else np.asarray(mod.weight, dtype=float)


def _nll(p, mod: _Model, x, *, per_bin: bool = False):
    """Whittle negative log-likelihood and its gradient (analytic) in the parameters ``p``;
    ``per_bin``: the gradient of each bin's (or block's) term instead, shape (K, n_params) (the scores whose
    outer products give the sandwich covariance; without the slope's prior :data:`SLOPE_PRIOR_SD`,
    which is no bin's term)."""
    if not per_bin:
        return _nll_sum(p, mod, x)
    val, grad, _ = _bin_scores(p, mod, x)
    return val, grad


def _bin_scores(p, mod: _Model, x):
    """:func:`_nll` with ``per_bin``, and the complex ``b / d`` (K, m, l) of each bin, ``b = gain
    (C V^H G)[:m]``: moving mode ``r``'s column of ``V`` by ``dv / d_r`` changes the bin's term by ``2
    Re((b / d)_r . dv)`` (so ``dv`` real moves its direction; ``i dv`` turns it complex). None in
    place of ``b / d`` where the model spectrum is not positive definite."""
    m = mod.m
    pp, q, d, v, vh, s = _spectrum(p, mod)
    u, c = pp.u, pp.c
    gain = _gain(pp, mod)
    white = _whitener(s)
    if white is None:
        return 1e30, np.zeros((x.shape[0], p.size)), None
    linv, diag = white
    # the inverse through the Cholesky factor: ``S^-1 = L^-H L^-1`` stays positive definite where
    # ``inv(S)`` of a nearly singular spectrum does not (a refit once reached a quadratic form of
    # -1.9e12, "gaining" that much likelihood by dropping a true mode); the form is ``|L^-1 x|^2``
    sinv = np.conj(np.swapaxes(linv, 1, 2)) @ linv
    if mod.weight is None:
        logdet = 2.0 * np.sum(np.log(diag))
        w = (linv @ x[:, :, None])[..., 0]
        y = (sinv @ x[:, :, None])[..., 0]
        gmat = sinv - y[:, :, None] * np.conj(y)[:, None, :]               # dL/dS^T, Hermitian
    else:   # blocks: ``n log det S + |L^-1 X|^2``, ``G = n S^-1 - Y Y^H``
        logdet = 2.0 * np.sum(mod.weight[:, None] * np.log(diag))
        w = linv @ x
        y = sinv @ x
        gmat = mod.weight[:, None, None] * sinv - y @ np.conj(np.swapaxes(y, 1, 2))
    val = float(logdet + np.sum(np.abs(w) ** 2))
    a = gain[:, None, None] * (vh @ gmat @ v)                              # (K, m+q, m+q)
    b = gain[:, None, None] * (c[None] @ vh @ gmat)[:, :m]                 # (K, m, l)
    bu = np.einsum("kra,ra->kr", b, u)                                     # (K, m)
    slope = mod.log_w * np.einsum("kij,ji->k", np.real(a), c) if mod.slope else 0.0
    b_over_d = b / d[:, :, None]
    grad = _gradient(np.zeros((x.shape[0], p.size)), pp, mod, q, d, bu, b_over_d, np.real(a),
                     np.real(gmat), slope, lambda t: t)
    return val, grad, b_over_d


def _response_derivatives(q, f, z, z0):
    """The derivatives of the normalised inverse response ``d`` (:func:`_response`) in each mode's
    frequency and damping ratio, (K, m) each."""
    return (2 * q ** 2 - 2j * z[None, :] * q) / (f[None, :] * 2 * z0[None, :]), 2j * q / (2 * z0[None, :])


def _gradient(grad, pp: _Params, mod: _Model, q, d, bu, b_over_d, ar, gr, slope, total):
    """The likelihood's gradient into ``grad`` (n_params,) or, bin by bin, (K, n_params), from
    ``dL/dS^T = G`` through ``b = gain (C V^H G)[:m]``: ``bu = b . u`` per bin (K, m), weighed bin
    by bin by the response's derivatives and then reduced by ``total`` (the sum over the bins, or the
    identity for the bins' scores), and, already so reduced, ``b / d``, ``Re gain V^H G V`` (``ar``),
    ``Re G`` (``gr``) and the slope's ``log(w / w_c) tr(Re(gain V^H G V) C)``."""
    f0, z0 = mod.ref
    m = mod.m
    f, z, u, norm, lc, ln, tm, tl = pp.f, pp.z, pp.u, pp.norm, pp.lc, pp.ln, pp.tm, pp.tl
    dd = -bu / d ** 2                                                      # dL/dd (times 2 Re)
    dd_df, dd_dz = _response_derivatives(q, f, z, z0)
    grad[..., :m] = 2 * np.real(total(dd * dd_df)) * f0 * z0
    grad[..., m:2 * m] = 2 * np.real(total(dd * dd_dz)) * z
    i = 2 * m + m * mod.l
    # u = v / |v|: moving v by dv moves the term by 2 Re(G . du), du = (dv - u Re(u^H dv)) / |v|,
    # G = b / d: along v's real parts 2 Re G - 2 Re(G . u) Re u (for real u the projection
    # (I - u u^T) of 2 Re G), along its imaginary parts (complex directions) -2 Im G - 2 Re(G . u) Im u
    gu = 2 * np.real(np.sum(b_over_d * u, axis=-1, keepdims=True))
    g_re = (2 * np.real(b_over_d) - gu * np.real(u)) / norm[:, None]
    grad[..., 2 * m:i] = g_re.reshape(g_re.shape[:-2] + (-1,))
    if mod.complex_directions:
        g_im = (-2 * np.imag(b_over_d) - gu * np.imag(u)) / norm[:, None]
        grad[..., grad.shape[-1] - m * mod.l:] = g_im.reshape(g_im.shape[:-2] + (-1,))
    ar = 0.5 * (ar + np.swapaxes(ar, -1, -2))
    grad[..., i:i + tm[0].size] = (2 * ar @ lc)[..., tm[0], tm[1]]
    if mod.noise:
        gr = 0.5 * (gr + np.swapaxes(gr, -1, -2))
        # through N = L L^T, or N's own entries (dN / dN_ab = E_ab + E_ba off the diagonal)
        gn = np.where(tl[0] == tl[1], 1.0, 2.0) * gr[..., tl[0], tl[1]] if mod.signed_background \
            else (2 * gr @ ln)[..., tl[0], tl[1]]
        grad[..., i + tm[0].size:i + tm[0].size + tl[0].size] = gn
    if mod.slope:   # dS/dbeta = log(w / w_c) gain V C V^H
        grad[..., mod.slope_index] = slope if abs(pp.beta) < MAX_SLOPE else 0.0
    return grad


def _nll_sum(p, mod: _Model, x):
    """:func:`_nll` summed over the bins: the same terms, formed bin by bin in one compiled pass
    (:func:`oma.output_only._whittle_kernels._likelihood_terms`) instead of stacked NumPy
    products."""
    pp = _unpack(p, mod)
    q = mod.w[:, None] / (2 * np.pi * pp.f[None, :])
    d, v = _columns(pp, mod)
    ok, logdet, quad, ar, gr, bu, gv, slope = compiled("_likelihood_terms")(
        np.ascontiguousarray(v), pp.c, pp.n, np.ascontiguousarray(_gain(pp, mod), dtype=float),
        np.ascontiguousarray(_roots(x)), _weights(mod), np.ascontiguousarray(pp.u), np.ascontiguousarray(d), np.ascontiguousarray(mod.log_w if mod.slope
                                                                               else np.zeros(mod.w.size)),
        MAX_CONDITION_ROOT)
    if not ok:
        return 1e30, np.zeros_like(p)
    val = float(logdet + quad)
    # the kernel's sums; ``b . u`` per bin (the frequencies' and damping's terms weigh it bin by bin)
    grad = _gradient(np.zeros_like(p), pp, mod, q, d, bu, gv, ar, gr, slope, lambda t: np.sum(t, axis=0))
    if mod.slope:   # the prior 0.5 (beta / sd)^2
        val += 0.5 * (pp.beta / SLOPE_PRIOR_SD) ** 2
        grad[mod.slope_index] += pp.beta / SLOPE_PRIOR_SD ** 2
    return val, grad


def _fisher(p, mod: _Model):
    """Fisher information of the Whittle likelihood, ``J_ij = Re sum_k tr(S^-1 dS_i S^-1 dS_j)``
    (:func:`_information_factor` ``R``: ``J = R^T R``, plus the slope's prior). None where the
    model spectrum is not positive definite."""
    r = _information_factor(p, mod)
    if r is None:
        return None
    if mod.complex_directions:   # the imaginary parts' columns, after the others
        m, l = mod.m, mod.l
        pp = _unpack(p, mod)
        # dv along v's imaginary part j: du = (i e_j - u Im u_j) / |v|
        du = (1j * np.eye(l)[None] - np.imag(pp.u)[:, :, None] * pp.u[:, None, :]) / pp.norm[:, None, None]
        r = np.hstack([r, _information_factor(p, mod, du)[:, 2 * m:2 * m + m * l]])
    jm = r.T @ r
    if mod.slope:
        jm[mod.slope_index, mod.slope_index] += 1.0 / SLOPE_PRIOR_SD ** 2     # the slope's prior
    return jm


def _information_factor(p, mod: _Model, directions=None):
    """The factor ``R`` (K l^2, n_params) of the Fisher information ``J = R^T R`` (without the
    slope's prior), ``J_ij = Re sum_k tr(S^-1 dS_i S^-1 dS_j)``; with ``directions`` (m, l, l),
    complex, the direction parameters' columns are those of moving mode ``r``'s direction by
    ``directions[r, j]`` per unit of its parameter ``j`` instead (the fit's own: ``(I - u u^T)_j /
    |v|``).

    Every ``dS_i`` has the form ``X Y^H + Y X^H`` (a column of ``V`` or of a Cholesky factor
    changing); with ``S = L L^H`` the whitened ``A_i = L^-1 dS_i L^-H`` give ``J = Re(A^H A)``.
    The slope's ``dS = log(w / w_c) gain V C V^H`` is the sum of such terms over the columns of
    ``V L_C``. None where the model spectrum is not positive definite (:func:`_whitener`: the
    likelihood's guard; no fit there has an information)."""
    f0, z0 = mod.ref
    m, l = mod.m, mod.l
    pp, q, d, v, vh, s = _spectrum(p, mod)
    f, z, u, norm, lc, ln, c, n, tm, tl = pp[:10]
    white = _whitener(s)
    if white is None:
        return None
    # the pairs (X_i, Y_i), each a multiple of a column of V, V C, V L_C or of the directions'
    # (I - u u^T) / |v|: frequency and damping X = -V_r (dd/d_r) sqrt(gain), Y = (V C)_r
    # sqrt(gain); direction (r, a) X = (I - u u^T)_a / (|v| d_r) sqrt(gain), Y = (V C)_r sqrt(gain);
    # L_C's entry (a, b) X = V_a sqrt(gain), Y = (V L_C)_b sqrt(gain); the background's
    # Cholesky entry (a, b) X = e_a, Y = L_N e_b (signed: X = e_a, Y = e_b, halved on the
    # diagonal); the slope, one pair per column j of V L_C, X = log(w/w_c) / 2 (V L_C)_j sqrt(gain),
    # Y = (V L_C)_j sqrt(gain). Whitened by L^-1 bin by bin, and A_i = X_i Y_i^H + Y_i X_i^H is
    # Hermitian: in its real coordinates (the diagonal, and sqrt 2 times the real and imaginary
    # parts of the upper triangle) Re tr(A_i A_j) is a real inner product, so J is one real Gram
    # matrix (a quarter of the complex one's arithmetic)
    dd_df, dd_dz = _response_derivatives(q, f, z, z0)
    dd_df, dd_dz = dd_df * (f0 * z0)[None, :], dd_dz * z[None, :]     # in the parameters p_f, p_z
    # (m, j, a): dv along v's real part j moves u by du = (e_j - u Re u_j) / |v| (for real u the
    # projection (I - u u^T) / |v|)
    du = (np.eye(l)[None] - np.real(u)[:, :, None] * u[:, None, :]) / norm[:, None, None] if directions is None \
        else np.asarray(directions)
    yn = np.eye(l)[tl[1]] * np.where(tl[0] == tl[1], 0.5, 1.0)[:, None] if mod.signed_background \
        else ln[:, tl[1]].T
    r = compiled("_information_rows")(
        np.ascontiguousarray(v), np.ascontiguousarray(v @ c), np.ascontiguousarray(v @ lc),
        np.ascontiguousarray(d), np.ascontiguousarray(dd_df), np.ascontiguousarray(dd_dz),
        np.ascontiguousarray(du.reshape(m * l, l), dtype=complex), np.sqrt(_gain(pp, mod)),
        np.ascontiguousarray(tm[0]), np.ascontiguousarray(tm[1]), np.ascontiguousarray(tl[0]),
        np.ascontiguousarray(yn, dtype=complex).reshape(tl[0].size, l), 0.5 * mod.log_w, bool(mod.slope), white[0])
    if mod.weight is not None:   # a block's information is its bins' (its spectrum is theirs)
        r *= np.repeat(np.sqrt(mod.weight), l * l)[:, None]
    return r


def _input_level(p, mod: _Model, derivative: int, direction_scale):
    """Each mode's input level in the physical channels, and the gradient of its logarithm in ``p``.

    The model's mode ``r`` contributes ``gain(w) C_rr u_r u_r^T / |d_r|^2`` to the spectrum of the
    group's scaled channels; in the signal's channels (times ``direction_scale``, shape (l,)) and
    as displacement that is ``P_r v_r v_r^T / |1 - (w/w_r)^2 + 2 i zeta_r w/w_r|^2``, ``v_r`` the
    direction made unit there, with ``P_r = |D u_r|^2 C_rr (2 zeta0_r)^2 / mean(w^(2 derivative))``.
    ``P_r`` (m^2/Hz when the channels are metres and their derivatives; two-sided, as the DFT's
    normalisation ``1/sqrt(fs n)``) is ``E|v_r . F|^2 / k_r^2``: with the mode's stiffness, ``P_r
    k_r^2`` is the power spectral density of the input force along ``v_r``. With a fitted slope
    (``_Model.slope``) the input's level is ``P_r (w / w_c)^beta``: the level returned is that
    at the mode's own frequency, ``w = 2 pi f_r`` (what a force's spectral density at the mode
    is compared with).

    Returns
    -------
    level : ndarray, shape (m,)
    grad_log : ndarray, shape (m, n_params)
        ``d log P_r / d p`` (through ``C_rr``, the direction's norm ``|D u_r|`` and, with a slope,
        ``beta log(2 pi f_r / w_c)``).
    """
    pp = _unpack(p, mod)
    m, l = mod.m, mod.l
    d = np.asarray(direction_scale, dtype=float)
    du = pp.u * d[None, :]
    n2 = np.sum(np.abs(du) ** 2, axis=1)
    crr = np.diag(pp.c)[:m]
    w2d = mod.w ** (2 * int(derivative))
    level = n2 * crr * (2.0 * mod.ref[1]) ** 2 / np.mean(w2d)
    grad = np.zeros((m, p.size))
    i0 = 2 * m + m * l
    tm = pp.tm
    for r in range(m):
        # C_rr = sum_j lc[r, j]^2 over row r of the Cholesky factor
        row = np.flatnonzero(tm[0] == r)
        grad[r, i0 + row] = 2.0 * pp.lc[r, tm[1][row]] / crr[r]
        if mod.complex_directions:   # the direction's part not derived (no error is drawn from it)
            continue
        # |D u|^2, u = v / |v|: d log|D u|^2 / dv = (I - u u^T) 2 D^2 u / (|v| |D u|^2)
        u = pp.u[r]
        grad[r, 2 * m + r * l:2 * m + (r + 1) * l] = (np.eye(l) - np.outer(u, u)) @ (2.0 * d ** 2 * u) / (
            pp.norm[r] * n2[r])
    if mod.slope:
        log_wr = np.log(2 * np.pi * pp.f / mod.w_c)
        level = level * np.exp(pp.beta * log_wr)
        grad[:, mod.slope_index] = log_wr if abs(pp.beta) < MAX_SLOPE else 0.0
        # d (beta log f_r) / d p_f = beta f0 zeta0 / f_r
        grad[np.arange(m), np.arange(m)] += pp.beta * mod.ref[0] * mod.ref[1] / pp.f
    return level, grad
