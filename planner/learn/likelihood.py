"""The likelihood of test-cut outcomes given a predicted limit depth.

For a cut of depth ``a`` and a parameter set whose limit at the cut's speed and engagement is
``b``, the chance that the cut really chatters is a soft step in the log-depth ratio,

    p_chatter = Phi_logistic(log(a / b) / s),       s = ``boundary_scale`` (default 0.03),

the few per cent by which a limit computed from nominal parameters is uncertain even when the
parameters are right (runout, feed variation, the operator's threshold). The forward model's own
error (the tables' interpolation, measured by ``learn`` against direct SDM limits at posterior
samples) adds in quadrature: per cut while learning, ``s_j = sqrt(s^2 + e_j^2)``, and its typical
value ``model_error`` in predictions. A mark is wrong with
probability ``eps`` (the mislabel rate), whatever the cut did:

    P(mark 'chatter') = eps + (1 - 2 eps) p_chatter,    P(mark 'stable') = 1 - P(mark 'chatter').

By default the rate is fixed at ``mislabel`` (0.05), and ``learn`` warns when more marks look
wrong than that rate explains. With ``mislabel_sd > 0`` it is learned with the rest: shops differ
(operators disagree on a third of the cuts in some, a tool wears in a series), and a rate fixed too
low makes a posterior over-confident when the marks are noisier. Its prior is then logit-normal on
``(0, 0.5)``: ``eps = 0.5 expit(logit(2 mislabel) + x)``, ``x ~ N(0, mislabel_sd^2)``, so
``mislabel`` is the prior median and ``mislabel_sd = 1.2`` puts 90 % of the prior between 0.7 % and
22 %. Measured (docs/learn.md): with 5 % of the marks flipped, learning it costs boundary accuracy
(20 seeds, 40 cuts: median error 13.4 % against 10.9 %); with 20 % flipped it keeps the posterior
honest (the truth inside its 90 % band at 89 % of the speeds against 77 %).

With ``mislabel_average`` (and ``mislabel_sd > 0``) the rate's prior is a spike and a slab: with
probability 1/2 it is exactly ``mislabel``, otherwise logit-normal as above around a median
``noisy_mislabel`` (0.15: 90 % of the slab between 2.8 % and 38 %, the marks of a shop whose
operators disagree on a third of the cuts, as the issue warns). Until session 11 the slab's
median was ``mislabel`` itself: a slab centred on the spike is nearly the same model, so the
evidence could not tell them apart on clean marks (the learned model's weight 0.35-0.64 on the
benchmark's 5 % flips), and on a third of the marks flipped it held the learned rate at 15 %
where 22 % were wrong (docs/learn.md, session 12). ``learn`` samples
both models and mixes their posteriors in proportion to their evidence (the marginal likelihood
that its tempered SMC estimates): Bayesian model averaging (Hoeting et al., Stat. Sci. 14, 1999).
Marks as clean as assumed then keep most of the fixed rate's sharpness (the fixed model has the
larger evidence: it spends no prior mass on noisy marks), and noisy marks move the weight to the
learned rate, whose posterior is honest about them.

An ``uncertain`` mark says the cut was near the boundary (light marks, an operator not sure): its
likelihood is ``eps + (1 - 2 eps) exp(-(log(a/b))^2 / (2 s_u^2))`` with ``s_u`` =
``uncertain_scale`` (0.15: within about 15 % of the limit), and it enters tempered, raised to the
power ``uncertain_weight`` (0.3), so it is weak evidence, never ignored. A label detected from a
record enters raised to its detection confidence (0..1). This is the Bayesian-stability
likelihood of Karandikar et al. (J. Manuf. Sci. Eng. 136, 2014) with a label-noise term, as
Cornelius et al. (Procedia Manuf. 53, 2021) use for reverse identification.

A detected mark is not a mark with a different weight: a detector is wrong in its own way. Near
the limit the chatter of a cut with the tool leaving the cut saturates at an amplitude below the
forced tooth lines, so ``diagnose``'s detection calls it stable up to well above the limit, and
just below the limit the nearly undamped chatter pole rings under the background force and is
sometimes called chatter. Its boundary is lagged and wider:

    P(detected 'chatter') = eps + (1 - 2 eps) Phi_logistic((log(a / b) - lag) / s_d),

``lag`` = ``detection_lag`` (0.22: half of the chattering cuts are detected at 1.25x the limit)
and ``s_d`` = ``detection_scale`` (0.11), the forward model's error in quadrature. Measured
(``benchmarks/bench_detection.py``, docs/learn.md) on 300 cuts recorded for 2 and for 4 s and 300
others for 1 s: the fitted lag is 0.16-0.28 and the scale 0.07-0.17 whatever the record length, so
it is the detector's threshold against a saturated amplitude, not growth time (a 4x finer
simulation step changes no outcome). ``detection_lag = 0``
with ``detection_scale = boundary_scale`` treats detected marks like marks (before session 9: the
posterior over-confident towards "stable", its 90 % band holding the truth at 69-74 % of the speeds).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.special import expit, log_expit

__all__ = ["Likelihood", "STABLE", "CHATTER", "UNCERTAIN", "LEARNED_MISLABEL_SD", "DETECTION_LAG",
           "DETECTION_SCALE"]

STABLE, CHATTER, UNCERTAIN = 0, 1, 2
#: The log-odds sd of a learned rate of wrong marks when none is given (90 % of the prior
#: between 0.7 % and 22 % around a median of 5 %).
LEARNED_MISLABEL_SD = 1.2
#: Log-depth lag and width of the boundary of outcomes detected from records (module notes).
DETECTION_LAG = 0.22
DETECTION_SCALE = 0.11


@dataclass(frozen=True)
class Likelihood:
    """Settings of the outcome likelihood (see the module notes)."""

    mislabel: float = 0.05
    boundary_scale: float = 0.03
    uncertain_scale: float = 0.15
    uncertain_weight: float = 0.3
    model_error: float = 0.0
    mislabel_sd: float = 0.0
    mislabel_average: bool = False
    noisy_mislabel: float = 0.15
    detection_lag: float = DETECTION_LAG
    detection_scale: float = DETECTION_SCALE

    def __post_init__(self):
        if not 0 <= self.mislabel < 0.5:
            raise ValueError(f"mislabel must be in [0, 0.5), found {self.mislabel}")
        if not 0 < self.noisy_mislabel < 0.5:
            raise ValueError(f"noisy_mislabel must be in (0, 0.5), found {self.noisy_mislabel}")
        if not (self.boundary_scale > 0 and self.uncertain_scale > 0 and self.detection_scale > 0):
            raise ValueError("boundary_scale, uncertain_scale and detection_scale must be > 0")
        if not 0 <= self.detection_lag < 1:
            raise ValueError(f"detection_lag must be in [0, 1), found {self.detection_lag}")
        if not self.model_error >= 0:
            raise ValueError(f"model_error must be >= 0, found {self.model_error}")
        if not self.mislabel_sd >= 0:
            raise ValueError(f"mislabel_sd must be >= 0, found {self.mislabel_sd}")

    @property
    def learns_mislabel(self) -> bool:
        """Whether the mislabel rate is a learned parameter (else fixed at ``mislabel``)."""
        return self.mislabel > 0 and self.mislabel_sd > 0

    @property
    def averages_mislabel(self) -> bool:
        """Whether the fixed and the learned rate are averaged by their evidence."""
        return self.mislabel_average and self.learns_mislabel

    def components(self) -> tuple["Likelihood", ...]:
        """The models of the rate that ``learn`` samples: this one, or (fixed, learned) when
        averaging (each with ``mislabel_average`` off; the learned one's median ``noisy_mislabel``)."""
        if not self.averages_mislabel:
            return (self,)
        return (replace(self, mislabel_sd=0.0, mislabel_average=False),
                replace(self, mislabel=self.noisy_mislabel, mislabel_average=False))

    def mislabel_rate(self, x=0.0) -> np.ndarray:
        """The mislabel rate at the prior's standardised-free coordinate ``x`` (its log-odds shift):
        ``0.5 expit(logit(2 mislabel) + x)``; ``mislabel`` at ``x = 0``."""
        if self.mislabel == 0:
            return np.zeros(np.shape(x))
        return 0.5 * expit(np.log(2 * self.mislabel / (1 - 2 * self.mislabel)) + np.asarray(x, dtype=float))

    def mislabel_prior(self) -> tuple[float, float]:
        """Mean and sd of the mislabel rate under its prior (Gauss-Hermite, 40 nodes; with
        ``mislabel_average``, half of the prior's mass at ``mislabel`` itself and the other half
        around ``noisy_mislabel``)."""
        if not self.learns_mislabel:
            return float(self.mislabel), 0.0
        z, w = np.polynomial.hermite_e.hermegauss(40)
        slab = self.components()[-1]
        r = slab.mislabel_rate(self.mislabel_sd * z)
        w = w / w.sum()
        if self.averages_mislabel:
            r, w = np.r_[r, self.mislabel], np.r_[0.5 * w, 0.5]
        m = float(np.sum(w * r))
        return m, float(np.sqrt(np.sum(w * (r - m) ** 2)))

    def scale(self, model_error=None, *, width=None):
        """Width of the soft boundary (or of ``width``, e.g. ``uncertain_scale``): it and the
        forward model's error (per cut when given, else ``model_error``) in quadrature."""
        e = self.model_error if model_error is None else np.asarray(model_error, dtype=float)
        return np.hypot(self.boundary_scale if width is None else width, e)

    def p_chatter(self, log_ratio, *, model_error=None) -> np.ndarray:
        """Chance the cut chatters, ``log_ratio = log(a / b)``."""
        return expit(np.asarray(log_ratio) / self.scale(model_error))

    def mark_logit(self, log_ratio, detected=None, *, model_error=None) -> np.ndarray:
        """Log-odds that a cut's outcome reads 'chatter' before any wrong mark: ``log(a/b) / s``
        for a mark, ``(log(a/b) - lag) / s_d`` where ``detected`` (n_cuts,) says the outcome was
        detected from a record."""
        r = np.asarray(log_ratio, dtype=float)
        x = r / self.scale(model_error)
        if detected is None or not np.any(detected):
            return x
        xd = (r - self.detection_lag) / self.scale(model_error, width=self.detection_scale)
        return np.where(np.asarray(detected, dtype=bool), xd, x)

    def p_mark_chatter(self, log_ratio, detected=None, *, model_error=None) -> np.ndarray:
        """Chance the outcome reads 'chatter' (a mark: the cut chatters; detected: it is detected)."""
        return expit(self.mark_logit(log_ratio, detected, model_error=model_error))

    def log_terms(self, log_ratio, outcome, weight, *, model_error=None, mislabel=None, detected=None) -> np.ndarray:
        """Weighted log-likelihood of each cut, shape of ``log_ratio`` (``(..., n_cuts)``).

        ``outcome`` (n_cuts,) holds STABLE, CHATTER or UNCERTAIN; ``weight`` (n_cuts,) the label
        weights (the tempering of uncertain marks is applied here, on top); ``model_error``
        (n_cuts,) the forward model's error at each cut (default ``self.model_error``);
        ``mislabel`` the mislabel rate, broadcast against ``log_ratio`` (e.g. one per sample,
        shape ``(n_samples, 1)``; default ``self.mislabel``); ``detected`` (n_cuts,) which
        outcomes were detected from records (their lagged boundary, module notes).
        """
        x = self.mark_logit(log_ratio, detected, model_error=model_error)
        eps = np.asarray(self.mislabel if mislabel is None else mislabel, dtype=float)
        with np.errstate(divide="ignore"):
            log_eps = np.log(eps)
        # log(eps + (1 - 2 eps) sigma(x)) and log(eps + (1 - 2 eps) sigma(-x)), stably
        log_ch = np.logaddexp(log_eps, np.log1p(-2 * eps) + log_expit(x))
        log_st = np.logaddexp(log_eps, np.log1p(-2 * eps) + log_expit(-x))
        z = np.asarray(log_ratio, dtype=float) / self.scale(model_error, width=self.uncertain_scale)
        log_un = np.logaddexp(log_eps, np.log1p(-2 * eps) - 0.5 * z * z)
        outcome = np.asarray(outcome)
        w = np.asarray(weight, dtype=float) * np.where(outcome == UNCERTAIN, self.uncertain_weight, 1.0)
        terms = np.where(outcome == CHATTER, log_ch, np.where(outcome == STABLE, log_st, log_un))
        return w * terms

    def to_dict(self) -> dict:
        return {"mislabel": self.mislabel, "boundary_scale": self.boundary_scale,
                "uncertain_scale": self.uncertain_scale, "uncertain_weight": self.uncertain_weight,
                "model_error": self.model_error, "mislabel_sd": self.mislabel_sd,
                "mislabel_average": self.mislabel_average, "noisy_mislabel": self.noisy_mislabel,
                "detection_lag": self.detection_lag,
                "detection_scale": self.detection_scale}
