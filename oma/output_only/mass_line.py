"""A third scale for output-only modes: the mass lines of the background force's response.

Away from its resonance a mode still answers the broadband background force, along its
direction and in proportion to its flexibility: the acceleration per force is
``u_r u_r^T g_r(w) / m_r`` with ``g_r = -w^2 / (w_r^2 - w^2 + 2 i zeta_r w_r w)`` (1 far above the
mode: its mass line; ``-(w / w_r)^2`` far below: its stiffness line) and ``m_r = k_r / w_r^2``. With a
background force of the same power spectral density ``s(w)`` along every direction, the
response's spectral matrix outside the modes' resonances is

    S(w) = s(w) A(w) A(w)^H,    A(w) = sum_r u_r u_r^T g_r(w) / m_r,

known up to ``s(w)`` and the masses once the frequencies, damping and directions are. The modes
the tooth-passing lines scale give their masses, the channels along them give ``s(w)`` at each
frequency, and the channels along a mode the lines cannot scale (on the paper's cell the Z mode
beside X) give its mass, frequency by frequency against the same ``s(w)``.

Why this and not the mode's level at its resonance (:mod:`oma.output_only.background`): a mode's
resonance holds a narrowband response of a few Hz, about ``T * 2 zeta f`` independent
frequency bins (20 in a 20 s record at 10 Hz, 5 %), so its level is uncertain by about
``1/sqrt(20)``, 20 % in power and 10 % in stiffness, whatever the method (measured in session 18:
the level's stated log standard error 0.12-0.35 on 20 of the benchmark's records). The mass
lines span the band outside the resonances, some thousand bins in the same record, and the same
frequencies give the reference level: the background's colour cancels (the resonance level needs
the background white between the modes' frequencies: session 16 measured 23-39 % off for a
pink, red or blue one).

What it assumes, and the model says so (the mode is not trusted): the background force is as
strong along the mode's direction as along the scaled modes' at the same frequency (as the
background level does); no mode in the band is missing from the model (a missing mode's line
along the target inflates its flexibility); the accelerometers' own noise is far below the mass
lines (a flat noise floor cannot be told from a mass line, which is flat in acceleration too).

Accelerations, and velocities differentiated (on the audit generator's velocity records with
0-10 % sensor noise, Z with the true X and Y stiffnesses within 5.7 %). Not displacements: their
mass lines fall as ``f^-4``, under a tracker's rounding floor and the resonances' own leakage. A
floor fitted beside them traded with the Z mass line (Z 20 % and 51 % soft with a stated error
of 3 %); without a floor, clean displacements of the audit generator gave Z 20-37 % soft with the
fit's deviance ratio still about 1. On accelerations under white, pink, red and blue backgrounds
Z was within 4 %.

The fit is a Whittle maximum a posteriori over blocks of adjacent bins: ``log s`` piecewise linear
in log frequency (:data:`SUB_BANDS` pieces), ``log m_r`` of every mode but the first (the data fix
``s / m_r^2`` only: the levels), each mode's direction turned by small angles with its stated
angular error as the prior (the close pair's are tilted by 5-20 degrees in 20 s records; held
there, a first version's Z was up to 35 % off in 12 records, against 6 % with the true
directions). It returns each mode's level in the convention of the refinement's, and
:mod:`oma.output_only.background` scales with them as with the resonances' (the lines'
stiffnesses of the modes they scale, the spread allowed between directions).

The directions it turns carry that isotropy: under the simulator's background (232 / 278 N^2
along X / Y, the paper's spread) the lines solved with them gave oblique modes (30 and 45 degrees
in XY) 6-14 % soft in the median (session 19). :func:`mass_line_directions` fits the same band
with the background's level free to differ between channels (``s(f) A D A^H``, ``D`` diagonal,
:data:`CHANNEL_SCALE_SD`) and gives only directions (for modes along the channels ``D`` and the
masses trade, so its levels are not identified); the lines are solved again with those. Measured
(session 19, 20 records per case): the X stiffness beside Z 8.8-9.3 % -> 5.9-6.2 % at most on the
paper's cell, the extra-mode case 12.0 -> 11.3 % (two records over 10 %, one before); the oblique
structures' lowest modes as before (5.2 and 12.0 % at most), their third modes 12.2 % (was 32.0)
and 6.7 % (11.8); the close pair's Z direction 10.5 -> 6.1 degrees off in the mean over 8 records.

Standard errors of the levels: the larger of the inverse Hessian's and the sandwich's (blocks' scores; White
1982), as the refinement does (:func:`oma.output_only._ml_inference._information_se`).
The MAP is found by BFGS on the posterior's analytic gradient (session 22: with BFGS differencing
it, the two fits of one record of the extra case took 15 000 evaluations and 3.3 s of its 4.2 s;
now 1.7 s in all).

Measured (session 18, ``benchmarks/bench_oma_output_only.py``, 20 records per case): the Z
stiffness beside X 1.2-1.9 % median, 4.7-7.1 % max over the tooth, runout, on-mode and extra
cases (from the resonances: 6.5-7.5 %, 11.5-15.3 %).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np
from scipy import optimize, special

from .ml import LINE_GUARD_HZ, _band_bins, _spectra

__all__ = ["MassLineLevels", "mass_line_levels", "mass_line_directions", "CHANNEL_SCALE_SD", "CLEARANCE",
           "STIFFNESS_CLEARANCE", "SUB_BANDS", "BLOCK_BINS", "MIN_BLOCKS"]

#: Bins are used on a mode's mass-line side from ``f / f_r >= CLEARANCE`` (there ``|g_r|`` is within
#: 80 % of its asymptote 1 and a 0.5 % frequency error moves ``|g_r|^2`` by 1.6 %) ...
CLEARANCE = 1.5
#: ... and on its stiffness side up to ``f / f_r <= 1 / STIFFNESS_CLEARANCE``: there the mode's
#: response is at most a third of its mass line, but grows as ``(f / f_r)^2``, so its frequency and
#: mass weigh on every channel it points along (session 18, the ``extra`` case's 70 Hz mode at
#: 0.53-0.67 of its frequency left the fit 15-32 % off in Z with a clearance of 1.5 on both sides).
STIFFNESS_CLEARANCE = 2.0
#: Intervals of the background's log level, piecewise linear in log frequency (knots at the
#: blocks' quantiles).
SUB_BANDS = 4
#: Prior standard deviation of each channel's log background level against the first's in
#: :func:`mass_line_directions` (the paper's measured variances 232 / 278 / 251 N^2 differ by 0.18
#: in log at most; a generous prior that keeps the fit regular where the data do not fix it).
CHANNEL_SCALE_SD = 1.0
#: Adjacent bins averaged into one block (a Wishart of this many degrees of freedom).
BLOCK_BINS = 8
#: Fewer blocks than this: no mass-line scale.
MIN_BLOCKS = 20


@dataclass(frozen=True)
class MassLineLevels:
    """Each mode's input level from the mass lines (module docstring), in the convention of
    :attr:`oma.output_only.modes.OutputOnlyModes.input_level` (``E|u_r . F|^2 / k_r^2`` per Hz,
    two-sided, with ``F``'s level the geometric mean over the blocks), so that
    :func:`oma.output_only.background.background_level` and
    :func:`~oma.output_only.background.scale_by_background` use them as they use the resonances'.

    Attributes
    ----------
    input_level, input_level_log_se : ndarray, shape (n_modes,)
        The levels and the standard errors of their logarithms (the records' noise and the
        directions' errors).
    band_hz : (float, float)
        Lowest and highest bin used.
    n_bins : int
        Bins used.
    misfit : float
        The blocks' deviance over its expectation (:func:`_deviance_ratio`; about 1 where the
        model explains them).
    directions : ndarray, shape (n_modes, l)
        The directions as the fit turned them (unit; a mode held: as given). Diagnostic: they carry
        the isotropy assumption (module docstring); :func:`mass_line_directions` gives those the
        lines are solved with.
    """

    input_level: np.ndarray
    input_level_log_se: np.ndarray
    band_hz: tuple
    n_bins: int
    misfit: float
    directions: np.ndarray | None = None


def _clear_of_modes(freq, freq_hz):
    """The bins outside every mode's clearances (:data:`CLEARANCE`, :data:`STIFFNESS_CLEARANCE`)
    and on the mass-line side of some mode (below every mode the response is quasi-static, no mass
    line, and where a record's low end is filtered or drifts: session 18's displacement records
    had a tenth of the model's power at 4-5 Hz)."""
    ratio = freq[:, None] / np.asarray(freq_hz)[None, :]
    beside = np.any((ratio > 1.0 / STIFFNESS_CLEARANCE) & (ratio < CLEARANCE), axis=1)
    return ~beside & np.any(ratio >= CLEARANCE, axis=1)


def _blocks(f, x, n):
    """Adjacent bins (in frequency order) averaged ``n`` at a time: centre frequencies (the unit of
    ``f``) and sample spectral matrices (B, l, l); a remainder shorter than ``n`` is dropped."""
    order = np.argsort(f, kind="stable")
    f, x = f[order], x[order]
    nb = f.size // n
    f = f[:nb * n].reshape(nb, n)
    x = x[:nb * n].reshape(nb, n, -1)
    return f.mean(axis=1), np.einsum("bki,bkj->bij", x, x.conj()) / n


def _deviance_ratio(s, s_hat, n):
    """The blocks' Wishart deviance ``n (tr(S^-1 S_hat) - log det(S^-1 S_hat) - l)`` over its
    expectation under the model (``S_hat`` a complex Wishart of ``n`` degrees of freedom:
    ``E log det(S^-1 S_hat) = sum_i psi(n - i) - l log n``): about 1 where the model explains the
    blocks, above where a line, a mode or a floor it lacks shows."""
    l = s.shape[-1]
    m = np.linalg.solve(s, s_hat)
    tr = np.real(np.trace(m, axis1=1, axis2=2))
    logdet = np.real(np.linalg.slogdet(m)[1])
    expected = n * (l * np.log(n) - np.sum(special.digamma(n - np.arange(l))))
    return float(np.mean(n * (tr - logdet - l)) / expected)


def _tangent(u):
    """Two orthonormal vectors perpendicular to the unit ``u`` (l,), as columns (l, l - 1)."""
    q = np.linalg.qr(np.column_stack([u, np.eye(u.size)]))[0]
    return q[:, 1:u.size]


def _curvature(per_block, posterior, p, prior_prec, h: float = 1e-4):
    """The inverse Hessian of the negative log posterior at ``p`` and the sandwich ``H^-1 (sum_b g_b
    g_b^T + P) H^-1`` of the blocks' scores ``g_b`` (``P`` the priors' precision), by central
    differences of ``per_block`` (the blocks' negative log-likelihoods) and ``posterior`` (their sum
    with the priors'), both None where the model spectrum is not positive definite; None where a
    step leaves it."""
    n_p = p.size
    eye = np.eye(n_p) * h
    grads = np.empty((n_p, per_block(p).size))
    for i in range(n_p):
        up, dn = per_block(p + eye[i]), per_block(p - eye[i])
        if up is None or dn is None:
            return None
        grads[i] = (up - dn) / (2 * h)
    hess = np.empty((n_p, n_p))
    for i in range(n_p):
        for j in range(i, n_p):
            corners = [posterior(p + si * eye[i] + sj * eye[j]) for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1))]
            if any(c is None for c in corners):
                return None
            hess[i, j] = hess[j, i] = (corners[0] - corners[1] - corners[2] + corners[3]) / (4 * h * h)
    if not np.all(np.isfinite(hess)):
        return None
    cov = np.linalg.pinv(hess, rcond=1e-12, hermitian=True)
    return cov, cov @ (grads @ grads.T + np.diag(prior_prec)) @ cov


class _Fit(NamedTuple):
    """The mass lines' Whittle MAP at its optimum ``p`` (:func:`_fit`)."""

    p: np.ndarray
    per_block: Callable      # the blocks' negative log-likelihoods at a parameter vector (None: no fit)
    posterior: Callable      # their sum with the priors'
    prior_prec: np.ndarray
    spectrum: Callable       # the model's spectral matrices (B, l, l)
    directions: np.ndarray   # the turned unit directions at ``p`` (n, l)
    channel_scales: np.ndarray  # the background's level per channel, the first's 1 (all 1 without them)
    hat: np.ndarray          # the log level's basis over the blocks (B, n_s)
    n_s: int
    wr: np.ndarray           # the modes' angular frequencies
    w_bins: np.ndarray
    s_hat: np.ndarray        # the blocks' spectral matrices
    objective: Callable | None = None  # the negative log posterior and its analytic gradient (None: no fit)


def _fit(residuals, sample_rate_hz, freq_hz, damping, directions, direction_se_rad, derivative, lines_hz, band_hz,
         line_guard_hz, channel_scale_sd: float | None = None):
    """The mass lines' Whittle MAP (module docstring, :class:`_Fit`); None without modes, with too
    few blocks, or when the fit fails. ``channel_scale_sd``: the background's level may differ
    between channels, ``s(f) A D A^H`` with ``D`` diagonal (the first channel's 1), each other
    channel's log scale a parameter with this prior standard deviation (:func:`mass_line_directions`)."""
    if derivative not in (1, 2):
        raise ValueError(f"the mass lines need velocities or accelerations (derivative 1 or 2), not {derivative!r}")
    fs = float(sample_rate_hz)
    f_r = np.asarray(freq_hz, dtype=float)
    z_r = np.asarray(damping, dtype=float)
    u0 = np.asarray(directions, dtype=float)
    u0 = u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    n, l = u0.shape
    if n == 0:
        return None
    # accelerations (velocities differentiated), the bins clear of the modes and the lines
    ffts = [(freq[clear], x[:, clear] * (2j * np.pi * freq[clear]) ** (2 - derivative))
            for freq, x in _spectra(residuals, fs) for clear in [_clear_of_modes(freq, f_r)]]
    w_bins, x = _band_bins(ffts, band_hz[0], min(band_hz[1], 0.45 * fs), np.asarray(lines_hz, dtype=float),
                           line_guard_hz)
    if w_bins.size < MIN_BLOCKS * BLOCK_BINS:
        return None
    w, s_hat = _blocks(w_bins, x, BLOCK_BINS)
    fb = w / (2 * np.pi)
    wr = 2 * np.pi * f_r
    g = -w[:, None] ** 2 / (wr[None] ** 2 - w[:, None] ** 2 + 2j * z_r[None] * wr[None] * w[:, None])
    # log s: piecewise linear in log frequency between knots at the blocks' quantiles (a power-law
    # colour exactly; the knots where the blocks are)
    knots = np.unique(np.quantile(np.log(fb), np.linspace(0.0, 1.0, SUB_BANDS + 1)))
    hat = np.column_stack([np.interp(np.log(fb), knots, np.eye(knots.size)[j]) for j in range(knots.size)])
    n_s = knots.size
    se_dir = np.asarray(direction_se_rad, dtype=float)
    turn = (np.isfinite(se_dir) & (se_dir > 0)) if l > 1 else np.zeros(n, bool)
    tang = [_tangent(u0[r]) for r in range(n)]
    n_t = int(turn.sum()) * (l - 1)
    n_c = l - 1 if channel_scale_sd is not None else 0
    # parameters: log s at the knots, log(1/m) of modes 1.. (mode 0's is 0: the scale of s and
    # the masses is one degree of freedom the data do not fix), the turns, the channels' log scales
    p0_ = np.zeros(n_s + n - 1 + n_t + n_c)
    a_mat = np.einsum("ri,rj,br->bij", u0, u0, g)
    p_mod = np.real(np.einsum("bij,bij->b", a_mat, a_mat.conj()))
    p_obs = np.real(np.trace(s_hat, axis1=1, axis2=2))
    p0_[:n_s] = np.linalg.lstsq(hat, np.log(p_obs / p_mod), rcond=None)[0]
    prior_prec = np.zeros(p0_.size)
    prior_prec[n_s + n - 1:n_s + n - 1 + n_t] = np.repeat(1.0 / se_dir[turn] ** 2, l - 1)
    if n_c:
        prior_prec[n_s + n - 1 + n_t:] = 1.0 / channel_scale_sd ** 2

    def turned(p):
        d = p[n_s + n - 1:n_s + n - 1 + n_t].reshape(-1, l - 1)
        u = u0.copy()
        for j, r in enumerate(np.flatnonzero(turn)):
            v = u0[r] + tang[r] @ d[j]
            u[r] = v / np.linalg.norm(v)
        return u

    def parts(p):
        """``S = s M D M^H`` and its factors: the level ``s`` per block (B,), the channels' scales
        ``D`` (l,), the turned directions (n, l), ``g / m`` (B, n), ``M`` and ``S`` (B, l, l)."""
        s_b = np.exp(hat @ p[:n_s])
        scale_c = np.exp(np.concatenate([[0.0], p[n_s + n - 1 + n_t:]])) if n_c else np.ones(l)
        u = turned(p)
        gm = g * np.exp(np.concatenate([[0.0], p[n_s:n_s + n - 1]]))[None]
        m_b = np.einsum("ri,rj,br->bij", u, u, gm)
        return s_b, scale_c, u, gm, m_b, s_b[:, None, None] * ((m_b * scale_c) @ m_b.conj().transpose(0, 2, 1))

    def spectrum(p):
        return parts(p)[-1]

    def per_block(p):
        s = spectrum(p)
        sign, logdet = np.linalg.slogdet(s)
        if not (np.all(np.isfinite(p)) and np.all(np.real(sign) > 0) and np.all(np.isfinite(logdet))):
            return None
        return BLOCK_BINS * (logdet.real + np.real(np.trace(np.linalg.solve(s, s_hat), axis1=1, axis2=2)))

    def posterior(p):
        v = per_block(p)
        return None if v is None else float(v.sum() + 0.5 * np.sum(prior_prec * p ** 2))

    def posterior_and_gradient(p):
        """The negative log posterior and its gradient, analytic: with ``S = s M D M^H`` (``M = sum_r
        u_r u_r^T g_r / m_r``, ``D`` the channels' scales) and ``G = S^-1 - S^-1 S_hat S^-1``, a
        parameter's term is ``BLOCK_BINS sum_b Re tr(G dS)``; (value, gradient), or None where the
        model spectrum is not positive definite."""
        if not np.all(np.isfinite(p)):
            return None
        s_b, scale_c, u, gm, m_b, s = parts(p)
        try:
            chol = np.linalg.cholesky(s)
        except np.linalg.LinAlgError:
            return None
        logdet = 2.0 * np.sum(np.log(np.real(np.diagonal(chol, axis1=1, axis2=2))), axis=1)
        s_inv = np.linalg.inv(s)
        s_inv = 0.5 * (s_inv + s_inv.conj().transpose(0, 2, 1))
        sis = s_inv @ s_hat
        value = BLOCK_BINS * float(np.sum(logdet + np.real(np.trace(sis, axis1=1, axis2=2))))
        gmat = s_inv - sis @ s_inv                                        # G (B, l, l)
        grad = np.zeros(p.size)
        # log s at the knots: dS = hat_bj S
        grad[:n_s] = BLOCK_BINS * hat.T @ np.real(np.einsum("bij,bji->b", gmat, s))
        # W = D M^H G; a mode's term dM = (u dv^T + dv u^T) gm (dv = u for its log level)
        w_mat = scale_c[None, :, None] * (m_b.conj().transpose(0, 2, 1) @ gmat)
        uwu = np.einsum("ri,bij,rj->br", u, w_mat, u)
        grad[n_s:n_s + n - 1] = (2 * BLOCK_BINS * np.real(s_b[:, None] * uwu * gm).sum(axis=0))[1:]
        i = n_s + n - 1
        for r in np.flatnonzero(turn):
            v = u0[r] + tang[r] @ p[i:i + l - 1]
            du = (np.eye(l) - np.outer(u[r], u[r])) @ tang[r] / np.linalg.norm(v)      # (l, l - 1)
            t = np.einsum("i,bij,jk->bk", u[r], w_mat, du) + np.einsum("ik,bij,j->bk", du, w_mat, u[r])
            grad[i:i + l - 1] = 2 * BLOCK_BINS * np.real(s_b[:, None] * t * gm[:, r:r + 1]).sum(axis=0)
            i += l - 1
        if n_c:
            # dS / dc_k = s M D E_kk M^H: Re tr(G dS) = s D_kk Re (M^H G M)_kk
            mgm = np.real(np.einsum("bik,bij,bjk->bk", m_b.conj(), gmat, m_b))
            grad[i:] = (BLOCK_BINS * (s_b[:, None] * mgm).sum(axis=0) * scale_c)[1:]
        return value + 0.5 * float(np.sum(prior_prec * p ** 2)), grad + prior_prec * p

    def objective(p):
        out = posterior_and_gradient(p)
        return (1e300, np.zeros(p.size)) if out is None else out

    p = optimize.minimize(objective, p0_, jac=True, method="BFGS", options={"gtol": 1e-6, "maxiter": 500}).x
    if per_block(p) is None:
        return None
    scales = parts(p)[1]
    return _Fit(p, per_block, posterior, prior_prec, spectrum, turned(p), scales, hat, n_s, wr, w_bins, s_hat,
                posterior_and_gradient)


def mass_line_directions(residuals, sample_rate_hz: float, freq_hz, damping, directions, direction_se_rad, *,
                         derivative: int = 2, lines_hz=(), band_hz=(4.0, 100.0), line_guard_hz: float = LINE_GUARD_HZ,
                         channel_scale_sd: float = CHANNEL_SCALE_SD):
    """The modes' directions turned to explain the mass lines, the background's level free to differ
    between channels (``s(f) A D A^H``, ``D`` diagonal, each log scale with the prior standard
    deviation ``channel_scale_sd``): the directions without the isotropy the levels need. Arguments as
    :func:`mass_line_levels`. Returns ``(directions (n, l), channel_scales (l,))`` or None."""
    fit = _fit(residuals, sample_rate_hz, freq_hz, damping, directions, direction_se_rad, derivative, lines_hz,
               band_hz, line_guard_hz, channel_scale_sd=channel_scale_sd)
    if fit is None:
        return None
    return fit.directions, fit.channel_scales


def mass_line_levels(residuals, sample_rate_hz: float, freq_hz, damping, directions, direction_se_rad, *,
                     derivative: int = 2, lines_hz=(), band_hz=(4.0, 100.0),
                     line_guard_hz: float = LINE_GUARD_HZ) -> MassLineLevels | None:
    """Every mode's input level from the mass lines of the background's response (module docstring).

    Parameters
    ----------
    residuals : sequence of ndarray, shape (l, n_samples)
        Accelerations or velocities of one pose with the milling lines removed.
    freq_hz, damping : array_like, shape (n,)
        The modes (refined).
    directions : array_like, shape (n, l)
        Unit directions in the channels.
    direction_se_rad : array_like, shape (n,)
        Their angular standard errors (the prior of the turn; NaN or 0: held).
    derivative : {1, 2}
        Velocities (differentiated here) or accelerations.
    lines_hz : array_like
        Milling lines removed from the residuals; bins within ``line_guard_hz`` are left out.
    band_hz : (float, float)
        The band used (up to 0.45 ``fs``): every mode in it must be in the model (one missing shows
        in ``misfit``).

    Returns
    -------
    MassLineLevels or None
        None without modes, with fewer than :data:`MIN_BLOCKS` blocks, or when the fit fails.
    """
    fit = _fit(residuals, sample_rate_hz, freq_hz, damping, directions, direction_se_rad, derivative, lines_hz,
               band_hz, line_guard_hz)
    if fit is None:
        return None
    p, n_s, wr = fit.p, fit.n_s, fit.wr
    n = wr.size
    # the levels log(s / m_r^2) (log s averaged over the blocks) are what the data fix: linear
    # combinations of the parameters; their errors from the curvature and the blocks' scores
    comb = np.zeros((n, p.size))
    comb[:, :n_s] = fit.hat.mean(axis=0)
    comb[1:, n_s:n_s + n - 1] = 2.0 * np.eye(n - 1)
    curvature = _curvature(fit.per_block, fit.posterior, p, fit.prior_prec)
    if curvature is None:
        return None
    cov, sandwich = curvature
    var = np.fmax(np.einsum("ri,ij,rj->r", comb, cov, comb), np.einsum("ri,ij,rj->r", comb, sandwich, comb))
    # s / m_r^2 = s / (k_r / w_r^2)^2: the input level E|u . F|^2 / k_r^2 is that over w_r^4
    log_level = comb @ p - 4.0 * np.log(wr)
    misfit = _deviance_ratio(fit.spectrum(p), fit.s_hat, BLOCK_BINS)
    return MassLineLevels(input_level=np.exp(log_level), input_level_log_se=np.sqrt(np.maximum(var, 0.0)),
                          band_hz=(float(fit.w_bins.min() / (2 * np.pi)), float(fit.w_bins.max() / (2 * np.pi))),
                          n_bins=int(fit.w_bins.size), misfit=misfit, directions=fit.directions)
