"""Samples no model of the structure explains (spikes, edge artefacts): found from the time-domain
fit's residual and left out of it.

Why. A record can hold samples that no modal model driven by the measured force explains: a spike
or dropout of a sensor, or the ringing that differentiating, integrating or filtering a
non-periodic record with the FFT leaves at both of its ends (its periodic extension jumps there).
An acceleration made so from a 10 s displacement record (audit, session 15) had its first samples
at 20-200 times the signal's rms, decaying over some 20 samples; the least-squares fit weighs every
sample alike, and on that record it put two 17.5 Hz modes with 30 % damping where the record has
9.6 and 10.5 Hz at 5 % (fit error 97 %). Fitted without its first and last 10 samples the same
record gives the true modes to 0.1 %. The fit is right on the same motion simulated directly
(:func:`oma.synthetic.synthetic_record` with ``output='acceleration'``): the record was the problem.

How. A sample is an outlier when its residual exceeds :data:`OUTLIER_SD` robust standard
deviations (1.4826 times the median absolute deviation, which a few outliers do not inflate) on
some output. Outliers are acted on only while they steer the fit: while their residual energy is
at least :data:`ENERGY_SHARE` of the measured response's on some output (alone a 10 % fit error;
the response without its milling lines, its energy from its robust standard deviation).
Then the largest of them, as many as that takes, are left out (with :data:`MARGIN` samples on
either side) and the fit is repeated: their rows drop out of the least squares while the measured
force still runs the model through them (a sensor's spike does not reset the structure). Again
while the refit exposes more (ringing decays from the ends: once the worst samples are out, the
fit improves and the next ones stand out), at most :data:`MAX_ROUNDS` times. Small outliers that
carry no weight (a simulator's resampling error at ten robust sd but a tenth of the signal's rms)
are left in.

Private module (:func:`oma.identify.identify`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["OUTLIER_SD", "ENERGY_SHARE", "MAX_ROUNDS", "MAX_TRUSTED_SHARE", "Artefacts", "outlier_samples",
           "fit_without_artefacts"]

#: Robust standard deviations of the residual beyond which a sample is an outlier (a Gaussian
#: residual passes it once in 10^15 samples).
OUTLIER_SD = 8.0
#: Residual energy of the outliers, as a share of the measured signal's energy on an output, from
#: which they steer the fit and are left out (1 %: alone a 10 % fit error).
ENERGY_SHARE = 0.01
#: Samples left out on either side of an outlier.
MARGIN = 2
#: Refits at most.
MAX_ROUNDS = 4
#: Largest share of a record's samples left out of a model that can still be trusted.
MAX_TRUSTED_SHARE = 0.02


@dataclass(frozen=True)
class Artefacts:
    """Samples left out of the time-domain fit, per record.

    Attributes
    ----------
    excluded : tuple of ndarray of bool
        One per record, ``(n_samples,)``: True where left out.
    peak_sd : float
        Largest outlier, in robust standard deviations of the residual.
    resolved : bool
        Whether the last fit's outliers no longer steer it (else :data:`MAX_ROUNDS` was reached).
    """

    excluded: tuple
    peak_sd: float
    resolved: bool

    def share(self, record: int) -> float:
        """Share of the record's samples left out."""
        return float(np.mean(self.excluded[record]))

    def where(self, record: int, sample_rate_hz: float) -> str:
        """Where the record's left-out samples lie, in words (times in its cut window; stretches
        less than 1 % of the record apart shown as one)."""
        ex = self.excluded[record]
        edges = np.flatnonzero(np.diff(np.r_[0, ex.astype(np.int8), 0]))
        gap = max(int(0.01 * ex.size), 1)
        spans: list[list[int]] = []
        for a, b in zip(edges[::2], edges[1::2]):
            if spans and a - spans[-1][1] <= gap:
                spans[-1][1] = b
            else:
                spans.append([a, b])
        runs = [f"{a / sample_rate_hz:.3f}-{b / sample_rate_hz:.3f}" for a, b in spans]
        return f"within t = {', '.join(runs[:4])}{' ...' if len(runs) > 4 else ''} s of the cut window"


def outlier_samples(residual, included=None) -> np.ndarray:
    """Normalised residual: per sample the largest ``|r - median| / robust sd`` over the outputs.

    Parameters
    ----------
    residual : array_like, shape (n_out, n)
        NaN rows (outputs not fitted) are ignored.
    included : ndarray of bool, shape (n,), optional
        Samples the robust statistics are taken over (all by default).

    Returns
    -------
    ndarray, shape (n,)
        A sample beyond :data:`OUTLIER_SD` is an outlier.
    """
    r = np.asarray(residual, dtype=float)
    r = r[~np.all(np.isnan(r), axis=1)]
    base = r if included is None else r[:, included]
    med = np.median(base, axis=1, keepdims=True)
    mad = 1.4826 * np.median(np.abs(base - med), axis=1, keepdims=True)
    scale = np.where(mad > 0, mad, np.maximum(np.std(base, axis=1, keepdims=True), np.finfo(float).tiny))
    return np.max(np.abs(r - med) / scale, axis=0)


def _to_leave_out(residual, signal_energy, included):
    """Samples to leave out this round (boolean over the stacked samples), and the largest outlier (sd).

    The outliers (beyond :data:`OUTLIER_SD`), largest share of the signal's energy first, until
    those left carry less than :data:`ENERGY_SHARE` of it on every output; none when they already
    do.
    """
    z = outlier_samples(residual, included)
    fitted = ~np.all(np.isnan(residual), axis=1)
    share = np.where(included, residual[fitted] ** 2, 0.0) / signal_energy[fitted, None]  # (n_out, n)
    cand = np.flatnonzero((z > OUTLIER_SD) & included)
    out = np.zeros(z.size, dtype=bool)
    if cand.size == 0:
        return out, 0.0
    left = share[:, cand].sum(axis=1)
    if np.max(left) < ENERGY_SHARE:
        return out, float(np.max(z[cand]))
    order = cand[np.argsort(-np.max(share[:, cand], axis=0))]
    # leave out the largest until what is left carries less than the share on every output
    after = left[:, None] - np.cumsum(share[:, order], axis=1)
    k = int(np.argmax(np.max(after, axis=0) < ENERGY_SHARE)) + 1
    out[order[:k]] = True
    return out, float(np.max(z[cand]))


def _robust_energy(signals, harmonics, rows):
    """Energy of the measured response per output (rows), the milling lines, mean and trend taken
    out: ``n sigma^2`` with the robust standard deviation (1.4826 MAD), which the artefacts
    themselves do not inflate (edge spikes can outweigh a whole record's response)."""
    from .harmonics import fit_harmonic_signal

    energy = np.zeros(len(rows))
    for s, h in zip(signals, harmonics):
        y = (s.motion if s.motion is not None else s.displacement_m)[rows]
        hz = h.freq_hz if h is not None else np.zeros(0)
        dyn = y - fit_harmonic_signal(y, s.sample_rate_hz, hz, trend=True)
        mad = 1.4826 * np.median(np.abs(dyn - np.median(dyn, axis=1, keepdims=True)), axis=1)
        energy += dyn.shape[1] * mad**2
    return energy


def fit_without_artefacts(signals, harmonics, first_fit, refit):
    """Refit a time-domain fit without the samples it cannot explain (module notes).

    Parameters
    ----------
    signals : sequence of PreparedSignals
        The records of ``first_fit``.
    harmonics : sequence of Harmonics or None
        Their milling lines (taken out of the response whose energy the outliers are measured by).
    first_fit : TimeFit
        The fit of all samples (its ``residual`` stacks the records in order).
    refit : callable
        ``refit(keep, previous) -> TimeFit`` fits the records with only the samples ``keep`` (one
        boolean array per record); ``previous`` is the last refit, None for the first (fitted the
        way ``first_fit`` was: that one may have been led astray).

    Returns
    -------
    fit : TimeFit
        ``first_fit`` itself when nothing was left out.
    artefacts : Artefacts or None
        None when nothing was left out.
    """
    sigs = list(signals)
    sizes = [s.n_samples for s in sigs]
    bounds = np.cumsum([0] + sizes)
    fitted_rows = ~np.all(np.isnan(first_fit.residual), axis=1) if first_fit.residual is not None else None
    if fitted_rows is None or not np.any(fitted_rows):
        return first_fit, None
    rows = np.flatnonzero(fitted_rows)
    energy = np.full(3, np.nan)
    energy[rows] = np.maximum(_robust_energy(sigs, harmonics, rows), np.finfo(float).tiny)

    excluded = np.zeros(bounds[-1], dtype=bool)
    fit, previous, peak, resolved = first_fit, None, 0.0, False
    for round_ in range(MAX_ROUNDS + 1):
        leave, z_max = _to_leave_out(np.asarray(fit.residual), energy, ~excluded)
        if not np.any(leave):
            if round_ == 0:
                return first_fit, None
            resolved = True
            break
        if round_ == MAX_ROUNDS:
            break
        peak = max(peak, z_max)
        hit = np.flatnonzero(leave)
        for i in range(len(sigs)):  # the margin stays inside each record
            mine = hit[(hit >= bounds[i]) & (hit < bounds[i + 1])]
            for d in range(-MARGIN, MARGIN + 1):
                excluded[np.clip(mine + d, bounds[i], bounds[i + 1] - 1)] = True
        keep = [~excluded[bounds[i]:bounds[i + 1]] for i in range(len(sigs))]
        fit = refit(keep, previous)
        previous = fit
    per_record = tuple(excluded[bounds[i]:bounds[i + 1]] for i in range(len(sigs)))
    return fit, Artefacts(excluded=per_record, peak_sd=peak, resolved=resolved)
