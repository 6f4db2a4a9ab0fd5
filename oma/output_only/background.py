"""A second scale for output-only modes: the level of the background force.

The tooth-passing lines scale a mode only as well as they force it. A mode the lines hardly
move (on the paper's cell the Z mode at 10.0 Hz beside the X mode at 10.5 Hz: the axial force is
a sixth of the feed force, so a degree of error in the pair's directions puts as much X response
into Z at the lines as the Z mode itself gives) cannot be scaled by them. But every mode is also
driven by the broadband background force, and its refined input level ``P_r = E|u_r . F|^2 /
k_r^2`` per Hz (:func:`oma.output_only.whittle._input_level`) is measured whatever the lines do.
For a mode the lines do scale, ``s_r = P_r k_r^2`` is the background force's power spectral
density along ``u_r``; if the background is as strong along an unscaled mode's direction, that
mode's stiffness is ``k_t = sqrt(s / P_t)``.

That "if" is an assumption, not a measurement: nothing in a record without force says how strong
the background is along a direction no scaled mode points in. The evidence for it: in the
paper's cell (Nguyen & Melkote 2020) the background force variance measured by the dynamometer
was 232, 278 and 251 N^2 along X, Y and Z (log standard deviation 0.09). The method allows for
anisotropy: ``log s`` along any direction is the common level plus a deviation of standard
deviation ``ANISOTROPY_LOG_SD`` (0.3, three times the paper's spread), or more when the scaled
modes' own levels disagree by more than their errors (a random-effects estimate of that spread,
DerSimonian & Laird, Control. Clin. Trials 7, 1986). The common level is their precision-weighted
mean. A mode scaled this way says so in a warning and leaves the model untrusted: the assumption
cannot be checked along its direction.

The cutting coefficients' error passes one for one into a mode scaled this way too: the scaled
modes' stiffnesses, and so the level ``s``, carry it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from .._arrays import readonly as _ro
from .scaling import StiffnessScaling

__all__ = ["BackgroundLevel", "background_level", "scale_by_background", "consistent_up_to_colour",
           "ANISOTROPY_LOG_SD"]

#: Prior standard deviation of the background force's log power spectral density between
#: directions: three times the spread of the paper's measured variances (232, 278, 251 N^2 along
#: X, Y, Z: log sd 0.09). Halved in the stiffness (``k ~ sqrt(s)``): 15 %.
ANISOTROPY_LOG_SD = 0.3


@dataclass(frozen=True)
class BackgroundLevel:
    """The background force's level from the modes the lines scale.

    Attributes
    ----------
    psd_N2_Hz : float
        Common power spectral density of the background force (two-sided, N^2/Hz; its variance
        as white noise at the sampling rate ``fs`` is ``psd * fs``).
    log_se : float
        Standard error of ``log psd`` (the scaled modes' level and stiffness errors; not the
        coefficients').
    anisotropy_log_sd : float
        Spread allowed between directions: ``ANISOTROPY_LOG_SD`` or the scaled modes' own,
        whichever is larger.
    reference : ndarray of int
        The modes it comes from.
    per_mode_psd_N2_Hz : ndarray, shape (n_modes,)
        ``P_r k_r^2`` of each reference mode (NaN for the others).
    per_mode_log_se : ndarray, shape (n_modes,)
    consistent : bool
        The reference modes' levels agree within their errors and the allowed spread (chi-square
        test at 1 %).
    source : str
        Where the levels come from: ``'resonances'`` (the refinement's, at each mode's resonance)
        or ``'mass lines'`` (:mod:`oma.output_only.mass_line`: the band outside the resonances).
    """

    psd_N2_Hz: float
    log_se: float
    anisotropy_log_sd: float
    reference: np.ndarray
    per_mode_psd_N2_Hz: np.ndarray
    per_mode_log_se: np.ndarray
    consistent: bool
    source: str = "resonances"

    def __post_init__(self):
        object.__setattr__(self, "reference", _ro(self.reference, int))
        for name in ("per_mode_psd_N2_Hz", "per_mode_log_se"):
            object.__setattr__(self, name, _ro(getattr(self, name)))

    def to_dict(self, sample_rate_hz: float) -> dict:
        """JSON: the level as PSD and as the variance of white noise at the record's rate."""
        fs = float(sample_rate_hz)
        return {
            "psd_N2_Hz": float(self.psd_N2_Hz), "white_variance_N2": float(self.psd_N2_Hz * fs),
            "log_standard_error": float(self.log_se), "anisotropy_log_sd": float(self.anisotropy_log_sd),
            "reference_modes": [int(k) for k in self.reference],
            "per_mode_white_variance_N2": [float(v * fs) if np.isfinite(v) else None for v in self.per_mode_psd_N2_Hz],
            "consistent": bool(self.consistent), "source": self.source,
        }


def background_level(scaling: StiffnessScaling, input_level, input_level_log_se, *,
                     anisotropy_log_sd: float = ANISOTROPY_LOG_SD, source: str = "resonances") -> BackgroundLevel | None:
    """The background force's level from the modes the lines scale well (module docstring).

    Parameters
    ----------
    scaling : StiffnessScaling
        The lines' scaling (:func:`oma.output_only.scaling.scale_modes`).
    input_level, input_level_log_se : array_like, shape (n_modes,)
        The modes' input levels ``P_r`` (m^2/Hz) and the standard errors of their logarithms
        (:class:`oma.output_only.modes.OutputOnlyModes`).
    anisotropy_log_sd : float
        Least spread of ``log psd`` between directions.
    source : str
        Where the levels come from (:attr:`BackgroundLevel.source`).

    Returns
    -------
    BackgroundLevel or None
        None when no mode is both scaled well by the lines and refined.
    """
    level = np.asarray(input_level, dtype=float)
    level_se = np.asarray(input_level_log_se, dtype=float)
    k = np.asarray(scaling.stiffness_N_m, dtype=float)
    k_se = np.asarray(scaling.statistical_relative_sd, dtype=float)
    ref = np.flatnonzero(~np.asarray(scaling.too_far) & np.isfinite(k) & (k > 0) & np.isfinite(level)
                         & (level > 0) & np.isfinite(level_se) & np.isfinite(k_se))
    if ref.size == 0:
        return None
    y = np.log(level[ref] * k[ref] ** 2)
    var = level_se[ref] ** 2 + (2.0 * k_se[ref]) ** 2
    w = 1.0 / var
    mean_fixed = np.sum(w * y) / np.sum(w)
    q = float(np.sum(w * (y - mean_fixed) ** 2))
    # the spread between directions beyond the errors (DerSimonian-Laird), at least the prior's
    denom = np.sum(w) - np.sum(w ** 2) / np.sum(w)
    tau2_data = max(0.0, (q - (ref.size - 1)) / denom) if ref.size > 1 and denom > 0 else 0.0
    tau = float(np.sqrt(max(tau2_data, anisotropy_log_sd ** 2)))
    wr = 1.0 / (var + tau ** 2)
    mean = float(np.sum(wr * y) / np.sum(wr))
    consistent = ref.size < 2 or float(np.sum((y - mean) ** 2 / (var + anisotropy_log_sd ** 2))) <= \
        float(stats.chi2.ppf(0.99, ref.size - 1))
    per_mode = np.full(level.size, np.nan)
    per_se = np.full(level.size, np.nan)
    per_mode[ref], per_se[ref] = np.exp(y), np.sqrt(var)
    return BackgroundLevel(psd_N2_Hz=float(np.exp(mean)), log_se=float(np.sqrt(1.0 / np.sum(wr))),
                           anisotropy_log_sd=tau, reference=ref, per_mode_psd_N2_Hz=per_mode,
                           per_mode_log_se=per_se, consistent=bool(consistent), source=source)


def consistent_up_to_colour(background: BackgroundLevel, freq_hz, *,
                            anisotropy_log_sd: float = ANISOTROPY_LOG_SD) -> bool:
    """Whether the reference modes' levels agree within their errors and the spread allowed once a
    power law in frequency is allowed too (weighted least squares of ``log psd`` on ``log f``; a
    chi-square test at 1 % on ``n - 2`` degrees of freedom). For levels each measured at its own
    mode's resonance, which differ by the background's colour (session 18: under a red background
    the levels of a right model at 12, 17 and 26 Hz were 400, 202 and 94 N^2); the mass lines'
    levels share their frequencies and take :attr:`BackgroundLevel.consistent`. Fewer than three
    reference modes: True (nothing to test)."""
    ref = background.reference
    if ref.size < 3:
        return True
    y = np.log(background.per_mode_psd_N2_Hz[ref])
    w = 1.0 / (background.per_mode_log_se[ref] ** 2 + anisotropy_log_sd ** 2)
    x = np.column_stack([np.ones(ref.size), np.log(np.asarray(freq_hz, dtype=float)[ref])])
    beta = np.linalg.solve(x.T @ (w[:, None] * x), x.T @ (w * y))
    return float(np.sum(w * (y - x @ beta) ** 2)) <= float(stats.chi2.ppf(0.99, ref.size - 2))


def scale_by_background(scaling: StiffnessScaling, background: BackgroundLevel, input_level, input_level_log_se,
                        *, level: float = 0.95) -> tuple[StiffnessScaling, np.ndarray]:
    """The modes the lines scale poorly (``too_far``), scaled by the background's level instead.

    For such a mode ``t`` with a refined input level: ``log k = (log s - log P_t) / 2`` with the
    variance ``(se_s^2 + tau^2 + se_P^2) / 4`` (``tau`` the spread allowed between directions). The
    lines' own estimate of that mode is not combined with it: a mode the lines force too weakly
    gets their response to the other modes through its direction's error, a bias and not noise
    (on the paper's cell the Z mode's line estimates were 26-362 % high in 4 of 10 records and
    not positive in 6; session 10). The coefficients' uncertainty is added as for every mode (it
    is in ``s`` one for one, through the scaled modes' stiffnesses).

    Returns
    -------
    StiffnessScaling
        With the new stiffnesses, statistical and total uncertainties and intervals of those
        modes (``too_far`` unchanged: it says what the lines could do).
    by_background : ndarray of bool, shape (n_modes,)
        The modes whose stiffness now comes from the background's level.
    """
    p = np.asarray(input_level, dtype=float)
    p_se = np.asarray(input_level_log_se, dtype=float)
    k = np.array(scaling.stiffness_N_m, dtype=float)
    stat = np.array(scaling.statistical_relative_sd, dtype=float)
    by_background = np.asarray(scaling.too_far) & np.isfinite(p) & (p > 0) & np.isfinite(p_se)
    by_background[background.reference] = False
    t = by_background
    k[t] = np.sqrt(background.psd_N2_Hz / p[t])
    stat[t] = 0.5 * np.sqrt(background.log_se ** 2 + background.anisotropy_log_sd ** 2 + p_se[t] ** 2)
    total = np.hypot(stat, scaling.coefficient_relative_sd)
    zq = stats.norm.ppf(0.5 + 0.5 * level)
    with np.errstate(over="ignore", invalid="ignore"):
        interval = np.column_stack([k * np.exp(-zq * total), k * np.exp(zq * total)])
    return replace(scaling, stiffness_N_m=k, statistical_relative_sd=stat, relative_sd=total,
                   interval_N_m=interval), by_background
