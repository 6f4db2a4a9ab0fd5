"""Diagnose: where the simulation disagrees with the measurement, which cause explains it, and how much
better the extended model predicts.

1. Compare (:mod:`~planner.diagnosis.compare`): force, structure and stability parts, each record
   split into a fit half and a validation half, with the nominal cutting coefficients.
2. Re-fit the cutting coefficients on the fit halves (:mod:`~planner.diagnosis.coefficients`): the
   baseline every other cause must beat. ``cutting_coefficients`` is scored as the re-fitted
   baseline against the nominal one.
3. Fit every other candidate cause on the fit halves on top of the re-fitted coefficients
   (:mod:`~planner.diagnosis.causes`) and predict its part on the validation halves.
4. Score: ``gain = (e_before - e_after) / e_before`` of the candidate's part on the validation
   halves (against the re-fitted baseline), and its significance ``z`` (the reduction of the
   validation residual over the standard deviation the noise alone would give it,
   :func:`~planner.diagnosis.compare.significance`).
5. Name the cause. A candidate qualifies in a part that disagrees with the measurement beyond its
   noise (``disagreement >= min_significance``) when its own reduction there is significant (``z
   >= min_significance``; 3: a spurious extension reaches it with probability below 0.2 %, since
   its expected reduction is negative), ``gain >= min_gain`` (the share of the part's error it
   removes) and its fitted size passes its practical floor (:mod:`~planner.diagnosis.floors`:
   twice its standard error and a physically argued amount), and only when its fit succeeded (an
   optimiser that stopped short of its optimum has not measured the cause). Among the qualified,
   an effect beats the coefficients (it survived their re-fit; the re-fit is reported beside it), and among
   effects the one that explains the most disagreement wins: ``score = sum over the parts it
   predicts of gain x disagreement`` (in standard deviations of each part's noise power, so that
   parts compare). ``none`` if no candidate qualifies. An extension may predict more than its own
   part: process damping also changes the force harmonics (through the forced vibration), which
   the simulator predicts; the coefficients also change the closed-loop spectrum.

What the records cannot show. A mode of the model above the records' band (the anti-alias cut-off
``0.4 fs``, :func:`~planner.diagnosis.response.visible_band_hz`: a spindle/tool mode at 720 Hz in
a 1 kHz record) is held as given: it enters the comparison by its response in the band (about its
static compliance), is not turned (``cross_coupling``), drifted (``pose_drift``) or used to size
a delay, and a warning says so. What the records do tell of such a mode, its compliance in the
band, is fitted (:func:`~planner.diagnosis.causes.fit_above_band_compliance`) as the alternative
the structure causes must beat: a structure cause whose validation gain is no larger than that
compliance change's is not named (the records cannot tell it from a stiffer or missing spindle
mode; on the example's long record with the planning model, whose 720/735 Hz tool modes the
records lack, a 21 deg turn of the 10.5 Hz mode took 32 % of the structure error where the
compliance explains 98 %). A record whose predicted chatter frequency lies above the band it
shows cannot tell chatter there (filtered out, or folded to ``fs - f_c``): its chatter detection is
marked unsure and a warning says so.
"""

from __future__ import annotations

import math
import warnings as _warnings
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from oma.cutting import CuttingCoefficients
from oma.errors import InputError
from oma.modal import ModalModel
from oma.record import Record
from oma.spectra import welch_spectra

from .causes import CANDIDATES, Extension, fit_above_band_compliance, fit_candidate
from .coefficients import CoefficientFit, fit_coefficients
from .floors import FLOORS, practical_size
from .compare import Comparison, Parts, record_comparisons
from .evaluation import PartEvaluation, prepare_views, significance
from .forcemodel import sensor_gain
from .parts import align_angle, rotate
from .response import views_band_hz

__all__ = ["CandidateResult", "Diagnosis", "diagnose", "CAUSE_NAMES"]

#: Smallest relative change of the compliance of a mode above the records' band that a warning
#: reports as a disagreement (the unmodeled mode's floor, :mod:`~planner.diagnosis.floors`).
ABOVE_BAND_FLOOR = 0.10
#: Every value of ``Diagnosis.cause``.
CAUSE_NAMES = ("none",) + tuple(CANDIDATES) + ("cutting_coefficients",)
#: The candidates a diagnosis tries, in the order of cli.md.
CANDIDATE_NAMES = CAUSE_NAMES[1:]


def _num(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _plain(obj):
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _num(obj)
    return obj


@dataclass(frozen=True)
class CandidateResult:
    """One candidate cause, fitted and validated.

    Attributes
    ----------
    cause : str
    part : str
        The part where the extension explains most (module notes); the numbers below are its.
    gain : float
        Relative reduction of the part's validation error (``nan`` when the fit failed).
    significance : float
        ``z`` of the reduction (module notes).
    error_before, error_after : float
        The part's validation error without and with the extension.
    disagreement : float
        ``z`` of the part's validation error over its noise (the comparison, before any extension).
    score : float
        Disagreement explained, summed over the parts the extension predicts: ``sum gain *
        disagreement`` (in standard deviations of each part's noise power).
    parts : dict
        Per part: gain, significance, errors, disagreement, explained.
    parameters : dict
    success : bool
    message : str
    """

    cause: str
    part: str
    gain: float
    significance: float
    error_before: float
    error_after: float
    parameters: dict
    success: bool
    message: str
    extension: Extension | None = field(default=None, repr=False)
    disagreement: float = float("nan")
    score: float = 0.0
    parts: dict = field(default_factory=dict)
    practical: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"cause": self.cause, "gain": _num(self.gain), "significance": _num(self.significance),
                "practical": _plain(self.practical),
                "part": self.part, "error_before": _num(self.error_before), "error_after": _num(self.error_after),
                "disagreement": _num(self.disagreement), "score": _num(self.score),
                "parts": {k: {kk: _num(vv) for kk, vv in v.items()} for k, v in self.parts.items()},
                "parameters": _plain(self.parameters), "success": bool(self.success)}


@dataclass(frozen=True)
class Diagnosis:
    """What robomill concludes from comparing records with its simulation.

    Attributes
    ----------
    cause : str
        One of :data:`CAUSE_NAMES`.
    parameters : dict
        The named cause's fitted parameters, physical units in the key names (empty for ``none``).
    error_before, error_after : float
        Validation error of the named cause's part without and with the extension (for ``none``:
        the part of the best-ranked candidate, unchanged).
    gain : float
        ``(error_before - error_after) / error_before`` (0 for ``none``).
    significance : float
        ``z`` of the named cause's reduction (module notes).
    part : str
        The part the named cause extends.
    ranking : tuple of CandidateResult
        Every candidate, the most disagreement explained first (failed fits last).
    comparison : Comparison
        Part errors (validation halves) and per-record chatter and predicted stability.
    min_significance, min_gain : float
        The thresholds used.
    plot_data : dict
        Arrays for :meth:`plot`: residual spectra before/after, FRF with and without the extension,
        the evidence of the named (or best-ranked) cause.
    warnings : tuple of str
        What the records cannot tell (modes above their band, a predicted chatter frequency they
        cannot show) and candidates left unnamed because their fit did not succeed or a change of
        the compliance of the modes above the band explains as much (module notes).
    above_band : dict or None
        The compliance of the model's modes above the records' band as the records see it:
        ``mode_frequency_hz``, ``compliance_factor`` (1: the model's), ``gain`` and
        ``significance`` in the structure part (None when the model has no such mode).
    """

    cause: str
    parameters: dict
    error_before: float
    error_after: float
    gain: float
    significance: float
    part: str
    ranking: tuple
    comparison: Comparison
    min_significance: float
    min_gain: float
    plot_data: dict = field(default_factory=dict, repr=False)
    coefficient_fit: CoefficientFit | None = field(default=None, repr=False)
    warnings: tuple = ()
    above_band: dict | None = None

    def to_dict(self) -> dict:
        """The ``robomill diagnose --json`` object (cli.md), plus the comparison's part errors."""
        return {
            "cause": self.cause,
            "parameters": _plain(self.parameters),
            "error_before": _num(self.error_before),
            "error_after": _num(self.error_after),
            "gain": _num(self.gain),
            "ranking": [c.to_dict() for c in self.ranking],
            "part": self.part,
            "significance": _num(self.significance),
            "errors": {k: _num(v) for k, v in self.comparison.errors.items()},
            "records": [r.to_dict() for r in self.comparison.records],
            "thresholds": {"min_significance": self.min_significance, "min_gain": self.min_gain,
                           "practical_floors": {k: v[0] for k, v in FLOORS.items()}},
            "baseline_coefficients": (self.coefficient_fit.to_dict() if self.coefficient_fit is not None
                                      else None),
            "above_band": _plain(self.above_band) if self.above_band is not None else None,
            "warnings": list(self.warnings),
        }

    def plot(self, *, figsize=(12.0, 8.5)):
        """Residual spectra before/after, FRF with and without the extension, and the evidence.

        Returns
        -------
        fig, axes
            One figure (matplotlib imported only here, via :mod:`~planner.diagnosis.plots`).
        """
        from .plots import plot_diagnosis

        return plot_diagnosis(self, figsize=figsize)


# ------------------------------------------------------------------------------------ scoring
def _evaluate(parts: Parts, part: str, prediction) -> tuple[PartEvaluation, PartEvaluation]:
    if part == "force":
        return parts.base_force["val"], parts.force.evaluate("val", prediction)
    if part == "structure":
        return parts.base_structure, parts.structure.evaluate(prediction)
    return parts.base_stability["val"], parts.stability.evaluate("val", prediction)


def _score(parts: Parts, cause: str) -> CandidateResult:
    try:
        ext = fit_candidate(cause, parts)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # a fit that cannot run
        part = {"channel_delay": "structure", "unmodeled_mode": "structure", "cross_coupling": "structure",
                "pose_drift": "structure", "process_damping": "stability"}.get(cause, "force")
        return CandidateResult(cause, part, float("nan"), float("nan"), float("nan"), float("nan"), {}, False,
                               f"fit failed: {exc}")
    return _score_extension(parts, ext)


def _score_extension(parts: Parts, ext: Extension) -> CandidateResult:
    """Validation gain and significance of a fitted extension in each part it predicts, against the
    baseline of ``parts``; its practical size against its floor (:mod:`~planner.diagnosis.floors`)."""
    cause = ext.cause
    if not ext.prediction:
        return CandidateResult(cause, ext.part, float("nan"), float("nan"), float("nan"), float("nan"),
                               ext.parameters, False, ext.message, ext)
    per_part = {}
    for part, prediction in [(ext.part, ext.prediction)] + list(ext.other_predictions.items()):
        before, after = _evaluate(parts, part, prediction)
        e_b, e_a = before.error, after.error
        gain = (e_b - e_a) / e_b if e_b > 0 else 0.0
        dis = before.disagreement
        per_part[part] = {"gain": float(gain), "significance": significance(before, after), "error_before": e_b,
                          "error_after": e_a, "disagreement": dis,
                          "explained": max(gain, 0.0) * max(dis, 0.0) if math.isfinite(gain) else 0.0}
    main = max(per_part, key=lambda k: per_part[k]["explained"]) if len(per_part) > 1 else ext.part
    m = per_part[main]
    practical = practical_size(cause, ext.parameters, parts, ext)
    return CandidateResult(cause, main, m["gain"], m["significance"], m["error_before"], m["error_after"],
                           ext.parameters, ext.success, ext.message, ext, m["disagreement"],
                           float(sum(v["explained"] for v in per_part.values())), per_part, practical)


def _score_coefficients(nominal: Parts, refit: Parts, fit: CoefficientFit) -> CandidateResult:
    """The re-fitted coefficients as a cause: the refit's baseline against the nominal one."""
    from .forcefits import _harmonic_evidence

    pred = list(refit.force.baseline)
    ext = Extension("cutting_coefficients", "force", dict(fit.parameters), fit.success, fit.message, pred,
                    evidence=_harmonic_evidence(nominal, pred),
                    other_predictions={"stability": list(refit.base_logs["val"])})
    return _score_extension(nominal, ext)


# ------------------------------------------------------------------------------- plot arrays
def _measured_frf(view, nperseg):
    """MIMO H1 estimate ``S_xF S_FF^-1``, shape (3, 3, n_freq) (NaN rows for axes not measured)."""
    axes = view.displacement_axes
    x = np.where(np.isnan(view.displacement), 0.0, view.displacement)
    sp = welch_spectra(view.force, x, view.sample_rate_hz, nperseg=nperseg)
    h = np.einsum("oik,ijk->ojk", sp.syu, np.linalg.inv(sp.suu.transpose(2, 0, 1)).transpose(1, 2, 0))
    h[~axes] = np.nan
    return sp.freq_hz, h


def _prediction_for(ext: Extension | None, part: str):
    if ext is None:
        return None
    if ext.part == part:
        return ext.prediction or None
    return ext.other_predictions.get(part)


def _plot_data(parts: Parts, best: CandidateResult) -> dict:
    out: dict = {"part": best.part, "cause": best.cause}
    ext = best.extension
    v0 = parts.views[0]
    pred = _prediction_for(ext, best.part)
    # residual spectra before/after on the validation half of the first record
    if best.part == "force":
        y = parts.force.measured["val"][0]
        s = parts.force.noise["val"][0]
        b = parts.force.baseline[0]
        a = pred[0] if pred else b
        wts = 1.0 / np.maximum(s, 1e-30)
        out["residual"] = {
            "kind": "harmonics", "freq_hz": np.arange(y.shape[1]) * v0.spindle_hz,
            "before": np.abs(y - rotate(b, align_angle(y, b, wts))),
            "after": np.abs(y - rotate(a, align_angle(y, a, wts))), "noise": np.sqrt(s)}
    elif best.part == "structure" and parts.structure.views:
        st = parts.structure
        v = st.views[0]
        sl = v.half("val")
        fs = v.sample_rate_hz
        from .spectral import welch_psd

        nper = int(min(sl.stop - sl.start, 2 ** round(math.log2(max((sl.stop - sl.start) / 4, 64)))))
        base = st.baseline[0]
        aft = pred[0] if pred else base
        xm = np.where(np.isnan(v.displacement), 0.0, v.displacement)
        f, pb = welch_psd(xm[:, sl] - base[:, sl], fs, nper)
        _, pa = welch_psd(xm[:, sl] - aft[:, sl], fs, nper)
        _, px = welch_psd(xm[:, sl], fs, nper)
        out["residual"] = {"kind": "psd", "freq_hz": f, "before": pb, "after": pa, "measured": px,
                           "unit": "m^2/Hz"}
    else:
        sp = parts.stability
        d = sp.data[0]["val"]
        base = parts.base_logs["val"][0]
        aft = pred[0] if pred else base
        eb = sp.evaluate("val", [base], views=[0])
        ea = sp.evaluate("val", [aft], views=[0])
        out["residual"] = {"kind": "log_psd", "freq_hz": d["freq"], "measured": d["y"],
                           "before": eb.p.reshape(d["y"].shape), "after": ea.p.reshape(d["y"].shape)}
    # FRF with and without the extension
    fs = v0.sample_rate_hz
    top = max(4.0 * float(np.max(parts.model.natural_frequency_hz)) if parts.model.n_modes else 0.0, 60.0)
    if ext is not None and ext.model is not None and ext.model.n_modes:
        top = max(top, 1.5 * float(np.max(ext.model.natural_frequency_hz)))
    if ext is not None and best.cause == "force_sensor_dynamics":
        top = max(top, 1.5 * float(ext.parameters.get("sensor_frequency_hz", 0.0)))
    f_model = np.linspace(0.5, min(0.45 * fs, top), 800)
    g = parts.model.receptance(f_model)
    g_before = np.array([g[a, a] for a in range(3)])
    g_after = g_before
    g_after_full = g
    if ext is not None and ext.model is not None:
        g_after_full = ext.model.receptance(f_model)
        g_after = np.array([g_after_full[a, a] for a in range(3)])
    elif best.cause == "channel_delay" and ext is not None:
        g_after = g_before * np.exp(-2j * np.pi * f_model * ext.parameters["delay_s"])[None, :]
    elif best.cause == "force_sensor_dynamics" and ext is not None:
        # what an FRF estimated from the sensor's force shows: G / H_sensor
        g_after = g_before / sensor_gain(f_model, ext.parameters["sensor_frequency_hz"],
                                         ext.parameters["sensor_damping_ratio"])[None, :]
    out["frf"] = {"freq_hz": f_model, "before": g_before, "after": g_after, "after_full": g_after_full}
    if np.any(v0.displacement_axes):
        n = v0.n_samples
        f_h1, h1 = _measured_frf(v0, int(2 ** math.floor(math.log2(max(n // 4, 64)))))
        out["frf"].update({"measured_freq_hz": f_h1, "measured": np.array([h1[a, a] for a in range(3)]),
                           "measured_full": h1})
    out["evidence"] = dict(ext.evidence) if ext is not None else {}
    out["evidence"]["cause"] = best.cause
    out["evidence"]["parameters"] = dict(best.parameters)
    return out


# ---------------------------------------------------------------------------------- diagnose
def diagnose(records: Sequence[Record], model: ModalModel, *, coefficients: CuttingCoefficients | None = None,
             causes: Sequence[str] | None = None, min_significance: float = 3.0, min_gain: float = 0.2,
             refit_coefficients: bool = True, plot_data: bool = True) -> Diagnosis:
    """Compare records with robomill's simulation, name the cause of the disagreement, measure the gain.

    Parameters
    ----------
    records : sequence of Record
        Cuts at one pose with force (X, Y, Z) and tool-tip displacement, spindle speed, axial
        depth and (unless ``coefficients`` is given) the material's cutting coefficients. At least
        2 s of cut window each (the halves must hold several periods of the robot modes).
    model : ModalModel
        The current tool-tip model.
    coefficients : CuttingCoefficients, optional
        Overrides the records' coefficients.
    causes : sequence of str, optional
        Candidates to try (default all of :data:`CAUSE_NAMES` but ``none``).
    min_significance : float
        Smallest ``z`` of a named cause.
    min_gain : float
        Smallest validation gain of a named cause.
    refit_coefficients : bool
        Re-fit the cutting coefficients first and measure every other cause against them (module
        notes); ``False`` keeps the nominal ones (and drops ``cutting_coefficients``).
    plot_data : bool
        Keep the arrays :meth:`Diagnosis.plot` needs.

    Returns
    -------
    Diagnosis

    Raises
    ------
    InputError
        A record that cannot be compared (no spindle speed, depth, coefficients, force axes; too
        short).
    ValueError
        An unknown cause.
    """
    if not records:
        raise InputError(None, "records", "at least one record", "none")
    names = CANDIDATE_NAMES if causes is None else tuple(causes)
    for c in names:
        if c not in CANDIDATE_NAMES:
            raise ValueError(f"cause must be one of {', '.join(CANDIDATE_NAMES)}, not {c!r}")
    views = prepare_views(records, coefficients=coefficients)
    nominal = Parts(views, model)
    comparison = Comparison(errors=nominal.errors(), records=record_comparisons(nominal))
    fit = None
    parts = nominal
    same = all(v.coefficients == views[0].coefficients for v in views)
    if refit_coefficients and same:
        # the baseline every other cause must beat: the coefficients re-fitted on the fit halves
        fit = fit_coefficients(nominal)
        parts = Parts([replace(v, coefficients=fit.fitted) for v in views], model, structure=nominal.structure)
    results = [_score(parts, c) for c in names if c != "cutting_coefficients"]
    if fit is not None and "cutting_coefficients" in names:
        results.append(_score_coefficients(nominal, parts, fit))
    above = _score_above_band(parts)

    def significant(r):
        return r.practical.get("passes", False) and any(
            math.isfinite(p["gain"]) and p["significance"] >= min_significance and p["gain"] >= min_gain
            and p["disagreement"] >= min_significance for p in r.parts.values())

    def mimicked(r):
        # a structure cause that explains no more than a change of the compliance of the modes the
        # records cannot see is not told apart from it
        return (above is not None and r.part == "structure" and "structure" in r.parts
                and math.isfinite(r.parts["structure"]["gain"]) and r.parts["structure"]["gain"] <= above["gain"])

    def qualifies(r):
        # a fit that did not succeed has not measured its cause, however much it lowers the error
        return r.success and significant(r) and not mimicked(r)

    def key(r):
        # a cause that survives on top of the re-fitted coefficients is the more specific finding:
        # qualified effects first, then the coefficients, then the rest; each by disagreement explained
        tier = 0 if qualifies(r) and r.cause != "cutting_coefficients" else 1 if qualifies(r) else 2
        return (0 if math.isfinite(r.gain) else 1, tier, -r.score, -(r.gain if math.isfinite(r.gain) else 0.0))

    ranking = tuple(sorted(results, key=key))
    eligible = [r for r in ranking if qualifies(r)]
    if eligible:
        best = eligible[0]
        cause, params, gain, z = best.cause, dict(best.parameters), best.gain, best.significance
        e_b, e_a = best.error_before, best.error_after
    else:
        best = ranking[0]
        cause, params, gain, z = "none", {}, 0.0, 0.0
        e_b = e_a = best.error_before if math.isfinite(best.error_before) else comparison.errors["force"]
    data = _plot_data(nominal if best.cause == "cutting_coefficients" else parts, best) if plot_data else {}
    if cause == "none" and data:
        data["cause"] = "none"
    # the records disagree with the modes above their band when a change of those modes' compliance
    # is significant, removes a share of the structure error a cause would need (min_gain), changes
    # some compliance by 10 % or more (the unmodeled mode's floor: the limit a mode sets moves by as
    # much), and no structure cause that qualifies explains more
    disagrees = bool(above is not None and above["significance"] >= min_significance and above["gain"] >= min_gain
                     and max(abs(a - 1.0) for a in above["compliance_factor"]) >= ABOVE_BAND_FLOOR
                     and not any(qualifies(r) and r.part == "structure" and r.parts["structure"]["gain"] > above["gain"]
                                 for r in results))
    notes = _band_warnings(views, model, comparison, above if disagrees else None) + tuple(
        f"{r.cause}: not named, its fit did not succeed ({r.message}), although its validation gain "
        f"{r.gain:.2f} (z = {r.significance:.1f}) and size pass the thresholds"
        for r in ranking if not r.success and significant(r)) + tuple(
        f"{r.cause}: not named, a change of the compliance of the modes above the band explains as much of "
        f"the structure disagreement (gain {above['gain']:.2f} against its {r.parts['structure']['gain']:.2f})"
        for r in ranking if r.success and significant(r) and mimicked(r))
    for note in notes:
        _warnings.warn(note, UserWarning, stacklevel=2)
    return Diagnosis(cause=cause, parameters=params, error_before=float(e_b), error_after=float(e_a),
                     gain=float(gain), significance=float(z), part=best.part,
                     ranking=ranking, comparison=comparison, min_significance=float(min_significance),
                     min_gain=float(min_gain), plot_data=data, coefficient_fit=fit, warnings=notes,
                     above_band=above)


def _score_above_band(parts: Parts) -> dict | None:
    """The compliance of the modes above the records' band fitted, with its structure gain and ``z``
    on the validation halves (None without such modes)."""
    ext = fit_above_band_compliance(parts)
    if ext is None:
        return None
    before, after = _evaluate(parts, "structure", ext.prediction)
    gain = (before.error - after.error) / before.error if before.error > 0 else 0.0
    return dict(ext.parameters, gain=float(gain), significance=float(significance(before, after)),
                success=bool(ext.success))


def _band_warnings(views, model: ModalModel, comparison: Comparison, above: dict | None) -> tuple:
    """What the records cannot show: the model's modes above their band (and, given ``above``, the
    compliance the records put on them), and predicted chatter frequencies above the band a record
    shows (module notes)."""
    out = []
    band = views_band_hz(views)
    fn = np.asarray(model.natural_frequency_hz, dtype=float)
    high = fn[fn > band]
    if high.size:
        fs = min(v.sample_rate_hz for v in views)
        out.append(f"the model's modes at {', '.join(f'{f:.4g}' for f in high)} Hz lie above the band the records "
                   f"resolve ({band:.4g} Hz: the anti-alias cut-off of {fs:.4g} Hz sampling, Nyquist "
                   f"{0.5 * fs:.4g} Hz); the records cannot see them: they are held as given (not turned, "
                   f"drifted or used to size a delay) and enter the comparison by their response in the band "
                   f"(about their static compliance)")
    if above is not None:
        factors = ", ".join(f"{a:.3g}" for a in above["compliance_factor"])
        out.append(f"the records' response in the band puts the compliance of the modes above it at {factors} "
                   f"times the model's (structure gain {above['gain']:.2f}, z = {above['significance']:.1f}): the "
                   f"records disagree with these modes' stiffness (below 1: the model's are too soft, or the "
                   f"records lack them; above 1: too stiff); a measurement that resolves them (a tap test, a "
                   f"faster record) must tell")
    for rec in comparison.records:
        ch = rec.chatter
        if not ch.out_of_band or rec.predicted_stable:
            continue
        seen = (f"chatter was detected at {ch.frequency_hz:.4g} Hz, which may be its alias" if ch.chatter
                else f"the record's 'no chatter' cannot be trusted (confidence {ch.confidence:.2g})")
        out.append(f"record {rec.name}: the model predicts chatter at {ch.expected_chatter_hz:.4g} Hz (depth "
                   f"{rec.axial_depth_m:.4g} m over its limit {rec.depth_limit_m:.4g} m), above the band the record "
                   f"shows; there it is filtered out or folds to {ch.expected_alias_hz:.4g} Hz: {seen}")
    return tuple(out)
