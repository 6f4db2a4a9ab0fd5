"""The cutting coefficients re-fitted on the fit halves: the baseline every other cause must beat.

Coefficients from a database or another tool or material batch are commonly 10-30 % off
(DOMAIN.md, ``cutting_coefficients``): the force scales, its direction turns (``Krc / Ktc``), and
the stability limit moves in proportion, with no new dynamics. Left in the nominal model, such an
error is the largest disagreement of the force part, and every force-side cause (runout, a size
effect, a sensor resonance) explains part of it and takes the blame. So the diagnosis fits the six
coefficients of the linear-plus-edge model (formats.md, "Force model") first, on the force
harmonics of the fit halves, and measures every other cause against the re-fitted model.

The rigid-tool force is linear in the six coefficients, so its harmonics are a sum of six basis
arrays (:func:`~planner.diagnosis.forcemodel.analytic_harmonics` with one unit coefficient each);
the fit is a weighted least squares over them and one spindle angle per record
(:func:`~planner.diagnosis.forcefits._fit_force`), the vibration feedback of the nominal simulation
kept as a correction (a fraction of a percent on a robot). Standard errors come from the
Jacobian of the whitened residuals, scaled by the reduced chi-square (so a misfit of shape, say a
helix a few degrees off, widens them instead of hiding).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from oma.cutting import CuttingCoefficients

from .compare import Parts
from .forcemodel import analytic_harmonics

__all__ = ["CoefficientFit", "fit_coefficients", "FIELDS"]

#: The six coefficients, in the order of the fit.
FIELDS = ("Ktc_N_m2", "Krc_N_m2", "Kac_N_m2", "Kte_N_m", "Kre_N_m", "Kae_N_m")


@dataclass(frozen=True)
class CoefficientFit:
    """Re-fitted coefficients, their standard errors and the predictions they give.

    Attributes
    ----------
    nominal, fitted : CuttingCoefficients
    standard_error : dict
        Per field, same units.
    parameters : dict
        Relative changes of Ktc, Krc, Kac and the ratio Krc / Ktc (the force direction) with
        their standard errors (``*_sigma``), and the fitted coefficients.
    success : bool
    message : str
    """

    nominal: CuttingCoefficients
    fitted: CuttingCoefficients
    standard_error: dict
    parameters: dict
    success: bool
    message: str

    def to_dict(self) -> dict:
        return {"nominal": {f: float(getattr(self.nominal, f)) for f in FIELDS},
                "fitted": {f: float(getattr(self.fitted, f)) for f in FIELDS},
                "standard_error": dict(self.standard_error),
                "relative_change": {k: float(v) for k, v in self.parameters.items() if k.endswith("_change")},
                "success": bool(self.success)}


def _units(view, nominal: CuttingCoefficients) -> np.ndarray:
    ktc = max(abs(nominal.Ktc_N_m2), 1.0)
    fz = max(float(view.cut.feed_per_tooth_m), 1e-6)
    return np.array([ktc, ktc, ktc, ktc * fz, ktc * fz, ktc * fz])


#: Edge coefficients re-fitted: ``"scale"`` (one factor, their ratios kept) or ``"free"`` (three).
EDGE_MODE = "scale"


def n_parameters() -> int:
    """Parameters of the coefficient fit: Ktc, Krc, Kac and the edge terms (:data:`EDGE_MODE`)."""
    return 6 if EDGE_MODE == "free" else 4


def expand(x, nominal: CuttingCoefficients, units) -> np.ndarray:
    """The six coefficients (in ``units``) of the fit's four parameters: Ktc, Krc, Kac (in units)
    and one scale of the three edge coefficients (their ratios kept: a size effect would take
    the freedom of three independent edge terms, since ``h^(1-p)`` is close to ``a + b h`` over
    one feed's chips)."""
    if len(x) == 6:
        return np.asarray(x, dtype=float)
    edges = np.array([getattr(nominal, f) for f in FIELDS[3:]]) / units[3:]
    return np.concatenate([x[:3], x[3] * edges])


def coefficient_start(nominal: CuttingCoefficients, units) -> np.ndarray:
    cut = [max(getattr(nominal, f) / u, 1e-6) for f, u in zip(FIELDS[:3], units[:3])]
    if n_parameters() == 6:
        return np.array(cut + [max(getattr(nominal, f) / u, 1e-6) for f, u in zip(FIELDS[3:], units[3:])])
    return np.array(cut + [1.0])


def coefficient_bounds(x0):
    return np.zeros(len(x0)), np.maximum(5.0 * np.abs(x0), 5.0)


def standard_errors(res, n_par: int) -> np.ndarray:
    """Standard errors of the first ``n_par`` parameters of a whitened least-squares fit
    (``scipy.optimize.least_squares`` result), scaled by the reduced chi-square when above 1."""
    jac = res.jac
    dof = max(res.fun.size - jac.shape[1], 1)
    chi2 = 2.0 * float(res.cost) / dof
    cov = np.linalg.pinv(jac.T @ jac) * max(chi2, 1.0) / 2.0  # whitened real/imag parts: variance 1/2
    return np.sqrt(np.clip(np.diag(cov)[:n_par], 0.0, None))


def coefficient_basis(parts: Parts, units) -> list:
    """Harmonics of each unit coefficient, per view: list of arrays (6, 3, H + 1)."""
    out = []
    for v in parts.views:
        b = []
        for k in range(6):
            vals = np.zeros(6)
            vals[k] = units[k]
            b.append(analytic_harmonics(v.tool, v.cut, CuttingCoefficients(*vals), v.n_harm, spindle_hz=v.spindle_hz,
                                        sample_rate_hz=v.sample_rate_hz))
        out.append(np.array(b))
    return out


def fit_coefficients(parts: Parts) -> CoefficientFit:
    """Fit the six cutting coefficients (shared by all records) on the fit halves' force harmonics.

    Parameters
    ----------
    parts : Parts
        Built with the nominal coefficients (all views must share them).

    Returns
    -------
    CoefficientFit
    """
    from .forcefits import _fit_force

    nominal = parts.views[0].coefficients
    units = _units(parts.views[0], nominal)
    basis = coefficient_basis(parts, units)
    x0 = coefficient_start(nominal, units)

    def predict(x, i):
        return np.tensordot(expand(x, nominal, units), basis[i], axes=1) + parts.force.correction[i]

    lower, upper = coefficient_bounds(x0)
    x, res = _fit_force(parts, predict, x0, lower, upper)
    n_par = len(x0)
    sig_x = standard_errors(res, n_par)
    vals = expand(x, nominal, units) * units
    if n_par == 6:
        sig = sig_x * units
    else:
        sig = np.concatenate([sig_x[:3] * units[:3], np.abs([getattr(nominal, f) for f in FIELDS[3:]]) * sig_x[3]])
    fitted = CuttingCoefficients(*[float(v) for v in vals])
    se = {f: float(s) for f, s in zip(FIELDS, sig)}

    def rel(num, den):
        return num / den - 1.0 if den else 0.0

    ratio0 = nominal.Krc_N_m2 / nominal.Ktc_N_m2
    ratio = fitted.Krc_N_m2 / fitted.Ktc_N_m2 if fitted.Ktc_N_m2 > 0 else float("nan")
    ratio_sig = abs(ratio) * math.hypot(se["Krc_N_m2"] / max(fitted.Krc_N_m2, 1e-30),
                                        se["Ktc_N_m2"] / max(fitted.Ktc_N_m2, 1e-30))
    params = {
        "Ktc_relative_change": rel(fitted.Ktc_N_m2, nominal.Ktc_N_m2),
        "Krc_relative_change": rel(fitted.Krc_N_m2, nominal.Krc_N_m2),
        "Kac_relative_change": rel(fitted.Kac_N_m2, nominal.Kac_N_m2),
        "ratio_relative_change": ratio / ratio0 - 1.0 if ratio0 else 0.0,
        "Ktc_relative_change_sigma": se["Ktc_N_m2"] / abs(nominal.Ktc_N_m2) if nominal.Ktc_N_m2 else float("nan"),
        "Krc_relative_change_sigma": se["Krc_N_m2"] / abs(nominal.Krc_N_m2) if nominal.Krc_N_m2 else float("nan"),
        "ratio_relative_change_sigma": ratio_sig / ratio0 if ratio0 else float("nan"),
        "edge_scale": float(x[3]) if n_par == 4 else float("nan"),
        "coefficients": {f: float(getattr(fitted, f)) for f in FIELDS},
        "reduced_chi_square": 2.0 * float(res.cost) / max(res.fun.size - res.jac.shape[1], 1),
    }
    return CoefficientFit(nominal, fitted, se, params, bool(res.success), str(res.message))
