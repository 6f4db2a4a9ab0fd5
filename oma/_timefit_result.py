"""Result of the time-domain fit (:class:`TimeFit`) and its assembly: misfit, the block-sandwich
standard errors of the least-squares poles, and the result of a modal-form likelihood fit.

Private module: :class:`TimeFit` and :class:`NoModeFound` are imported from :mod:`oma.timefit`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._arrays import readonly as _ro
from ._linalg import orthonormal_basis
from .modal import ModalModel
from .quantised import MIN_BLOCKS, block_labels, sandwich_se

__all__ = ["TimeFit", "NoModeFound"]


class NoModeFound(ValueError):
    """The records support no mode (nothing but rounding noise and forced response)."""


@dataclass(frozen=True)
class TimeFit:
    """Result of :func:`fit_time_domain`.

    Attributes
    ----------
    model : ModalModel
    residues : ndarray, shape (n_modes, 3, 3)
        Residue matrices ``A_r`` of the modes, m/N s^-2 (rows outputs, columns inputs): the free
        least-squares residues of the mode's pole, or ``phi_r phi_r^T`` in the modal form.
    residual_rms_m : ndarray, shape (3,)
        RMS of the displacement residual per output, m (NaN where not measured).
    fit_error : ndarray, shape (3,)
        Relative misfit of the dynamic response per output: ``sqrt((||y - x_fit||^2 - N q^2/12) /
        (||y_dyn||^2 - N q^2/12))``, the rounding noise ``q^2/12`` of quantised displacement taken
        out of both (plain ``||y - x_fit|| / ||y_dyn||`` otherwise).
    noise_scale_m : ndarray, shape (3,)
        Scale ``s`` of the Gaussian error inside the rounding, per output, m (NaN when the
        displacement was not quantised and least squares was used).
    quantised : bool
        Whether the quantised-output likelihood was used.
    dropped_modes_hz, split_modes_hz : tuple
        Modes removed, and modes split in two, by the information criterion.
    above_band_hz, below_band_hz : tuple
        Modes the fit pinned at the top or the bottom of the band the records resolve
        (``band_hz``): they stand for response the modes in the band cannot follow (of modes above
        it, which the records cannot identify; slow drift, edge artefacts). They stay in the fit
        (so that the modes in the band do not take up that response) and are left out of
        ``model``.
    band_hz : (float, float)
        The band the records resolve, Hz: from :data:`oma.timefit.MIN_CYCLES` cycles in the
        longest record up to :func:`oma.timefit.resolved_band_hz`.
    success : bool
    message : str
    frequency_se_hz, damping_se : ndarray, shape (n_modes,)
        Standard errors of the model's natural frequencies and damping ratios from a block
        sandwich (the residuals' own correlation counted) of the modal-form likelihood
        (:func:`oma.quantised._block_sandwich`) or of the least squares
        (:func:`_ls_block_sandwich`); NaN where not available (the free-residue likelihood of
        rounded data with different input and output axes, or fewer than
        :data:`oma.quantised.MIN_BLOCKS` blocks of data).
    n_blocks : int
        Blocks behind those standard errors (their intervals use ``n_blocks - 1`` degrees of
        freedom).
    residual : ndarray, shape (3, n_samples_total) or None
        Measured minus fitted output per sample, the records one after another (units of the
        fitted quantity; NaN rows for outputs not measured).
    """

    model: ModalModel
    residues: np.ndarray
    residual_rms_m: np.ndarray
    fit_error: np.ndarray
    noise_scale_m: np.ndarray
    quantised: bool = False
    dropped_modes_hz: tuple = ()
    split_modes_hz: tuple = ()
    above_band_hz: tuple = ()
    below_band_hz: tuple = ()
    band_hz: tuple = (0.0, np.inf)
    success: bool = True
    message: str = ""
    frequency_se_hz: np.ndarray | None = None
    damping_se: np.ndarray | None = None
    n_blocks: int = 0
    residual: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        for name in ("frequency_se_hz", "damping_se"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(self.model.n_modes, np.nan))
        for name in ("residues", "residual_rms_m", "fit_error", "noise_scale_m", "frequency_se_hz", "damping_se"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        if self.residual is not None:
            object.__setattr__(self, "residual", _ro(self.residual))


def _ls_block_sandwich(prob, fn, zeta, beta, xd, resid, *, step=1e-6, n_used=None):
    """Block-sandwich standard errors of ``(log fn, log zeta)`` of the least-squares fit.

    The poles solve ``sum_o w_o^2 d_o^T r_o = 0`` with ``d_o`` the derivative of output ``o``'s
    prediction projected off the linear columns (variable projection) and ``w_o`` the fit's output
    weights; their influence is ``S^-1 sum_o w_o^2 d_o^T r_o`` with ``S = sum_o w_o^2 d_o^T d_o``,
    and the scores summed over blocks (:func:`oma.quantised.block_labels`) give the sandwich, as
    for the likelihood (:func:`oma.quantised._block_sandwich`), with the white-residual standard
    error ``sigma_o^2 = rss_o / (N - K)`` as a floor. Returns the standard errors (2 n_modes,) and
    the number of blocks (NaN errors below :data:`oma.quantised.MIN_BLOCKS`). ``n_used``: the
    samples fitted (rows of ``xd`` left out of the fit are zero), all rows by default.
    """
    n_m = fn.size
    _, starts = block_labels(prob.records, prob.fs, fn, zeta)
    g_count = starts.size
    nan = np.full(2 * n_m, np.nan)
    if g_count < MIN_BLOCKS or n_m == 0:
        return nan, g_count
    n_tot, k = xd.shape
    q_x = orthonormal_basis(xd)
    w2 = prob.out_weight ** 2
    d = np.zeros((beta.shape[0], n_tot, 2 * n_m))
    # only the columns that depend on the poles are differenced (the nuisance columns, most of the
    # design at shop rates, would difference to zero)
    x_dyn, nuisance = prob.full_design(fn, zeta, nuisance=False)
    beta_dyn = beta[:, ~nuisance]
    for j in range(2 * n_m):
        f1, z1 = fn.copy(), zeta.copy()
        if j < n_m:
            f1[j] *= np.exp(step)
        else:
            z1[j - n_m] *= np.exp(step)
        dx = (prob.full_design(f1, z1, nuisance=False)[0] - x_dyn) / step
        d[:, :, j] = beta_dyn @ dx.T
    d -= np.einsum("nk,okj->onj", q_x, np.einsum("nk,onj->okj", q_x, d))  # projected off the linear columns
    s_mat = np.einsum("o,oni,onj->ij", w2, d, d)
    scores = np.add.reduceat(np.einsum("o,onj,on->nj", w2, d, resid), starts, axis=0)
    sigma2 = np.sum(resid ** 2, axis=1) / max((n_tot if n_used is None else n_used) - k, 1)
    try:
        s_inv = np.linalg.inv(s_mat)
    except np.linalg.LinAlgError:
        return nan, g_count
    model = s_inv @ np.einsum("o,oni,onj->ij", w2 ** 2 * sigma2, d, d) @ s_inv
    return sandwich_se(s_inv, scores, model), g_count


def _full_residual(res, outputs):
    """Residual rows of the fitted outputs placed in a (3, n) array, NaN elsewhere."""
    out = np.full((3, res.shape[1]), np.nan)
    out[outputs] = res
    return out


def _misfit(y_all, pred, nuis_part, recs, outputs, quantised):
    """RMS residual and relative misfit of the dynamic response per output (see :class:`TimeFit`).

    What the rounding alone explains (``q^2 / 12`` per sample of quantised displacement) is not a
    misfit of the model and is taken out of both the residual and the dynamic response.
    """
    q_var = sum(rec["y"].shape[1] * (rec["step"] or 0.0) ** 2 / 12.0 for rec in recs) if quantised else 0.0
    rms = np.full(3, np.nan)
    ferr = np.full(3, np.nan)
    for k, o in enumerate(outputs):
        dyn_meas = y_all[k] - nuis_part[k]
        num = float(np.sum((y_all[k] - pred[k]) ** 2))
        den = float(np.sum((dyn_meas - dyn_meas.mean()) ** 2))
        rms[o] = np.sqrt(num / y_all.shape[1])
        excess = max(num - q_var, 0.0)
        ferr[o] = np.sqrt(excess / max(den - q_var, 1e-300)) if den > 0 else np.nan
    return rms, ferr


#: A mode within this relative distance of an end of the resolved band is pinned there (the
#: refinements stop at the end itself; a mode that converged inside sits well away from it)
AT_BAND_EDGE = 0.005


def _band_edges(fn, visible, band_hz):
    """Visible modes pinned at the top and at the bottom of the band (frequencies), and the mask
    of all pinned modes."""
    top = fn >= (1.0 - AT_BAND_EDGE) * band_hz[1]
    bottom = fn <= (1.0 + AT_BAND_EDGE) * band_hz[0]
    return (tuple(float(v) for v in fn[visible & top]), tuple(float(v) for v in fn[visible & bottom]),
            top | bottom)


def _time_fit_from_rank_one(r1, recs, inputs, outputs, dropped, split_hz, source, message,
                            band_hz=(0.0, np.inf)) -> TimeFit:
    """The :class:`TimeFit` of a modal-form likelihood fit (:func:`oma.quantised.modal_form_ml`)."""
    y_all = np.concatenate([rec["y_raw"] for rec in recs], axis=1)
    rms, ferr = _misfit(y_all, r1["pred"], r1["nuis_part"], recs, outputs, True)
    fn, zeta = r1["fn"], r1["zeta"]
    phi = np.zeros((fn.size, 3))
    phi[:, inputs] = r1["phi"]
    norm = np.linalg.norm(phi, axis=1)
    ok = norm > 0
    k = (2 * np.pi * fn) ** 2 / np.where(ok, norm, 1.0) ** 2
    u = phi / np.where(ok, norm, 1.0)[:, None]
    u = u * np.sign(u[np.arange(fn.size), np.argmax(np.abs(u), axis=1)])[:, None]
    # a mode whose resonant peak is below 1 % of the largest on every axis carries no measurable
    # response (a pole the fit parked far from the data): dropped
    u2 = u**2 / (k * zeta)[:, None]
    visible = ok & np.any(u2 >= 0.01 * np.max(u2[ok], axis=0, keepdims=True), axis=1)
    dropped = list(dropped) + [float(f) for f in fn[~visible]]
    above, below, edge = _band_edges(fn, visible, band_hz)
    visible = visible & ~edge
    order = np.argsort(fn[visible])
    sel = np.flatnonzero(visible)[order]
    if sel.size == 0:
        raise NoModeFound("the time-domain fit left no mode with a measurable response")
    model = ModalModel(natural_frequency_hz=fn[sel], damping_ratio=zeta[sel], stiffness_N_m=k[sel],
                       directions=u[sel], source=source)
    residues = np.einsum("mi,mj->mij", phi[sel], phi[sel])
    sigma = np.full(3, np.nan)
    sigma[outputs] = r1["sigma"]
    # standard errors of log fn, log zeta -> of fn, zeta (to first order)
    log_se, n_blocks = r1["uncertainty"]()
    se_f = fn[sel] * log_se[: fn.size][sel]
    se_z = zeta[sel] * log_se[fn.size:][sel]
    return TimeFit(model=model, residues=residues, residual_rms_m=rms, fit_error=ferr, noise_scale_m=sigma,
                   quantised=True, dropped_modes_hz=tuple(dropped), split_modes_hz=tuple(split_hz),
                   above_band_hz=above, below_band_hz=below, band_hz=tuple(band_hz),
                   residual=_full_residual(y_all - r1["pred"], outputs), success=bool(r1["converged"]),
                   message=message, frequency_se_hz=se_f, damping_se=se_z, n_blocks=int(n_blocks))
