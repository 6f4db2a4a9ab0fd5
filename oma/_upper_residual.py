"""The compliance of modes above the analysed band: what the records show beyond the model's modes.

A mode well above the band (a spindle or tool mode at 700 Hz seen by a tracker sampled at 1 kHz)
cannot be identified from the records, but its static compliance ``u u^T / k`` is in every
line of the measured FRF below it: a flat, real offset (times ``1 / (1 - (f / f_r)^2)``, within
2 % up to 0.14 of its frequency). A model of the band's modes alone misses it: at the band's top
the measured compliance is mostly that offset, the model's static compliance is short by it, and
lobes from the model miss those modes altogether.

:func:`upper_residual` holds the reported model's modes and estimates that offset from the H1
estimate, per measured entry, as the inverse-variance weighted mean of ``Re(H - G_modes)`` over
the analysed band (the upper residual term of a modal fit, Ewins, Modal Testing, 2nd ed. 2000;
the random error of ``H`` from Bendat & Piersol, Random Data, 2010). Its standard error comes
from the scatter of the lines about it (a sandwich, which also holds when the H1 error estimate
of few averages is off, or the held modes are), and neighbouring Welch lines are not
independent: the DFT lines of a windowed white segment correlate by
``rho_k = sum_n w_n^2 exp(-2 pi i k n / N) / sum_n w_n^2``, the H1 errors of lines ``k`` apart by
``|rho_k|^2``, so the variance of a mean over many lines is ``sum_k |rho_k|^2 =
N sum w^4 / (sum w^2)^2`` (Parseval) times that of independent lines: 1.94 for the Hann window
(measured on simulated records: 1.84). On 40 simulated 20 s records of a structure with a known
flat compliance the estimates scattered by 1.0-1.13 of their standard errors.
:mod:`oma.identify` reports a compliance that is there beyond noise and large enough to matter
(:data:`RESIDUAL_SIGMAS`, :data:`RESIDUAL_SHARE`), keeps it in the model and does not trust the
model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal as sps

from ._arrays import readonly as _ro
from .timefit import resolved_band_hz

__all__ = ["RESIDUAL_SIGMAS", "RESIDUAL_SHARE", "UpperResidual", "upper_residual", "line_correlation_factor"]

AXES = ("X", "Y", "Z")

#: An axis's upper residual compliance is present when its estimate exceeds this many standard
#: errors (one-sided: the compliance of modes above the band is positive). On 20 s tracker records
#: of the example cell without modes above the band, 36 estimates (12 seeds, 3 axes) scattered
#: with a standard deviation of 0.99 standard errors, the largest 2.0; with the example's tool
#: modes (720 / 735 Hz, 4.0 / 4.4 MN/m) they were 47-62 (20 s) and 8-13 (1.1 s) standard errors,
#: each within 1 standard error of the modes' ``sum u_a^2 / k`` (times their amplification at the
#: band's top).
RESIDUAL_SIGMAS = 5.0
#: ... and this share of the static compliance along the axis (modes and residual). A smaller one
#: changes a static deflection by less than this, and the modes it comes from are stiff enough for
#: their lowest chatter limit to lie far above the band's modes': the most negative real part of a
#: mode's receptance, ``-R / (4 zeta (1 + zeta))``, is for ``R`` at 5 % of the static compliance
#: and 2 % damping about an eighth of that of the band's modes at 5 % damping.
RESIDUAL_SHARE = 0.05


@dataclass(frozen=True)
class UpperResidual:
    """The flat compliance the records show beyond the model's modes (:func:`upper_residual`).

    Attributes
    ----------
    compliance_m_N : ndarray, shape (3, 3)
        Estimate per entry, m/N, symmetrised where both ``(a, b)`` and ``(b, a)`` are measured;
        NaN where not measured.
    standard_error_m_N : ndarray, shape (3, 3)
        Its standard error (neighbouring lines' correlation counted), m/N.
    present : ndarray of bool, shape (3,)
        Per axis: the direct entry exceeds :data:`RESIDUAL_SIGMAS` standard errors and
        :data:`RESIDUAL_SHARE` of the static compliance along the axis.
    static_share : ndarray, shape (3,)
        ``R_aa / (G_modes,aa(0) + R_aa)``: the share of the static compliance along the axis that
        the model's modes do not give.
    modes_share_at_top : ndarray, shape (3,)
        ``|G_modes,aa(f_top)| / |G_modes,aa(f_top) + R_aa|``: the share of the compliance at the
        band's top that the model's modes give.
    band_hz : (float, float)
        The band averaged over.
    """

    compliance_m_N: np.ndarray
    standard_error_m_N: np.ndarray
    present: np.ndarray
    static_share: np.ndarray
    modes_share_at_top: np.ndarray
    band_hz: tuple

    def __post_init__(self):
        for name in ("compliance_m_N", "standard_error_m_N", "static_share", "modes_share_at_top"):
            object.__setattr__(self, name, _ro(getattr(self, name)))
        object.__setattr__(self, "present", _ro(self.present, bool))

    def model_compliance(self) -> np.ndarray:
        """The residual compliance for the model, shape (3, 3), m/N: the entries between present
        axes, made positive semi-definite (zero when no axis is present)."""
        keep = np.outer(self.present, self.present)
        r = np.where(keep, np.nan_to_num(self.compliance_m_N), 0.0)
        ev, vec = np.linalg.eigh(0.5 * (r + r.T))
        return (vec * np.maximum(ev, 0.0)) @ vec.T

    def to_dict(self) -> dict[str, Any]:
        def plain(a):
            return [[float(v) if np.isfinite(v) else None for v in row] for row in a]

        return {"compliance_m_N": plain(self.compliance_m_N), "standard_error_m_N": plain(self.standard_error_m_N),
                "present": {a: bool(p) for a, p in zip(AXES, self.present)},
                "band_hz": [float(v) for v in self.band_hz]}

    def warning(self, sample_rate_hz: float, *, added: bool) -> str | None:
        """The warning naming the axes where the compliance is present; None when it is nowhere.
        ``added``: the compliance was put into the model (else the model had its own)."""
        if not np.any(self.present):
            return None
        lo, hi = self.band_hz
        parts = []
        for a in np.flatnonzero(self.present):
            r, se = self.compliance_m_N[a, a], self.standard_error_m_N[a, a]
            parts.append(f"{AXES[a]} {r:.2g} m/N (a spring of {1.0 / r:.2g} N/m; {r / se:.0f} standard errors), "
                         f"{100 * self.static_share[a]:.0f} % of the static compliance along {AXES[a]}, and the "
                         f"model's modes give only {100 * self.modes_share_at_top[a]:.0f} % of the compliance at "
                         f"{hi:.0f} Hz")
        kept = "kept as the model's residual compliance" if added else "in the model's residual compliance"
        return (f"the records show a compliance flat across the analysed band ({lo:.1f}-{hi:.0f} Hz) that the "
                "model's modes do not explain, the static compliance of modes above the band: " + "; ".join(parts)
                + f". It is {kept}, but those modes are not in the model: stability lobes and forced vibration "
                "from it miss their resonances (spindle and tool modes above "
                f"{resolved_band_hz(sample_rate_hz):.0f} Hz, which records sampled at {sample_rate_hz:g} Hz cannot "
                "resolve). Add them from a tool-tip tap test "
                "(tool_mode.yaml; --tool-model: in series, with this residual compliance taken out, since it is "
                "their static compliance), or record faster")


def line_correlation_factor(nperseg: int, window="hann") -> float:
    """Variance of a mean over neighbouring Welch lines relative to independent lines:
    ``nperseg sum w^4 / (sum w^2)^2`` (1.94 for Hann, 1 for a rectangular window)."""
    w = sps.get_window(window, int(nperseg))
    return float(w.size * np.sum(w ** 4) / np.sum(w ** 2) ** 2)


def upper_residual(model, est, weights, band_hz) -> UpperResidual:
    """The flat compliance of the H1 estimate ``est`` beyond the modes of ``model`` in ``band_hz``.

    Parameters
    ----------
    model : ModalModel
        The model whose modes are held (its own residual compliance is not used).
    est : FRFEstimate
        The H1 estimate (receptance, m/N) with its random error ``std_m_N``.
    weights : ndarray, shape (3, 3, n_freq)
        ``1 / std_m_N`` (0 where unknown or left out, e.g. at milling lines).
    band_hz : (float, float)
        The band averaged over (the modal fit's).

    Returns
    -------
    UpperResidual
    """
    f = est.freq_hz
    sel = (f >= band_hz[0]) & (f <= band_hz[1])
    modes = model.with_modes(residual_compliance_m_N=np.zeros((3, 3)))
    g = modes.receptance(f[sel])
    inflation = line_correlation_factor(est.table.meta.get("nperseg", est.spectra.nperseg))
    r = np.full((3, 3), np.nan)
    se = np.full((3, 3), np.nan)
    measured = est.table.measured
    for o, i in zip(*np.nonzero(measured)):
        w2 = 2.0 * np.asarray(weights[o, i, sel], dtype=float) ** 2  # Re(H) has sd std / sqrt(2)
        if not np.sum(w2) > 0:
            continue
        d = (est.receptance_m_N[o, i, sel] - g[o, i]).real
        r[o, i] = float(np.sum(w2 * d) / np.sum(w2))
        # from the scatter of the lines themselves (a sandwich): the random error of an H1
        # estimate of few averages is itself uncertain (it came out 20 % small on simulated
        # records), and the held modes' own errors add to it
        se[o, i] = float(np.sqrt(inflation * np.sum(w2 ** 2 * (d - r[o, i]) ** 2)) / np.sum(w2))
    both = measured & measured.T
    r = np.where(both, 0.5 * (r + r.T), r)
    se = np.where(both & ~np.eye(3, dtype=bool), 0.5 * np.hypot(se, se.T), se)
    diag, diag_se = np.diag(r), np.diag(se)
    static = np.diag(modes.static_compliance_m_N)
    top = np.diag(modes.receptance(band_hz[1])[:, :, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        static_share = diag / (static + diag)
        modes_share = np.abs(top) / np.abs(top + diag)
        present = (np.isfinite(diag) & (diag > RESIDUAL_SIGMAS * diag_se) & (static_share > RESIDUAL_SHARE))
    return UpperResidual(compliance_m_N=r, standard_error_m_N=se, present=present, static_share=static_share,
                         modes_share_at_top=modes_share, band_hz=(float(band_hz[0]), float(band_hz[1])))
