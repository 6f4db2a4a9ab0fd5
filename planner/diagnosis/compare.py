"""Compare measured cuts with robomill's own prediction, in three parts that separate the causes.

Every record (its cut window) is split in two halves: a cause is fitted on the first half (the
*fit* part) and scored on the second (the *validation* part), so a gain is a prediction gain. The
errors below are those of the validation part unless said otherwise; with several records the
sums run over all of them.

(a) Force model -- ``e_force``
    Measured: least-squares coefficients ``c^m_{a,h}`` of the force along axis ``a`` at the
    multiples ``h = 0 .. H`` of the spindle frequency (refined from the force spectrum), ``H =
    floor(0.3 fs / f_s)`` (below 0.3 fs the record's anti-alias filter is flat to 1 %). Predicted:
    the same coefficients of the simulated cut (:func:`~planner.diagnosis.forcemodel.
    simulated_harmonics`; no background force), turned by the one angle ``theta`` that best aligns
    them (the spindle angle at the start of a record is unknown): ``c^p_{a,h} exp(-i h theta)``.
    ``v_{a,h} = E|noise|^2`` of each measured coefficient follows from the force density around
    the line (``2 S(f_h) / T``; :func:`~planner.diagnosis.spectral.harmonic_noise_variance`). Then::

        e_force = max(0, sum |c^m - c^p|^2 - sum v) / (sum |c^m|^2 - sum v)

    the squared error of the mean force and harmonic amplitudes and phases relative to their
    squared size, in excess of what the background force alone explains.

(b) Structure model -- ``e_structure``
    The displacement predicted from the MEASURED force through the model (:func:`~planner.
    diagnosis.response.modal_response`, started in static equilibrium at the record start and run
    through the whole record) against the measured displacement, both as DFT lines ``X_{a,k}`` of
    the validation part, over a band ``B_a`` per axis: the line 0 (static deflection) and every
    line where the fit part's measured displacement density exceeds 4 times the sensor noise
    density. The noise is that of the displacement sensor's quantisation, simulated on the
    predicted displacement with random grid offsets (a tracker's rounding of a slow signal is not
    white: it follows the signal), plus the force sensor's noise through the model (or, for a
    sensor of unknown resolution, a white level from the residual above 0.3 fs). With ``w_k = 1``
    for line 0 and 2 otherwise (``1/N`` Parseval weights), ``R = X^m - X^p``::

        e_structure = max(0, sum w |R|^2 / N - noise) / (sum w |X^m|^2 / N - noise)

    the squared error of the band-limited displacement (static deflection, spectra and phases
    together) relative to its squared size, in excess of the expected sensor noise.

(c) Stability -- ``e_stability``
    The cut is a closed loop: regeneration and process damping shape the spectrum of the measured
    force at the robot's modes (:mod:`~planner.diagnosis.closedloop`), and chatter adds a line. The
    force with its harmonics removed gives Welch densities ``P^m_{a,k}`` (Hann, segments of a
    quarter of the part, 50 % overlap) at lines ``k`` of the band ``[0.5 min f_n, min(2.5 max f_n,
    0.3 fs)]`` more than 2.5 lines away from a harmonic; the prediction is the closed-loop density
    for an independent background, as a Welch estimate of that resolution would see it,
    ``P^p_{a,k}``. With ``l = ln P^m - ln P^p - alpha_a - beta_a u_k`` (a level and a slope per axis
    fitted by least squares: the background's own spectrum is unknown; ``u`` the line's position in
    the band from -1 to 1) over all ``n`` lines (``n_a`` per axis)::

        e_stability = max(0, sum l^2 - sum_a (n_a - 2) psi1(nu/2)) / n

    the mean squared logarithmic error of the force spectrum in excess of the Welch estimate's own
    (``psi1`` the trigamma function, ``nu`` twice the equivalent number of averages). Alongside it,
    :func:`~planner.diagnosis.chatter.detect_chatter` on the measured force says whether the cut
    chattered, and the zero-order approximation (:func:`stability.lobes.predict_point`) whether the
    model predicts it should have.

Significance. For any of the three, a change ``delta`` of the prediction (an extension of the
model) lowers the validation error sum ``E = sum w |y - p|^2`` by ``dE``; if the extension is
spurious, the noise part of ``dE`` has the standard deviation ``sqrt(sum c w^2 |delta|^2 s)`` with
``s`` the noise variance of each element (``c = 2`` for complex elements, 4 for real ones), and
``E[dE] = -sum w |delta|^2 < 0``. ``z = dE / std`` is the significance of the extension. The
disagreement of a part itself is ``(E - noise) / sqrt(sum c' w^2 s^2)`` (``c' = 1`` complex, 2 real):
the excess over the noise in standard deviations of the noise power.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from oma.cutting import CuttingCoefficients
from oma.modal import ModalModel
from oma.record import Record

from .chatter import ChatterResult, detect_chatter
from .evaluation import PartEvaluation, RecordView, prepare_views, significance
from .parts import ForcePart, StabilityPart, StructurePart

__all__ = [
    "RecordView",
    "PartEvaluation",
    "ForcePart",
    "StructurePart",
    "StabilityPart",
    "RecordComparison",
    "Comparison",
    "prepare_views",
    "compare_records",
    "significance",
    "PARTS",
]

PARTS = ("force", "structure", "stability")


# ---------------------------------------------------------------------------------- comparison
@dataclass(frozen=True)
class RecordComparison:
    """Per-record comparison: part errors on the validation half, chatter and predicted stability.

    Attributes
    ----------
    name : str
    spindle_hz : float
        Refined from the force spectrum, Hz.
    errors : dict
        ``force``, ``structure``, ``stability`` (module notes; NaN where a part has no data).
    chatter : ChatterResult
        Chatter detection on the measured force of the whole window, told the predicted chatter
        frequency (a "no" is unsure when that frequency lies above the band the record shows).
    predicted_stable : bool
    depth_limit_m : float
        Zero-order-approximation limit at the record's speed, m.
    axial_depth_m : float
    predicted_chatter_hz : float
    """

    name: str
    spindle_hz: float
    errors: dict
    chatter: ChatterResult
    predicted_stable: bool
    depth_limit_m: float
    axial_depth_m: float
    predicted_chatter_hz: float

    def to_dict(self) -> dict:
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {"name": self.name, "spindle_hz": float(self.spindle_hz),
                "errors": {k: num(v) for k, v in self.errors.items()},
                "chatter": self.chatter.to_dict(), "predicted_stable": bool(self.predicted_stable),
                "depth_limit_m": num(self.depth_limit_m), "axial_depth_m": float(self.axial_depth_m),
                "predicted_chatter_hz": num(self.predicted_chatter_hz)}


@dataclass(frozen=True)
class Comparison:
    """What the current model gets right and wrong (validation halves; module notes).

    Attributes
    ----------
    errors : dict
        ``force``, ``structure``, ``stability`` over all records.
    records : tuple of RecordComparison
    """

    errors: dict
    records: tuple

    def to_dict(self) -> dict:
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {"errors": {k: num(v) for k, v in self.errors.items()},
                "records": [r.to_dict() for r in self.records]}


class Parts:
    """The three parts of one set of views, built once (the expensive baseline simulations)."""

    def __init__(self, views: Sequence[RecordView], model: ModalModel, *, structure: "StructurePart | None" = None):
        self.views = list(views)
        self.model = model
        self.force = ForcePart(views, model)
        # the structure part does not depend on the cutting coefficients (it is driven by the
        # measured force): a re-fit of the coefficients may share it
        self.structure = StructurePart(views, model) if structure is None else structure
        self.stability = StabilityPart(views, model)
        self.base_force = {h: self.force.evaluate(h, self.force.baseline) for h in ("fit", "val")}
        self.base_structure = self.structure.evaluate(self.structure.baseline) if self.structure.views else None
        self.base_logs = {h: self.stability.baseline_logs(h) for h in ("fit", "val")}
        self.base_stability = {h: self.stability.evaluate(h, self.base_logs[h]) for h in ("fit", "val")}

    def errors(self) -> dict:
        return {
            "force": self.base_force["val"].error,
            "structure": self.base_structure.error if self.base_structure is not None else float("nan"),
            "stability": self.base_stability["val"].error,
        }

    def record_errors(self, i: int) -> dict:
        out = {"force": self.force.evaluate("val", self.force.baseline, views=[i]).error}
        j = next((k for k, v in enumerate(self.structure.views) if v.index == self.views[i].index), None)
        out["structure"] = (self.structure.evaluate(self.structure.baseline, views=[j]).error
                            if j is not None else float("nan"))
        out["stability"] = self.stability.evaluate("val", self.base_logs["val"], views=[i]).error
        return out


def record_comparisons(parts: Parts) -> tuple:
    """Per-record comparison (errors, chatter, predicted limit) of prepared parts."""
    from stability.lobes import predict_point

    out = []
    for i, v in enumerate(parts.views):
        try:
            op = predict_point(parts.model, v.tool, v.cut, v.coefficients, spindle_rpm=60.0 * v.spindle_hz,
                               axial_depth_m=float(v.cut.axial_depth_m), method="zoa", n_freq=4000)
            stable, limit, fc = bool(op.stable), float(op.depth_limit_m), float(op.chatter_frequency_hz)
        except (ValueError, ArithmeticError):  # pragma: no cover - a model the ZOA cannot handle
            stable, limit, fc = True, float("nan"), float("nan")
        # records are filtered before sampling (formats.md; the simulator's anti-alias filter):
        # no harmonic above the Nyquist frequency folds into them; a chatter frequency the model
        # puts above the band searched cannot be seen (its "no" is marked unsure)
        chat = detect_chatter(v.force, v.sample_rate_hz, v.spindle_hz, v.tool.teeth, refine=False,
                              max_harmonic_hz=0.5 * v.sample_rate_hz, expected_chatter_hz=fc)
        out.append(RecordComparison(name=v.name, spindle_hz=v.spindle_hz, errors=parts.record_errors(i), chatter=chat,
                                    predicted_stable=stable, depth_limit_m=limit,
                                    axial_depth_m=float(v.cut.axial_depth_m), predicted_chatter_hz=fc))
    return tuple(out)


def compare_records(records: Sequence[Record], model: ModalModel, *, coefficients: CuttingCoefficients | None = None
            ) -> Comparison:
    """Compare measured records with the simulation of the same cuts by ``model`` (module notes).

    Parameters
    ----------
    records : sequence of Record
        Cuts with force (X, Y, Z) and tool-tip displacement, spindle speed and axial depth.
    model : ModalModel
        The current model of the tool-tip dynamics.
    coefficients : CuttingCoefficients, optional
        Default: each record's material coefficients.

    Returns
    -------
    Comparison
    """
    views = prepare_views(records, coefficients=coefficients)
    parts = Parts(views, model)
    return Comparison(errors=parts.errors(), records=record_comparisons(parts))
