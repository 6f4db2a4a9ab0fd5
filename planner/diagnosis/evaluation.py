"""Records prepared for the comparison (:class:`RecordView`) and what a part's comparison yields
(:class:`PartEvaluation`, :func:`significance`); the statistics are in :mod:`planner.diagnosis.compare`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from oma.cutting import CuttingCoefficients, Cut, Tool
from oma.errors import InputError
from oma.record import Record
from oma.signals import prepare_record

from .chatter import refine_spindle_frequency_aliased

__all__ = ["RecordView", "PartEvaluation", "prepare_views", "significance", "HARMONIC_FRACTION"]

#: Highest harmonic compared in part (a), as a fraction of the sample rate.
HARMONIC_FRACTION = 0.3


# ------------------------------------------------------------------------------------------ views
@dataclass(frozen=True)
class RecordView:
    """One record prepared for the comparison: signals of its cut window, SI.

    Attributes
    ----------
    index : int
    name : str
    tool, cut, coefficients
        ``cut`` has the spindle speed refined from the force (``60 spindle_hz``).
    force : ndarray, shape (3, n)
        N.
    displacement : ndarray, shape (3, n)
        m (NaN rows for axes not recorded).
    sample_rate_hz, spindle_hz : float
    split : int
        First sample of the validation half.
    resolution_m : float or None
        Displacement quantisation step (from the record's sensors or the samples' grid).
    force_noise_variance_N2 : float
    has_static : bool
        Whether the displacement carries the static deflection (False when integrated from velocity
        or acceleration).
    """

    index: int
    name: str
    tool: Tool
    cut: Cut
    coefficients: CuttingCoefficients
    force: np.ndarray = field(repr=False)
    displacement: np.ndarray = field(repr=False)
    sample_rate_hz: float
    spindle_hz: float
    split: int
    resolution_m: float | None
    force_noise_variance_N2: float
    has_static: bool = True

    @property
    def n_samples(self) -> int:
        return int(self.force.shape[1])

    def half(self, which: str) -> slice:
        """``'fit'`` (first half) or ``'val'`` (second half)."""
        return slice(0, self.split) if which == "fit" else slice(self.split, self.n_samples)

    def t0(self, which: str) -> float:
        """Start time of a half relative to the window start, s."""
        return (0 if which == "fit" else self.split) / self.sample_rate_hz

    @property
    def displacement_axes(self) -> np.ndarray:
        return ~np.all(np.isnan(self.displacement), axis=1)

    @property
    def n_harm(self) -> int:
        return max(int(math.floor(HARMONIC_FRACTION * self.sample_rate_hz / self.spindle_hz)), 1)


def prepare_views(records: Sequence[Record], *, coefficients: CuttingCoefficients | None = None,
                  min_duration_s: float = 2.0) -> list[RecordView]:
    """Prepare records for :func:`compare` and :func:`~planner.diagnosis.diagnose`.

    Raises
    ------
    InputError
        A record without spindle speed, axial depth or cutting coefficients, or shorter than
        ``min_duration_s`` in its cut window.
    """
    views = []
    for i, rec in enumerate(records):
        name = rec.name or f"record {i}"
        # a record read from a file is named by its path; one made in memory by its name
        src, pre = (rec.path, "") if rec.path is not None else (None, f"{name}: ")
        if rec.cut.spindle_rpm is None or not rec.cut.spindle_rpm > 0:
            raise InputError(src, f"{pre}cut.spindle_rpm", "a positive spindle speed", repr(rec.cut.spindle_rpm))
        if rec.cut.axial_depth_m is None or not rec.cut.axial_depth_m > 0:
            raise InputError(src, f"{pre}cut.axial_depth_m", "a positive axial depth", repr(rec.cut.axial_depth_m))
        coef = coefficients
        if coef is None:
            coef = rec.material.cutting_coefficients if rec.material is not None else None
        if coef is None:
            raise InputError(src, f"{pre}material.cutting_coefficients", "cutting coefficients", "none")
        sig = prepare_record(rec)
        fs = float(sig.sample_rate_hz)
        if sig.duration_s < min_duration_s:
            raise InputError(src, f"{pre}signals", f"a cut window of at least {min_duration_s:g} s",
                             f"{sig.duration_s:.3g} s")
        force = np.asarray(sig.force_N, dtype=float)
        if np.any(np.all(np.isnan(force), axis=1)):
            raise InputError(src, f"{pre}signals", "force along X, Y and Z", "a missing force axis")
        f_nom = float(rec.cut.spindle_rpm) / 60.0
        f_sp = refine_spindle_frequency_aliased(force, fs, f_nom, teeth=rec.tool.teeth, search=0.05)
        cut = replace(rec.cut, spindle_rpm=60.0 * f_sp)
        resolution = None
        if rec.sensors is not None and rec.sensors.displacement_resolution_m:
            resolution = float(rec.sensors.displacement_resolution_m)
        elif sig.quantisation_step_m is not None:
            resolution = float(sig.quantisation_step_m)
        noise = 0.0
        if rec.sensors is not None and rec.sensors.force_noise_variance_N2:
            noise = float(rec.sensors.force_noise_variance_N2)
        views.append(RecordView(
            index=i, name=name, tool=rec.tool, cut=cut, coefficients=coef, force=force,
            displacement=np.asarray(sig.displacement_m, dtype=float), sample_rate_hz=fs, spindle_hz=f_sp,
            split=force.shape[1] // 2, resolution_m=resolution, force_noise_variance_N2=noise,
            has_static=sig.motion_quantity == "displacement"))
    return views


# -------------------------------------------------------------------------------- evaluations
@dataclass(frozen=True)
class PartEvaluation:
    """The elements of one part's error on one half: measured ``y``, predicted ``p``, noise ``s``.

    ``E = sum w |y - p|^2``, ``noise = sum w s``; ``error = max(0, E - noise) / denominator``.
    Elements are flattened over records, axes and lines. ``correlation`` multiplies the variance of
    a sum over neighbouring elements (1.5 for adjacent lines of a Hann-window Welch estimate).
    """

    part: str
    y: np.ndarray
    p: np.ndarray
    s: np.ndarray
    w: np.ndarray
    denominator: float
    real: bool = False
    correlation: float = 1.0

    @property
    def residual_power(self) -> float:
        return float(np.sum(self.w * np.abs(self.y - self.p) ** 2))

    @property
    def noise_power(self) -> float:
        return float(np.sum(self.w * self.s))

    @property
    def error(self) -> float:
        if not self.denominator > 0:
            return float("nan")
        return max(self.residual_power - self.noise_power, 0.0) / self.denominator

    @property
    def n_elements(self) -> int:
        return int(self.y.size)

    @property
    def disagreement(self) -> float:
        """``z`` of the excess ``E - noise``: how far the prediction misses beyond the noise, in
        standard deviations of the noise power (``Var |n|^2 = s^2`` for a complex element, ``2 s^2``
        for a real one)."""
        c = (2.0 if self.real else 1.0) * self.correlation
        std = math.sqrt(float(np.sum(c * self.w**2 * self.s**2)))
        if std <= 0.0:
            return 0.0
        return (self.residual_power - self.noise_power) / std


def significance(before: PartEvaluation, after: PartEvaluation) -> float:
    """``z`` of the reduction of the residual power from ``before`` to ``after`` (module notes)."""
    d_e = before.residual_power - after.residual_power
    delta = after.p - before.p
    c = (4.0 if before.real else 2.0) * before.correlation
    var = float(np.sum(c * before.w**2 * np.abs(delta) ** 2 * before.s))
    if var <= 0.0:
        return 0.0 if d_e <= 0 else float("inf")
    return float(d_e / math.sqrt(var))


def _concat(part: str, items, denominator, real=False, correlation=1.0) -> PartEvaluation:
    ys, ps, ss, ws = zip(*items) if items else ((), (), (), ())
    cat = (lambda xs: np.concatenate([np.ravel(x) for x in xs])) if items else (lambda xs: np.zeros(0))
    return PartEvaluation(part, cat(ys), cat(ps), cat(ss), cat(ws), float(denominator), real, correlation)
