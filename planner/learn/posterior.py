"""The posterior over the tool-tip modes and the cutting coefficients, from test-cut outcomes.

Parameters (log-multipliers of the prior's values, so the prior is a zero-mean normal in them, a
log-normal in the physical values): ``frequency`` (every mode's natural frequency), ``stiffness``,
``damping``, ``Ktc``, ``Krc``. Each relative prior sd ``sigma`` (cli.md ``--prior-sd``) becomes the
log-sd ``sqrt(log(1 + sigma^2))`` (the log-normal with that coefficient of variation, median at
the prior's value).

Inference: sequential Monte Carlo with likelihood tempering (Del Moral, Doucet & Jasra, JRSS B 68,
2006; Chopin 2002): particles drawn from the prior are carried to the posterior through
``p(theta) L(theta)^beta``, ``beta`` rising from 0 to 1 in steps chosen so that the effective
sample size stays at half the particles, with systematic resampling and random-walk Metropolis
moves (covariance from the particles, scale adapted to the acceptance) at each step. Why this:
the forward model is cheap once tabulated (:mod:`planner.learn.tables`: one interpolation per
sample and cut), the posterior over the frequency is multimodal whenever cuts sit on lobe flanks
(a cut that chattered is explained by the lobe moving left or right), which a Laplace
approximation misses and a single MCMC chain mixes between badly, and plain importance sampling
from the prior collapses with 30 informative cuts. Tempering keeps every mode populated. Checked
against a brute-force grid posterior in ``tests/test_learn_posterior.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from oma.cutting import CuttingCoefficients
from oma.modal import ModalModel

from ..workers import progress_bar
from .likelihood import Likelihood
from .tables import LimitTable, scaled_coefficients, scaled_model

__all__ = ["PARAMETERS", "PriorSD", "SMCResult", "smc", "Posterior", "log_sd"]

PARAMETERS = ("frequency", "stiffness", "damping", "Ktc", "Krc")


def log_sd(relative_sd: float) -> float:
    """Log-space sd of a log-normal whose coefficient of variation is ``relative_sd``."""
    return float(np.sqrt(np.log1p(float(relative_sd) ** 2)))


@dataclass(frozen=True)
class PriorSD:
    """Relative prior standard deviations per group (cli.md defaults). 0 fixes a group."""

    frequency: float = 0.10
    stiffness: float = 0.30
    damping: float = 0.50
    coefficients: float = 0.25

    def log_sds(self) -> np.ndarray:
        """Log-sd of each of :data:`PARAMETERS`, shape (5,)."""
        return np.array([log_sd(self.frequency), log_sd(self.stiffness), log_sd(self.damping),
                         log_sd(self.coefficients), log_sd(self.coefficients)])


@dataclass(frozen=True)
class SMCResult:
    """Particles of a tempered SMC run (equally weighted after the last resampling)."""

    samples: np.ndarray  # (N, d) free coordinates
    log_likelihood: np.ndarray  # (N,)
    log_evidence: float
    betas: tuple[float, ...]
    acceptance: tuple[float, ...]


def _systematic(rng, logw: np.ndarray) -> np.ndarray:
    w = np.exp(logw - logw.max())
    c = np.cumsum(w / w.sum())
    n = logw.size
    return np.minimum(np.searchsorted(c, (rng.random() + np.arange(n)) / n), n - 1)


def _ess(logw: np.ndarray) -> float:
    w = np.exp(logw - logw.max())
    return float(w.sum() ** 2 / (w**2).sum())


def smc(log_likelihood: Callable[[np.ndarray], np.ndarray], prior_sd, *, rng: np.random.Generator,
        n_particles: int = 2000, ess_fraction: float = 0.5, moves: int = 6, final_moves: int = 20,
        support: Callable[[np.ndarray], np.ndarray] | None = None, desc: str | None = None) -> SMCResult:
    """Tempered SMC from a zero-mean normal prior ``N(0, diag(prior_sd^2))`` to the posterior.

    Parameters
    ----------
    log_likelihood : callable
        ``(N, d) -> (N,)``, vectorised; ``-inf`` where a parameter set is impossible.
    prior_sd : array_like, shape (d,)
    rng : numpy.random.Generator
    n_particles, ess_fraction, moves, final_moves
        Particles; target ESS per tempering step; Metropolis moves per step and at ``beta = 1``.
    support : callable, optional
        ``(N, d) -> (N,) bool``: the region the posterior is restricted to (the log-likelihood
        is ``-inf`` outside it). The particles then start from the prior restricted to it (by
        rejection), so that the first tempering step does not collapse them; the evidence is
        relative to that restricted prior.
    desc : str, optional
        The label of a progress bar over ``beta`` from 0 to 1, with the tempering stage
        (:func:`planner.workers.progress_bar`: on a terminal, for runs over a few seconds); None:
        none. The samples do not depend on it.
    """
    sd = np.asarray(prior_sd, dtype=float)
    d = sd.size
    x = rng.standard_normal((n_particles, d)) * sd
    if support is not None:
        inside = support(x)
        for _ in range(50):
            if inside.all():
                break
            fresh = rng.standard_normal((n_particles, d)) * sd
            keep = fresh[support(fresh)]
            need = np.flatnonzero(~inside)[:keep.shape[0]]
            x[need], inside[need] = keep[:need.size], True
        if not inside.any():
            raise RuntimeError("no prior sample falls inside the sampler's support (the forward model's range)")
    ll = log_likelihood(x)
    beta, log_z = 0.0, 0.0
    betas, acc_hist = [0.0], []
    scale = 2.38 / np.sqrt(max(d, 1))
    # the bar follows beta, redrawn after every move (miniters=0); nothing of it touches the particles or rng
    bar = progress_bar(1.0, desc, unit="beta", miniters=0,
                       bar_format="{desc}: {percentage:3.0f}%|{bar}| beta {n:.3f}{postfix} [{elapsed}]")
    while True:
        done = beta >= 1.0
        if not done:
            lo, hi = beta, 1.0
            if _ess((hi - beta) * ll) < ess_fraction * n_particles:
                for _ in range(60):
                    mid = 0.5 * (lo + hi)
                    if _ess((mid - beta) * ll) < ess_fraction * n_particles:
                        hi = mid
                    else:
                        lo = mid
                new = max(lo, beta + 1e-6)
            else:
                new = 1.0
            logw = (new - beta) * ll
            log_z += float(np.log(np.mean(np.exp(logw - logw.max()))) + logw.max())
            idx = _systematic(rng, logw)
            x, ll, beta = x[idx], ll[idx], new
            betas.append(beta)
            bar.update(beta - betas[-2])
        n_moves = 0 if d == 0 else final_moves if beta >= 1.0 else moves  # d = 0: nothing to move
        for move in range(n_moves):
            bar.set_postfix_str(f"stage {len(betas) - 1}{' (final)' if beta >= 1.0 else ''}, move {move + 1}/{n_moves}",
                                refresh=False)
            bar.update(0)
            cov = np.cov(x.T).reshape(d, d) + np.diag((1e-6 * sd) ** 2)
            chol = np.linalg.cholesky(cov)
            prop = x + scale * rng.standard_normal(x.shape) @ chol.T
            ll_p = log_likelihood(prop)
            log_a = beta * (ll_p - ll) - 0.5 * np.sum((prop / sd) ** 2 - (x / sd) ** 2, axis=1)
            ok = np.log(rng.random(n_particles)) < log_a
            x[ok], ll[ok] = prop[ok], ll_p[ok]
            rate = float(ok.mean())
            acc_hist.append(rate)
            scale *= 1.25 if rate > 0.35 else (0.7 if rate < 0.15 else 1.0)
        if beta >= 1.0:
            break
    bar.close()
    return SMCResult(samples=x, log_likelihood=ll, log_evidence=log_z, betas=tuple(betas),
                     acceptance=tuple(acc_hist))


@dataclass(frozen=True)
class Posterior:
    """Posterior samples of the five log-multipliers and what they mean.

    Attributes
    ----------
    reference : ModalModel
        The prior model (the samples multiply its frequencies, stiffnesses, damping ratios).
    coefficients : CuttingCoefficients
        The prior cutting coefficients.
    prior_log_sd : ndarray, shape (5,)
        Log-sd per parameter of :data:`PARAMETERS` (0: fixed).
    samples : ndarray, shape (n_samples, 5)
        Log-multipliers, equally weighted.
    log_posterior : ndarray, shape (n_samples,)
        Unnormalised log posterior of each sample (for the MAP); may be empty when read from file.
    likelihood : Likelihood
    method : str
        The stability method the samples were learned with (``sdm``, ``zoa``, ``auto``): whoever
        uses them computes limits the same way.
    mislabel_samples : ndarray, shape (n_samples,)
        The mislabel rate of each sample (learned with the rest, :mod:`.likelihood`); may be
        empty when read from file (predictions do not use it).
    mode_spread : ndarray, shape (3,)
        Several modes with a ``mode_correlation`` below one (``learn``): the log-sd of each
        mode's own deviation from the shared frequency, stiffness and damping factors, which the
        cuts cannot teach and ``learn`` integrates out (zeros: the modes move together).
    """

    reference: ModalModel
    coefficients: CuttingCoefficients
    prior_log_sd: np.ndarray
    samples: np.ndarray
    log_posterior: np.ndarray = field(default_factory=lambda: np.zeros(0))
    likelihood: Likelihood = Likelihood()
    method: str = "sdm"
    mislabel_samples: np.ndarray = field(default_factory=lambda: np.zeros(0))
    mode_spread: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def map_index(self) -> int:
        if self.log_posterior.size != self.samples.shape[0]:
            return int(np.argmin(np.sum((self.samples - np.median(self.samples, axis=0)) ** 2, axis=1)))
        return int(np.argmax(self.log_posterior))

    def model_at(self, u) -> tuple[ModalModel, CuttingCoefficients]:
        """The modal model and coefficients of one sample ``u`` (5 log-multipliers)."""
        u = np.asarray(u, dtype=float)
        model = scaled_model(self.reference, log_f=u[0], log_k=u[1], log_zeta=u[2])
        return model, scaled_coefficients(self.coefficients, log_kt=u[3], log_kr=u[4])

    def map_model(self) -> tuple[ModalModel, CuttingCoefficients]:
        return self.model_at(self.samples[self.map_index])

    def log_limits(self, table: LimitTable, *, samples=None) -> np.ndarray:
        """``log`` limit depth of every sample at every cut of ``table``, (n_samples, n_cuts)."""
        u = self.samples if samples is None else np.asarray(samples)
        return table.log_limit(u[:, 0], u[:, 1], u[:, 2], u[:, 3], u[:, 4])

    def probability_stable(self, table: LimitTable, axial_depth_m) -> np.ndarray:
        """Posterior probability that each cut of ``table`` at ``axial_depth_m`` is stable."""
        ratio = np.log(np.asarray(axial_depth_m, dtype=float))[None, :] - self.log_limits(table)
        return np.mean(1.0 - self.likelihood.p_chatter(ratio), axis=0)

    def parameters(self) -> dict:
        """Posterior mean and sd of each physical parameter, with the prior's value and sd.

        Per mode ``r``: ``natural_frequency_hz[r]``, ``stiffness_N_m[r]``, ``damping_ratio[r]``;
        then ``Ktc_N_m2``, ``Krc_N_m2``, and ``mislabel_rate`` when the samples carry it (its
        ``prior`` is the prior's mean). Also ``shift_in_prior_sd`` (posterior mean of the
        log-multiplier over its prior sd) and ``sd_ratio`` (posterior over prior log-sd).
        """
        out = {}
        ref = self.reference
        groups = [("natural_frequency_hz", ref.natural_frequency_hz, 0), ("stiffness_N_m", ref.stiffness_N_m, 1),
                  ("damping_ratio", ref.damping_ratio, 2)]
        for name, values, i in groups:
            for r, v in enumerate(values):
                out[f"{name}[{r}]"] = self._summary(float(v), i, mode=r)
        out["Ktc_N_m2"] = self._summary(self.coefficients.Ktc_N_m2, 3)
        out["Krc_N_m2"] = self._summary(self.coefficients.Krc_N_m2, 4)
        if self.mislabel_samples.size:
            m0, s0 = self.likelihood.mislabel_prior()
            e = self.mislabel_samples
            out["mislabel_rate"] = {"mean": float(e.mean()), "sd": float(e.std()), "prior": m0, "prior_sd": s0,
                                    "fixed": not self.likelihood.learns_mislabel,
                                    "shift_in_prior_sd": float((e.mean() - m0) / s0) if s0 > 0 else 0.0,
                                    "sd_ratio": float(e.std() / s0) if s0 > 0 else 0.0}
        return out

    def _summary(self, prior_value: float, i: int, mode: int = 0) -> dict:
        u = self.samples[:, i]
        sd0 = float(self.prior_log_sd[i])
        spread = float(self.mode_spread[i]) if i < 3 and self.reference.n_modes > 1 else 0.0
        if spread > 0:  # the mode's own deviation, not learned: its prior (fixed draws per mode)
            u = u + spread * np.random.default_rng([i, mode]).standard_normal(u.size)
            sd0 = float(np.hypot(sd0, spread))
        phys = prior_value * np.exp(u)
        cv0 = float(np.sqrt(np.expm1(sd0**2)))
        return {"mean": float(phys.mean()), "sd": float(phys.std()), "prior": float(prior_value),
                "prior_sd": float(prior_value * np.exp(sd0**2 / 2) * cv0), "fixed": sd0 == 0,
                "shift_in_prior_sd": float(u.mean() / sd0) if sd0 > 0 else 0.0,
                "sd_ratio": float(u.std() / sd0) if sd0 > 0 else 0.0}

    def cause(self) -> str:
        """The parameter group whose posterior moved most against its prior sd; ``"none"`` when
        every group was held fixed (a prior sd of 0: nothing could move)."""
        sd0 = self.prior_log_sd
        free = sd0 > 0
        if not free.any():
            return "none"
        shift = np.where(free, np.abs(self.samples.mean(axis=0)) / np.where(free, sd0, 1.0), -1.0)
        return PARAMETERS[int(np.argmax(shift))]

    def unpinned(self, *, threshold: float = 0.8) -> list[str]:
        """Groups whose posterior log-sd is still above ``threshold`` of the prior's."""
        sd0 = self.prior_log_sd
        return [PARAMETERS[i] for i in range(sd0.size)
                if sd0[i] > 0 and self.samples[:, i].std() > threshold * sd0[i]]

    def thinned(self, n: int, *, rng: np.random.Generator | None = None) -> "Posterior":
        """At most ``n`` samples (a random subset), MAP kept first."""
        rng = np.random.default_rng(0) if rng is None else rng
        m = self.samples.shape[0]
        rest = np.delete(np.arange(m), self.map_index)
        if m > n:
            rest = rng.choice(rest, n - 1, replace=False)
        keep = np.concatenate([[self.map_index], rest])
        lp = self.log_posterior[keep] if self.log_posterior.size == m else np.zeros(0)
        eps = self.mislabel_samples[keep] if self.mislabel_samples.size == m else np.zeros(0)
        from dataclasses import replace
        return replace(self, samples=self.samples[keep], log_posterior=lp, mislabel_samples=eps)
