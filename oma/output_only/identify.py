"""``robomill identify --output-only``: modes from the response, stiffness from the force model.

Chain: the motion channels of each record inside its cut window (displacement, velocity or
acceleration, as recorded) -> harmonics out, SSI-cov, modes with jackknife intervals
(:mod:`oma.output_only.modes`) -> the tooth-passing lines of the response against the force
model's prediction of the same lines -> stiffness with its uncertainty
(:mod:`oma.output_only.scaling`) -> a ``robomill-modal/1`` model. When the records also carry
force, the same records can be identified the force-based way and the two compared
(:func:`compare_models`): a check of the cutting coefficients.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple, Sequence

import numpy as np
from scipy import stats

from .._identify_checks import check_same_pose
from ..decimation import analysis_factor, decimated
from ..errors import RecordError
from ..modal import ModalModel
from ..record import Record
from ..signals import constant_rows, window_slice
from ..timefit import resolved_band_hz
from ._ml_inference import (COMPLEX_MIN, COMPLEX_P, COMPLEX_RESCUE_P,  # noqa: F401 (the thresholds, re-exported)
                            _complex_named)
from .background import (ANISOTROPY_LOG_SD, BackgroundLevel, background_level, consistent_up_to_colour,
                         scale_by_background)
from .coverage import unexplained_peaks
from .harmonics import STEADY_SEGMENTS, WINDOW_LINE_TO_NOISE, cutting_window, strongest_line_hz
from .mass_line import mass_line_directions, mass_line_levels
from .modes import OutputOnlyModes, output_only_modes
from .resolution import unresolved_modes
from .scaling import StiffnessScaling, line_misfit, scale_modes, tooth_force_harmonics, with_spindle

__all__ = ["OutputOnlyIdentification", "identify_output_only", "compare_models", "MOTION_QUANTITIES"]

MOTION_QUANTITIES = ("displacement", "velocity", "acceleration")
#: Damping below which a mode is suspected to be a tone (warning only).
LOW_DAMPING = 0.005
#: Reduced chi-square of the response lines against the scaled model above which the lines are
#: said to disagree with the force model (a warning) and the model is not trusted.
MAX_LINE_MISFIT = 4.0
#: The tooth-passing lines above those that scaled the modes (up to 0.3 fs) are said to carry the
#: response of modes above the band when, against the scaled model's prediction, their reduced
#: chi-square exceeds :data:`MAX_LINE_MISFIT` and on some axis ``||x - G F|| / ||G F||`` exceeds
#: this (:func:`oma.output_only.scaling.line_misfit`). Measured on 20 s records of the example
#: cell at 2700 rpm (lines at 180 and 270 Hz; tracker and acceleration, seeds 1-3): without modes
#: above the band chi-square 0.8-1.9 (the ratio reaches 4 on Z, whose lines are noise there); with
#: the example's tool modes (720 / 735 Hz) chi-square 56-5600 and the ratio 5.5-6.3 on X and Y.
LINE_DISCREPANCY = 0.5
#: The mass lines' fit (:mod:`oma.output_only.mass_line`) gives the background's scale only where
#: its deviance ratio is at most this; else the resonances' levels do. Measured (session 18, 60
#: benchmark records of the tooth, runout and on-mode cases): 1.00-1.22.
MAX_MASS_LINE_MISFIT = 1.5
#: A mode whose direction's standard error exceeds this (degrees) is not pinned by the record and
#: leaves the model untrusted: its ``u u^T / k`` could point anywhere in a cone of twice this.
#: Measured (session 19): the true modes of 120 benchmark records (six structures, 20 s
#: accelerations) at most 23.8 (the close pair's Z; median of the records' largest 10.6); the
#: independent generator's 66 acceleration, 12 velocity and 12 displacement records under 25
#: (90 % under 13.4), but for a false 12.5 Hz mode beside the close pair (44, 2 % sensor noise);
#: on the real Hurco files 30-68 on tones and near-duplicates (e.g. 494.6 / 496.7 Hz, 58 / 68).
MAX_DIRECTION_SE_DEG = 30.0
#: A mode drifted during the cut (DOMAIN.md's pose drift) when its frequency refitted on the
#: records' first and second halves (``OutputOnlyModes.half_freq_hz``) differs by more than this
#: many standard errors of the difference (taken as twice the full record's: each half has half
#: the data) and by more than :data:`DRIFT_WIDTHS` half-power half-widths ``zeta f``. Measured
#: (session 26): on 132 modes of stationary benchmark records the difference's z-scores had an rms
#: of 0.95 and reached 4.1 (the oblique probe's 12 Hz mode, whose halves identified alone differ
#: by 3.1 errors); with every frequency drifting by 15 % over the record (``bench_oma_drift.py``)
#: each record's largest was 6.6-7.4, by 10 % 4.4-4.6.
DRIFT_Z = 5.0
#: ... and the halves' frequencies differ by more than this many ``zeta f``: the peak smeared by
#: more than its width, so that the damping read from it is the drift's (at 15 % drift the flagged
#: modes' differences were 1.5-1.8 half-widths).
DRIFT_WIDTHS = 1.0
AXES = ("X", "Y", "Z")


@dataclass(frozen=True)
class OutputOnlyIdentification:
    """Result of :func:`identify_output_only`.

    Attributes
    ----------
    model : ModalModel
        Frequencies, damping, directions from the response; stiffness from the force model (NaN
        for a mode that could not be scaled).
    modes : OutputOnlyModes
        With the jackknife intervals of frequency and damping.
    scaling : str
        ``force_model``, ``measured_force`` or ``none``.
    stiffness : StiffnessScaling or None
    trusted : bool
    warnings : tuple of str
    quantity : str
        What the records carried.
    background : BackgroundLevel or None
        The background force's level from the modes the lines scale, when it scaled a mode they
        could not (:mod:`oma.output_only.background`).
    scaled_by : tuple of str
        Per mode: ``'lines'``, ``'background'`` (the lines scale it poorly) or ``'none'``.
    sample_rate_hz : float
        The records' rate, Hz (the background force's white variance is given at it).
    lines_scaling : StiffnessScaling or None
        With ``background``: what the lines alone gave (``stiffness`` has the background's values
        for the modes it scaled).
    unexplained_peaks : tuple of UnexplainedPeak
        Peaks of the residual spectra no identified mode explains (:mod:`oma.output_only.coverage`);
        any leaves the model untrusted.
    unresolved_modes : tuple of UnresolvedMode
        Modes whose band holds a second shape of response, two modes taken for one
        (:mod:`oma.output_only.resolution`); any leaves the model untrusted.
    undetermined_directions : tuple of int
        Modes whose direction's standard error exceeds :data:`MAX_DIRECTION_SE_DEG`; any leaves the
        model untrusted.
    drifting_modes : tuple of int
        Modes whose frequency moved between the records' halves (:data:`DRIFT_Z`,
        :data:`DRIFT_WIDTHS`); any leaves the model untrusted.
    complex_modes : tuple of int
        Modes whose directions the score test finds complex (:data:`COMPLEX_P`,
        :data:`COMPLEX_MIN`), and those refitted with complex directions where the real fit had
        taken a mode out of its band (:data:`COMPLEX_RESCUE_P`); any leaves the model untrusted.
    analysis_rate_hz : float
        The rate the records were analysed at, Hz: theirs, or lower where they were decimated
        (:mod:`oma.decimation`).
    directions_source : str
        Where the model's directions come from: ``'resonance band'`` (those of ``modes``) or
        ``'mass lines'`` (turned by :func:`oma.output_only.mass_line.mass_line_directions`, and
        the lines solved with them).
    """

    model: ModalModel
    modes: OutputOnlyModes = field(repr=False)
    scaling: str
    stiffness: StiffnessScaling | None = field(repr=False)
    trusted: bool
    warnings: tuple
    quantity: str
    background: BackgroundLevel | None = field(default=None, repr=False)
    scaled_by: tuple = ()
    sample_rate_hz: float = float("nan")
    lines_scaling: StiffnessScaling | None = field(default=None, repr=False)
    unexplained_peaks: tuple = ()
    unresolved_modes: tuple = ()
    undetermined_directions: tuple = ()
    directions_source: str = "resonance band"
    drifting_modes: tuple = ()
    complex_modes: tuple = ()
    analysis_rate_hz: float = float("nan")

    @property
    def scaled(self) -> bool:
        return self.stiffness is not None and bool(np.all(np.isfinite(self.model.stiffness_N_m)))

    def plot(self, ax=None, **kwargs):
        """The modes with their intervals and the milling lines (:meth:`OutputOnlyModes.plot`)."""
        return self.modes.plot(ax=ax, **kwargs)

    def to_dict(self) -> dict[str, Any]:
        """The ``identify --output-only --json`` object (cli.md keys plus the intervals)."""
        from ..identify import modal_mapping

        # cli.md's identify keys that need a force channel are there, null: the FRF fit error, the
        # background noise variances and the excitation check describe a force-based fit (with force
        # channels, the CLI adds that fit under ``force_based``); no modes: no model (an empty mode
        # list is not a robomill-modal/1 model)
        out: dict[str, Any] = {"model": modal_mapping(self.model) if self.model.n_modes else None,
                               "scaling": self.scaling, "trusted": bool(self.trusted),
                               "method": "output-only-ssi-cov", "quantity": self.quantity,
                               "frf_fit_error": None, "noise_variance_N2": None, "min_noise_variance_N2": None,
                               "excitation_sufficient": None}
        out.update(self.modes.to_dict())
        unc = self.stiffness.to_dict() if self.stiffness is not None else [
            {"stiffness_N_m": None, "relative_sd": None, "interval_N_m": [None, None]} for _ in range(self.model.n_modes)]
        out["stiffness_uncertainty"] = unc
        lines = self.lines_scaling.to_dict() if self.lines_scaling is not None else [None] * len(unc)
        for m, s, by, by_lines in zip(out["modes"], unc, self.scaled_by or ("none",) * len(unc), lines):
            s["scaled_by"] = by
            if by == "background" and by_lines is not None:
                s["lines"] = {key: by_lines[key] for key in ("stiffness_N_m", "statistical_relative_sd")}
            m["stiffness_uncertainty"] = s
        out["background_force"] = None if self.background is None else self.background.to_dict(self.sample_rate_hz)
        if self.stiffness is not None:
            out["scaling_misfit"] = float(self.stiffness.misfit)
            out["scaling_lines_hz"] = [float(f) for f in self.stiffness.lines_hz]
        out["unexplained_peaks"] = [{"axis": "XYZ"[p.channel], "freq_hz": p.freq_hz, "ratio_to_median": p.ratio}
                                    for p in self.unexplained_peaks]
        out["unresolved_modes"] = [u.to_dict() for u in self.unresolved_modes]
        # each entry of ``modes`` has the resonance band's direction; the model's are these
        out["directions_source"] = self.directions_source
        out["undetermined_directions"] = [
            {"freq_hz": float(self.modes.freq_hz[k]),
             "direction_standard_error_deg": float(np.degrees(self.modes.direction_se_rad[k]))}
            for k in self.undetermined_directions]
        z = _half_record_shift(self.modes)[1]
        out["drifting_modes"] = [
            {"freq_hz": float(self.modes.freq_hz[k]),
             "half_record_frequency_hz": [float(v) for v in self.modes.half_freq_hz[k]], "z": float(z[k])}
            for k in self.drifting_modes]
        out["complex_modes"] = [_complex_entry(self.modes, k) for k in self.complex_modes]
        out["analysis_rate_hz"] = float(self.analysis_rate_hz)
        out["warnings"] = list(self.warnings)
        return out


def _motion(record: Record):
    for quantity in MOTION_QUANTITIES:
        if record.has(quantity):
            sl = window_slice(record)
            return quantity, np.array(record.vector(quantity)[:, sl]), sl
    raise RecordError(record.path, "signals.columns", "displacement, velocity or acceleration channels", "none")


def identify_output_only(records: Sequence[Record], *, scaling: str = "force_model",
                         coefficient_relative_sd: float = 0.15, band_hz=(4.0, 100.0), n_segments: int = 10,
                         level: float = 0.95, refine_harmonics: bool = True, max_line_hz: float | None = None,
                         direction_sd: float | None = None, background_anisotropy: float | None = ANISOTROPY_LOG_SD,
                         decimate: bool = True, **mode_options) -> OutputOnlyIdentification:
    """Identify the tool-tip modal model from the vibration channels alone.

    Parameters
    ----------
    records : sequence of Record
        One pose; same sampling rate, same motion quantity and axes. Force channels, if present,
        are ignored unless ``scaling='measured_force'``.
    scaling : {'force_model', 'measured_force'}
        Force lines from the cutting-force model (the record's ``material.cutting_coefficients``
        and cut) or from the records' own force channels.
    coefficient_relative_sd : float
        Relative standard uncertainty of the cutting coefficients (carried into the stiffness
        one for one; 0 with ``measured_force``). DOMAIN.md: database coefficients are commonly
        10-30 % off.
    band_hz : (float, float)
        Band of the modes, Hz.
    n_segments : int
        Jackknife segments.
    level : float
        Coverage of all intervals.
    background_anisotropy : float or None
        A mode the tooth-passing lines scale poorly is also scaled by the background force's level
        found from the modes they scale well, allowing this log standard deviation of that level
        between directions (:mod:`oma.output_only.background`; default
        :data:`~oma.output_only.background.ANISOTROPY_LOG_SD`). None: not done.
    decimate : bool
        Records sampled far above what the analysis reads are decimated first
        (:mod:`oma.decimation`; the rate used is ``analysis_rate_hz``). False: the recorded
        rate throughout.
    """
    if scaling not in ("force_model", "measured_force"):
        raise ValueError(f"scaling must be 'force_model' or 'measured_force', not {scaling!r}")
    records = list(records)
    if not records:
        raise ValueError("identify needs at least one record")
    check_same_pose(records)  # cli.md: records of one pose
    recorded_fs = float(records[0].sample_rate_hz)
    q = analysis_factor(records, band_hz, max_line_hz=max_line_hz,
                        alias_up_to=mode_options.get("alias_up_to", 0.5)) if decimate else 1
    records = [decimated(r, q) for r in records]
    fs = float(records[0].sample_rate_hz)
    warnings: list[str] = []
    quantity, signals, slices, axes = _motion_signals(records, fs, warnings)
    rpm = [r.cut.spindle_rpm for r in records]
    teeth = [r.tool.teeth for r in records]
    signals, slices = _cut_windows(records, signals, slices, axes, fs, rpm, teeth, warnings)
    for r, v in zip(records, rpm):
        if v is None or not v > 0:
            warnings.append(f"{r.name or 'record'}: no spindle speed; milling harmonics not removed")
    try:
        modes = output_only_modes(signals, fs, rpm, teeth, band_hz=band_hz, n_segments=n_segments, level=level,
                                  refine_harmonics=refine_harmonics,
                                  **{"derivative": MOTION_QUANTITIES.index(quantity), **mode_options})
    except RecordError as exc:
        if exc.file is not None:
            raise
        # the analysis knows signals, not files: the shortest record is the one too short
        short = min(range(len(records)), key=lambda i: signals[i].shape[1])
        raise RecordError(records[short].path, exc.field, exc.expected,
                          f"{signals[short].shape[1] / fs:.3g} s of cut window (record too short)") from None
    warnings += list(modes.warnings)
    checks = _checked(records, modes, fs, axes, quantity, warnings)
    if modes.n_modes == 0:
        warnings.append("no mode found in the response")
        sc = _Scaled(None, "none", None, None, np.zeros(0, dtype=bool), False, None, "resonance band")
    else:
        top = max_line_hz if max_line_hz is not None else 1.5 * band_hz[1]   # the scaling lines' limit
        sc = _scaled(records, slices, modes, quantity, axes, scaling, coefficient_relative_sd, level, top,
                     direction_sd, background_anisotropy, checks, fs, warnings)
    stiffness = sc.stiffness
    k = stiffness.stiffness_N_m if stiffness is not None else np.full(modes.n_modes, np.nan)
    names = [r.name or f"record {i}" for i, r in enumerate(records)]
    # lines the model does not explain (a mode too weak in the record for SSI to find, session 11:
    # a 17 Hz mode under a tracker's rounding, the other two scaled "trusted") are not trusted
    trusted = bool(modes.n_modes > 0 and stiffness is not None and not np.any(stiffness.too_far)
                   and np.all(np.isfinite(k)) and np.all(np.isfinite(modes.damping_se))
                   and not stiffness.misfit > MAX_LINE_MISFIT and not sc.above and not checks.unsteady
                   and not np.any(modes.damping_ratio < LOW_DAMPING) and not checks.peaks and not checks.unresolved
                   and not checks.loose.size and not checks.drifting.size and not checks.complex.size
                   and not sc.levels_disagree)
    if not trusted:
        warnings.append("the identified model is NOT trusted (see the warnings above)")
    model = ModalModel(
        natural_frequency_hz=modes.freq_hz, damping_ratio=modes.damping_ratio,
        stiffness_N_m=k if k.size else np.zeros(0),
        directions=(stiffness.directions if stiffness is not None and stiffness.directions is not None
                    else modes.directions).reshape(-1, 3),
        joints_deg=next((r.joints_deg for r in records if r.joints_deg is not None), None),
        source={"method": "oma-output-only-ssi-cov", "scaling": sc.used, "records": names, "trusted": trusted},
    ) if modes.n_modes else ModalModel(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 3)),
                                       source={"method": "oma-output-only-ssi-cov", "records": names})
    scaled_by = tuple("none" if not np.isfinite(kk) else "background" if bg else "lines"
                      for kk, bg in zip(k, sc.by_background))
    return OutputOnlyIdentification(model=model, modes=modes, scaling=sc.used, stiffness=stiffness, trusted=trusted,
                                    warnings=tuple(warnings), quantity=quantity, background=sc.background,
                                    scaled_by=scaled_by, sample_rate_hz=recorded_fs, analysis_rate_hz=fs,
                                    lines_scaling=sc.lines_scaling if sc.background is not None else None,
                                    unexplained_peaks=tuple(checks.peaks), unresolved_modes=tuple(checks.unresolved),
                                    undetermined_directions=tuple(int(k) for k in checks.loose),
                                    directions_source=sc.directions_source,
                                    drifting_modes=tuple(int(k) for k in checks.drifting),
                                    complex_modes=tuple(int(k) for k in checks.complex))


def _motion_signals(records, fs, warnings):
    """The motion channels of every record inside its cut window (constant ones as not recorded):
    their quantity, the signals (3, n) with NaN rows for axes not recorded, the slices taken and
    the recorded axes. Records that differ in rate, quantity or axes are a :class:`RecordError`."""
    quantity = None
    signals, slices = [], []
    for r in records:
        if abs(r.sample_rate_hz - fs) > 1e-9 * fs:
            raise RecordError(r.path, "sample_rate_hz", f"{fs} Hz like the first record", f"{r.sample_rate_hz} Hz")
        q, y, sl = _motion(r)
        if quantity is None:
            quantity = q
        elif q != quantity:
            raise RecordError(r.path, "signals.columns", f"{quantity} channels like the first record", q)
        signals.append(y)
        slices.append(sl)
    for r, y in zip(records, signals):
        # a channel that never moves carries nothing (a dead sensor, a cable off): as not recorded
        # (session 23: an all-zero Z channel had raised an internal error in the channel scaling)
        dead = constant_rows(y)
        for a in np.flatnonzero(dead):
            warnings.append(f"{r.name or 'record'}: the {'XYZ'[a]} motion channel is constant (a dead sensor or a "
                            "disconnected cable?): taken as not recorded")
        y[dead] = np.nan
    axes = ~np.all(np.isnan(signals[0]), axis=1)
    for r, y in zip(records, signals):
        if not np.array_equal(~np.all(np.isnan(y), axis=1), axes):
            raise RecordError(r.path, "signals.columns", "motion along the same axes as the first record",
                              "other axes")
    if not axes.any():
        raise RecordError(records[0].path, "signals.columns", "a motion channel that moves", "only constant ones")
    if not axes.all():
        missing = ", ".join(a for a, ok in zip("XYZ", axes) if not ok)
        warnings.append(f"no {missing} channel in the records: modes that move only along {missing} are not seen, "
                        f"and the model holds no flexibility along {missing} (the modes' directions are measured "
                        "in the recorded axes only)")
    return quantity, signals, slices, axes


def _cut_windows(records, signals, slices, axes, fs, rpm, teeth, warnings):
    """The signals and slices cut to where the tool cuts.

    A record that does not cut throughout (entry, exit; no window_s given) has the tooth lines'
    amplitude of the cut over part of it only, so the lines and the modes are taken over the cut
    found from the tooth line's envelope (audit of session 15: +41-52 % stiffness); found from the
    recorded axes (session 23: a record without a Z channel, whose Z row is NaN, had raised an
    internal error here)."""
    signals, slices = list(signals), list(slices)
    for i, (r, v, z) in enumerate(zip(records, rpm, teeth)):
        info: dict = {}
        win = cutting_window(signals[i][axes], fs, v, z, info=info) if v is not None and v > 0 else None
        if info.get("line_to_noise", np.inf) < WINDOW_LINE_TO_NOISE:
            warnings.append(f"{r.name or 'record'}: the tooth-passing line stands only {info['line_to_noise']:.1f} "
                            "times over the noise beside it, too weak to tell whether the tool cuts throughout: the "
                            "whole record is used (give cut.window_s if the tool does not cut throughout)")
        if win is None:
            continue
        a, b = win
        start = slices[i].start or 0
        signals[i] = signals[i][:, a:b]
        slices[i] = slice(start + a, start + b)
        t0 = float(r.time[0]) if r.n_samples else 0.0
        warnings.append(f"{r.name or 'record'}: the tooth-passing line is present only from {t0 + (start + a) / fs:.2f} "
                        f"to {t0 + (start + b) / fs:.2f} s of the record (the tool not cutting outside): modes and "
                        "stiffness taken over that window; give cut.window_s to choose it")
    return signals, slices


class _Checks(NamedTuple):
    """What :func:`_checked` found in the identified modes, and the residuals it read."""

    unsteady: list          # records whose tooth line is not steady
    peaks: list             # residual peaks no mode explains
    unresolved: list        # modes whose band holds a second shape
    loose: np.ndarray       # indices of modes whose direction the record does not pin
    drifting: np.ndarray    # indices of modes whose frequency moved between the records' halves
    complex: np.ndarray     # indices of modes whose directions are complex
    residuals: list
    lines: np.ndarray


def _checked(records, modes: OutputOnlyModes, fs, axes, quantity, warnings) -> _Checks:
    """The checks of the modes that decide trust, each with its warning: unsteady milling lines,
    tones, residual peaks no mode explains, modes that hold two, directions the record does not
    pin, modes that drifted during the cut, modes whose directions are complex."""
    unsteady = [h for h in modes.harmonics if not h.steady]
    for r, h in zip(records, modes.harmonics):
        st = h.steadiness
        if h.tracked:
            warnings.append(f"{r.name or 'record'}: the spindle speed varied by {100 * h.speed_variation:.2f} % over "
                            "the record; the milling lines were fitted as orders of the tracked spindle angle")
        if not h.steady:
            warnings.append(
                f"{r.name or 'record'}: the tooth-passing line at {st['line_hz']:.1f} Hz is not steady over the "
                f"record (its amplitude on {STEADY_SEGMENTS} segments spreads by {100 * st['spread']:.0f} %, the "
                f"whole-record fit captures {100 * (1 - st['loss']):.0f} % of it): speed or cut not constant; the "
                "stiffnesses are not reliable")
    if modes.rejected_hz.size:
        warnings.append("stable poles at milling lines taken for harmonics, not modes: "
                        + ", ".join(f"{f:.2f} Hz" for f in modes.rejected_hz))
    for f, z in zip(modes.freq_hz, modes.damping_ratio):
        if z < LOW_DAMPING:
            warnings.append(f"mode at {f:.2f} Hz has {100 * z:.2f} % damping: a tone, not a robot mode (robot modes "
                            "have 2-10 %): chatter (a self-excited vibration near a mode, which also hides that "
                            "mode), a milling line not removed, or an electrical line; the model is not trusted")
    # a peak of a channel's spectrum that no mode explains (a mode SSI missed: session 16, one 5 s
    # record in twelve of an independent generator lost a 17 Hz Z mode and was trusted)
    residuals = [h.residual for h in modes.harmonics]
    lines = np.concatenate([h.freq_hz for h in modes.harmonics])
    wander = max(h.speed_variation for h in modes.harmonics)
    identified = (fs, modes.band_hz, modes.freq_hz, modes.damping_ratio, lines)
    peaks = unexplained_peaks(residuals, *identified, line_relative_halfwidth=wander, axes=np.flatnonzero(axes))
    warnings += [pk.describe() for pk in peaks]
    # a mode whose band holds two shapes of response: two modes taken for one (session 17: the
    # 10.0 / 10.5 Hz pair merged in 29 of 60 5 s records of the audit's generator, 7 trusted)
    unresolved = unresolved_modes(residuals, *identified, derivative=MOTION_QUANTITIES.index(quantity),
                                  line_relative_halfwidth=wander)
    warnings += [u.describe() for u in unresolved]
    # a mode whose direction the record does not pin (session 19: a false mode on one record of an
    # independent generator, its direction uncertain by 44 degrees, left X and Z unscalable by the
    # lines, with no warning naming it)
    loose = np.flatnonzero(np.nan_to_num(np.degrees(modes.direction_se_rad), nan=0.0) > MAX_DIRECTION_SE_DEG)
    for k in loose:
        warnings.append(f"mode at {modes.freq_hz[k]:.2f} Hz: its direction is uncertain by "
                        f"{np.degrees(modes.direction_se_rad[k]):.0f} degrees (standard error, more than "
                        f"{MAX_DIRECTION_SE_DEG:.0f}): the record does not pin it (a spurious mode, one mode taken "
                        "for two, or a tone); the model is not trusted")
    # a mode whose frequency moved between the records' halves: the modes drifted during the cut
    # (DOMAIN.md's pose drift; session 26: with every frequency drifting by 15 % over a 20 s
    # record, damping came out 9-33 % high in the median, frequencies up to 4.9 % off and 2 of 18
    # modes were lost, with no word of why)
    shift, z = _half_record_shift(modes)
    with np.errstate(invalid="ignore"):
        drifting = np.flatnonzero((np.abs(z) > DRIFT_Z)
                                  & (np.abs(shift) > DRIFT_WIDTHS * modes.damping_ratio * modes.freq_hz))
    for k in drifting:
        f1, f2 = modes.half_freq_hz[k]
        warnings.append(f"mode at {modes.freq_hz[k]:.2f} Hz: {f1:.2f} Hz in the first half of the record and "
                        f"{f2:.2f} Hz in the second ({abs(z[k]):.1f} standard errors apart, more than its half-power "
                        "half-width): the modes drifted during the cut (the arm moving along it?); the values are "
                        "the record's mean, the damping is widened by the drift and the intervals are too narrow; "
                        "identify shorter stretches of the cut; the model is not trusted")
    # a mode whose directions are complex: the real-mode model's values and intervals do not hold
    # (session 27: ``bench_oma_independent.py``'s whirling pairs)
    complex_ = _complex_directions(modes)
    for k in complex_:
        stat, dof, cx, fitted = modes.complex_test[k]
        values = ("its frequency and damping come from its group refitted with complex directions; the model's "
                  "direction is a real one" if fitted == 1.0 else
                  "its values and intervals are those of a real mode and may not hold")
        warnings.append(f"mode at {modes.freq_hz[k]:.2f} Hz: its response has a phase between the channels that a "
                        f"real mode cannot have (score test of complex directions {stat:.1f} on {dof:.0f} degrees of "
                        f"freedom, p = {stats.chi2.sf(stat, dof):.1g}; complexity about {cx:.2f}): a damping that is "
                        f"not proportional, gyroscopic coupling or a forced response at the mode; {values}; the "
                        "model is not trusted")
    return _Checks(unsteady, peaks, unresolved, loose, drifting, complex_, residuals, lines)


def _complex_directions(modes: OutputOnlyModes) -> np.ndarray:
    """The modes whose directions are complex (:func:`oma.output_only._ml_inference._complex_named`),
    and those named at :data:`COMPLEX_RESCUE_P` whose group was carried on with complex directions
    (where its real fit took a mode out of its band)."""
    test = modes.complex_test.T
    return np.flatnonzero(_complex_named(test) | ((test[3] == 1.0) & _complex_named(test, COMPLEX_RESCUE_P)))


def _complex_entry(modes: OutputOnlyModes, k: int) -> dict:
    """A named complex mode's JSON entry."""
    stat, dof, cx, fitted = modes.complex_test[k]
    return {"freq_hz": float(modes.freq_hz[k]), "statistic": float(stat), "degrees_of_freedom": int(dof),
            "p_value": float(stats.chi2.sf(stat, dof)), "complexity": float(cx), "complex_fit": bool(fitted == 1.0)}


def _half_record_shift(modes: OutputOnlyModes) -> tuple[np.ndarray, np.ndarray]:
    """Per mode, its frequency refitted on the records' second half less that on the first (Hz),
    and that difference in its standard errors (twice the full record's frequency error); NaN
    where either half is missing."""
    shift = np.diff(modes.half_freq_hz, axis=1)[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        return shift, shift / (2.0 * modes.freq_se_hz)


class _Scaled(NamedTuple):
    """The modes' scale (:func:`_scaled`)."""

    stiffness: StiffnessScaling | None
    used: str                          # 'force_model', 'measured_force' or 'none'
    background: BackgroundLevel | None  # the background's level, where it scales a mode
    lines_scaling: StiffnessScaling | None  # the lines' own scaling, before the background's
    by_background: np.ndarray          # the modes scaled by the background's level
    levels_disagree: bool              # the background's levels along the modes the lines scale disagree
    above: str | None                  # the warning that lines above the band carry other modes
    directions_source: str             # 'resonance band' or 'mass lines'


def _scaled(records, slices, modes: OutputOnlyModes, quantity, axes, scaling, coefficient_relative_sd, level, top,
            direction_sd, background_anisotropy, checks: _Checks, fs, warnings) -> _Scaled:
    """The modes scaled by the tooth-passing lines (:func:`_scale`), those the lines scale poorly by
    the background force's level, each with its warnings."""
    by_background = np.zeros(modes.n_modes, dtype=bool)
    stiffness, why = _scale(records, slices, modes, quantity, axes, scaling, coefficient_relative_sd, level, top,
                            direction_sd)
    if stiffness is None:
        warnings.append(f"modes not scaled: {why}")
        return _Scaled(None, "none", None, None, by_background, False, None, "resonance band")
    residuals, lines = checks.residuals, checks.lines
    directions_source = "resonance band"
    levels, mass_lines = None, False
    if background_anisotropy is not None and modes.n_modes > 1:
        levels, mass_lines = _background_levels(residuals, fs, modes, axes, quantity, lines, stiffness.too_far, top)
        if mass_lines:
            # the lines solved again with the directions the mass lines turn, the background free to
            # differ between channels (session 19: the close pair's from the resonance band are tilted
            # by 5-30 degrees and a mode the lines scale takes the response of its tilted neighbour;
            # turned under the levels' isotropy instead, oblique modes came out 6-14 % soft under a
            # 20 % anisotropic background)
            turned = mass_line_directions(residuals, fs, modes.freq_hz, modes.damping_ratio,
                                          modes.directions[:, axes], modes.direction_se_rad,
                                          derivative=MOTION_QUANTITIES.index(quantity), lines_hz=lines,
                                          band_hz=(modes.band_hz[0], top))
            again = None if turned is None else _scale(
                records, slices, _with_directions(modes, axes, turned[0]), quantity, axes, scaling,
                coefficient_relative_sd, level, top, direction_sd)[0]
            if again is not None:
                stiffness, directions_source = again, "mass lines"
    for k in np.flatnonzero(stiffness.too_far):
        near = stiffness.lines_hz[np.argmin(np.abs(stiffness.lines_hz - modes.freq_hz[k]))]
        sd = stiffness.statistical_relative_sd[k]
        warnings.append(
            f"mode at {modes.freq_hz[k]:.2f} Hz: the tooth-passing lines (nearest {near:.1f} Hz) are too far "
            f"from it or force it too weakly to scale it well (stiffness uncertainty "
            + (f"{100 * sd:.0f} %" if np.isfinite(sd) and sd < 100 else "unbounded")
            + " from the data alone)")
    lines_scaling = stiffness
    background = None
    levels_disagree = False
    # the background's level along each mode the lines scale: it scales those they cannot, and where
    # they scale all, a level far off the others' says one of them is wrong (session 18: under a red
    # background the lines gave Z 73 % soft with a stated 19 %, trusted; its level came out 10x under
    # X's at the same frequency)
    if levels is not None:
        background = background_level(stiffness, *levels, anisotropy_log_sd=background_anisotropy,
                                      source="mass lines" if mass_lines else "resonances")
        if background is not None and np.any(stiffness.too_far):
            stiffness, by_background = scale_by_background(stiffness, background, *levels, level=level)
        if np.any(by_background):
            warnings += _background_warnings(background, modes, stiffness, by_background, fs, background_anisotropy)
        else:
            levels_disagree = background is not None and not (
                background.consistent if mass_lines else
                consistent_up_to_colour(background, modes.freq_hz, anisotropy_log_sd=background_anisotropy))
            if levels_disagree:
                warnings.append(_disagreement_warning(background, modes, fs, background_anisotropy))
            background = None
    if stiffness.misfit > MAX_LINE_MISFIT:
        warnings.append(f"the response lines disagree with the force model by more than their noise "
                        f"(reduced chi-square {stiffness.misfit:.1f}): coefficients, runout or a mode "
                        "missing from the model")
    above = _lines_above(records, slices, modes, quantity, axes, scaling, stiffness, top, fs)
    if above:
        warnings.append(above)
    return _Scaled(stiffness, scaling, background, lines_scaling, by_background, levels_disagree, above,
                   directions_source)


def _background_levels(residuals, fs, modes: OutputOnlyModes, axes, quantity, lines, too_far, top_hz):
    """The modes' input levels for the background's scale, and whether they come from the mass
    lines (:mod:`oma.output_only.mass_line`; not for displacements): those where the band outside the
    modes' resonances holds enough bins, the fit explains them (deviance ratio at most
    :data:`MAX_MASS_LINE_MISFIT`) and they measure every mode to be scaled (``too_far``) more
    precisely than its resonance does; else the resonances' (the refinement's). The band reaches
    up to ``top_hz``, as far as the lines that scale the modes (the model is taken to hold there)."""
    ml = mass_line_levels(residuals, fs, modes.freq_hz, modes.damping_ratio, modes.directions[:, axes],
                          modes.direction_se_rad, derivative=MOTION_QUANTITIES.index(quantity), lines_hz=lines,
                          band_hz=(modes.band_hz[0], top_hz)) if quantity != "displacement" else None
    resonances = (modes.input_level, modes.input_level_log_se)
    if ml is None or not ml.misfit <= MAX_MASS_LINE_MISFIT:
        return resonances, False
    # only where they measure the modes to scale better than the resonances do (a mode inside the
    # band leaves few bins clear of every resonance: session 18, a 60 Hz mode beside the paper's
    # cell left Z's level uncertain by 0.4-0.7 in log)
    target = np.asarray(too_far) & np.isfinite(modes.input_level_log_se)
    if not np.all(ml.input_level_log_se[target] < modes.input_level_log_se[target]):
        return resonances, False
    return (ml.input_level, ml.input_level_log_se), True


def _with_directions(modes: OutputOnlyModes, axes, directions) -> OutputOnlyModes:
    """``modes`` with their directions in the measured channels (``axes``) replaced by
    ``directions`` (n_modes, l), renormalised."""
    d = np.array(modes.directions, dtype=float)
    d[:, axes] = directions
    return replace(modes, directions=d / np.linalg.norm(d, axis=1, keepdims=True))


def _reference_levels(background: BackgroundLevel, modes: OutputOnlyModes, fs: float) -> str:
    """The scaled modes' background levels, as white-noise variances at the record's rate."""
    return ", ".join(f"{modes.freq_hz[r]:.2f} Hz {background.per_mode_psd_N2_Hz[r] * fs:.0f} N^2"
                     for r in background.reference)


def _disagreement_warning(background: BackgroundLevel, modes: OutputOnlyModes, fs: float, allowed: float) -> str:
    """Where every mode is scaled by the lines and their background levels disagree (``allowed``: the
    spread of log PSD the test allows)."""
    return (f"the background force's level (from the {background.source}) along the modes the lines scale differs "
            f"between them by more than their errors and a {100 * allowed:.0f} % spread explain "
            f"(as white-noise variances: {_reference_levels(background, modes, fs)}): a stiffness from the lines is "
            "wrong, or the background force is far stronger along some directions than others; the model is not "
            "trusted")


def _background_warnings(background: BackgroundLevel, modes: OutputOnlyModes, stiffness: StiffnessScaling,
                         by_background, fs: float, allowed: float) -> list[str]:
    """What the user must know about modes scaled by the background's level (``allowed``: the
    least spread of log PSD between directions, the consistency test's)."""
    ref = _reference_levels(background, modes, fs)
    out = []
    for t in np.flatnonzero(by_background):
        out.append(f"mode at {modes.freq_hz[t]:.2f} Hz scaled by the background force's level (from the "
                   f"{background.source}) instead of the lines: assumes the background force along it is as strong "
                   f"as along the modes the lines scale "
                   f"(as white-noise variances: {ref}); stiffness uncertainty "
                   f"{100 * stiffness.statistical_relative_sd[t]:.0f} % without the coefficients', of which "
                   f"{100 * background.anisotropy_log_sd / 2:.0f} % for that assumption, which the record cannot check")
    if not background.consistent:
        out.append("the background force's level differs between the modes the lines scale by more than their "
                   f"errors and a {100 * allowed:.0f} % spread explain: the modes scaled by it are "
                   "doubtful")
    return out


def _lines(records, slices, modes: OutputOnlyModes, quantity, scaling, select):
    """Per record with lines chosen by ``select(harmonics)`` (a mask): the indices of those
    records, and their lines' displacement amplitudes, noise, force, frequencies and spindle
    orders; ``(None, reason)`` when the force is not known."""
    order = {"displacement": 0, "velocity": 1, "acceleration": 2}[quantity]
    which, response, noise, force, lines, orders = [], [], [], [], [], []
    for i, (r, sl, h) in enumerate(zip(records, slices, modes.harmonics)):
        if h.freq_hz.size == 0:
            continue
        use = select(h)
        if not np.any(use):
            continue
        hz = h.freq_hz[use]
        h_orders = np.rint(hz / h.spindle_hz).astype(int)
        conv = (2j * np.pi * hz) ** order
        response.append(h.amplitude[:, use] / conv[None, :])
        noise.append(h.noise_amplitude[:, use] / np.abs(conv)[None, :])
        if scaling == "force_model":
            coef = r.material.cutting_coefficients if r.material is not None else None
            if coef is None:
                return None, f"{r.name or 'record'} has no material.cutting_coefficients"
            if r.cut.axial_depth_m is None:
                return None, f"{r.name or 'record'} has no cut.axial_depth_m"
            force.append(tooth_force_harmonics(r.tool, with_spindle(r.cut, h.spindle_hz), coef, h_orders))
        else:
            f_rec = np.array(r.force[:, sl])
            if np.any(np.all(np.isnan(f_rec), axis=1)):
                return None, f"{r.name or 'record'} lacks force channels for measured_force scaling"
            # in the basis the response's lines were fitted in (orders of the tracked spindle angle)
            force.append(h.line_amplitudes(f_rec, r.sample_rate_hz)[:, use])
            h_orders = np.zeros_like(h_orders)  # measured force: same clock, no unknown angle
        which.append(i)
        lines.append(hz)
        orders.append(h_orders)
    return (which, response, noise, force, lines, orders), ""


def _scaling_lines(max_line_hz):
    """The lines that scale the modes: significant tooth-passing lines up to ``max_line_hz``."""
    return lambda h: h.tooth_passing & h.significant & (h.freq_hz <= max_line_hz) & ~h.aliased


def _scale(records, slices, modes: OutputOnlyModes, quantity, axes, scaling, coef_sd, level, max_line_hz,
           direction_sd):
    """Per-record lines and forces, then :func:`scale_modes`; (None, reason) when impossible."""
    got, why = _lines(records, slices, modes, quantity, scaling, _scaling_lines(max_line_hz))
    if got is None:
        return None, why
    _, response, noise, force, lines, orders = got
    if not response:
        return None, _no_lines_reason(records, slices, modes)
    result = scale_modes(modes.freq_hz, modes.damping_ratio, modes.directions, response, noise, force, lines, orders,
                         axes=axes, freq_se_hz=modes.freq_se_hz, damping_se=modes.damping_se,
                         direction_se_rad=modes.direction_se_rad,
                         coefficient_relative_sd=coef_sd if scaling == "force_model" else 0.0, level=level,
                         direction_sd=direction_sd)
    return result, ""


def _no_lines_reason(records, slices, modes: OutputOnlyModes) -> str:
    """Why no tooth-passing line scaled the modes: none in the response, or the strongest line
    near the nominal tooth frequency is elsewhere (the record's rpm off by more than the +-5 %
    search) or smeared (the speed varied too much to track)."""
    for r, sl, h in zip(records, slices, modes.harmonics):
        if not h.nominal_spindle_hz > 0:
            continue
        tooth_hz = h.nominal_spindle_hz * h.teeth
        y = np.array(r.vector(next(q for q in MOTION_QUANTITIES if r.has(q)))[:, sl])
        peak, width = strongest_line_hz(y, r.sample_rate_hz, tooth_hz)
        if not np.isfinite(peak):
            continue
        off = peak / tooth_hz - 1.0
        if abs(off) > 0.05:
            return (f"no tooth-passing line at the nominal tooth frequency ({tooth_hz:.1f} Hz, "
                    f"{60 * h.nominal_spindle_hz:.0f} rpm, {h.teeth} teeth); the strongest line near it lies at "
                    f"{peak:.1f} Hz, {100 * off:+.1f} % from it: check the record's spindle_rpm")
        if width > 2.0:
            return (f"the strongest line near the tooth frequency ({peak:.1f} Hz, {100 * off:+.1f} % from the nominal "
                    f"{tooth_hz:.1f} Hz) is smeared over {width:.1f} Hz: the spindle speed varied too much over the "
                    "record to fit its lines; cut the record where the speed is steady (cut.window_s)")
    return "no tooth-passing line stands out of the response (no harmonics to scale with)"


def _lines_above(records, slices, modes: OutputOnlyModes, quantity, axes, scaling, stiffness: StiffnessScaling,
                 max_line_hz, fs) -> str | None:
    """The warning when the significant tooth-passing lines above those that scaled the modes (up
    to :func:`oma.timefit.resolved_band_hz`) disagree with the scaled modes' prediction
    (:func:`oma.output_only.scaling.line_misfit`: :data:`MAX_LINE_MISFIT` and
    :data:`LINE_DISCREPANCY`): response of modes above the band, which the lines that scaled the
    modes carry too; None when they agree or there are none."""
    top = resolved_band_hz(fs)
    got, _ = _lines(records, slices, modes, quantity, scaling,
                    lambda h: h.tooth_passing & h.significant & (h.freq_hz > max_line_hz) & (h.freq_hz <= top)
                    & ~h.aliased)
    if got is None or not got[0]:
        return None
    # the spindle angle of each record as the scaling found it: ``theta_rad`` is per record with
    # scaling lines, in order (those :func:`_lines` kept for :func:`_scale`; records without: none)
    select = _scaling_lines(max_line_hz)
    scaled = [i for i, h in enumerate(modes.harmonics) if h.freq_hz.size and np.any(select(h))]
    theta = dict(zip(scaled, stiffness.theta_rad))
    keep = [j for j, i in enumerate(got[0]) if i in theta]
    if not keep:
        return None
    response, noise, force, lines, orders = ([part[j] for j in keep] for part in got[1:])
    misfit, discrepancy = line_misfit(stiffness, modes.freq_hz, modes.damping_ratio, response, noise, force, lines,
                                      orders, [theta[got[0][j]] for j in keep], axes=axes,
                                      freq_se_hz=modes.freq_se_hz, damping_se=modes.damping_se,
                                      direction_se_rad=modes.direction_se_rad)
    off = np.nan_to_num(discrepancy, nan=0.0, posinf=np.inf) > LINE_DISCREPANCY
    if not (misfit > MAX_LINE_MISFIT and np.any(off)):
        return None
    measured = [AXES[a] for a in range(3) if axes[a]]
    worst = ", ".join(f"{v:.2g} ({a})" if np.isfinite(v) else f"unbounded ({a})"
                      for a, v, o in zip(measured, discrepancy, off) if o)
    hz = ", ".join(f"{v:.0f}" for v in np.unique(np.round(np.concatenate(lines))))
    return (f"the tooth-passing lines above those that scaled the modes ({hz} Hz) disagree with the scaled model "
            f"(reduced chi-square {misfit:.0f}; their difference from its prediction is {worst} times the "
            "prediction): the response of modes above the band (spindle and tool modes, above "
            f"{top:.0f} Hz, which records analysed at {fs:g} Hz cannot resolve), whose static compliance also loads "
            "the lines that scaled the modes: the stiffnesses are not reliable. Scale with the measured force "
            "(identify without --output-only, which estimates that compliance) and add those modes from a "
            "tool-tip tap test (tool_mode.yaml)")


def compare_models(output_only: ModalModel, reference: ModalModel, *, standard_errors=None,
                   reference_standard_errors=None) -> list[dict[str, Any]]:
    """Pair each output-only mode with the reference mode nearest in frequency and direction.

    Returns one entry per output-only mode: its frequency, the reference's, and the ratios of
    frequency, damping and stiffness (output-only over reference); ``None`` when nothing pairs
    (no reference mode within 10 % in frequency with ``|u . u_ref| > 0.7``). With the standard
    errors of both (``(frequency_se_hz, damping_se)`` per model, in mode order), also
    ``frequency_z`` and ``damping_z``: the difference over the combined standard error (|z| < 2:
    the two agree to their uncertainty).
    """
    def errors(se, n):
        if se is None:
            return np.full(n, np.nan), np.full(n, np.nan)
        f_se, z_se = (np.asarray(v, dtype=float) for v in se)
        ok = f_se.shape == (n,) and z_se.shape == (n,)
        return (f_se, z_se) if ok else (np.full(n, np.nan), np.full(n, np.nan))

    se_f, se_z = errors(standard_errors, output_only.n_modes)
    ref_f, ref_z = errors(reference_standard_errors, reference.n_modes)
    out = []
    for i, (f, z, k, u) in enumerate(zip(output_only.natural_frequency_hz, output_only.damping_ratio,
                                         output_only.stiffness_N_m, output_only.directions)):
        d = np.abs(reference.natural_frequency_hz / f - 1.0)
        ok = (d < 0.10) & (np.abs(reference.directions @ u) > 0.7)
        if not np.any(ok):
            out.append({"natural_frequency_hz": float(f), "reference": None})
            continue
        j = int(np.flatnonzero(ok)[np.argmin(d[ok])])
        entry = {
            "natural_frequency_hz": float(f), "reference_natural_frequency_hz": float(reference.natural_frequency_hz[j]),
            "frequency_ratio": float(f / reference.natural_frequency_hz[j]),
            "damping_ratio_ratio": float(z / reference.damping_ratio[j]),
            "stiffness_ratio": float(k / reference.stiffness_N_m[j]) if np.isfinite(k) else None,
        }
        for key, diff, a, b in (("frequency_z", f - reference.natural_frequency_hz[j], se_f[i], ref_f[j]),
                                ("damping_z", z - reference.damping_ratio[j], se_z[i], ref_z[j])):
            scale = float(np.hypot(a, b))
            entry[key] = float(diff / scale) if np.isfinite(scale) and scale > 0 else None
        out.append(entry)
    return out
