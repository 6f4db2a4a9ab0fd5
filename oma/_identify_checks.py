"""Checks of the records :func:`oma.identify.identify` is given (one pose, long enough) and of
what it finds (modes inside the band the records resolve, agreement with the H1 fit, samples
left out).

Private module. The record checks raise :class:`~oma.errors.RecordError` (one line naming the
file, the field, what was expected and what was found; exit code 2 at the CLI); the result checks
return warnings, and a model that fails one is not trusted.
"""

from __future__ import annotations

import numpy as np

from .errors import RecordError
from .fit import relative_fit_error
from .spectra import default_nperseg
from .timefit import MIN_CYCLES, RESOLVED_BAND_FRACTION, resolved_band_hz
from ._timefit_artefacts import MAX_ROUNDS

__all__ = ["SAME_POSE_TOLERANCE_DEG", "HARMONIC_CLEARANCE_LINES", "H1_DISAGREEMENT", "H1_DISAGREEMENT_FLOOR",
           "check_same_pose", "min_samples_for_harmonics", "check_duration", "h1_misfit", "h1_disagreement",
           "keep_in_band", "artefact_warnings"]

AXES = ("X", "Y", "Z")

#: Largest difference of any joint angle between records identified together, degrees. A robot's
#: tool-tip modes move by about +-50 % over its workspace (DOMAIN.md), i.e. by well under 1 % per
#: degree of joint motion: records within 1 deg of each other share their modes to within the
#: identification's own accuracy, while the rounding of joint angles in files (0.01 deg) and the
#: arm's motion along a short cut stay inside it.
SAME_POSE_TOLERANCE_DEG = 1.0

#: Welch lines per spindle period of the force spectrum that the harmonics step needs: the
#: harmonics and background steps remove +-3 lines around every spindle multiple
#: (:func:`oma.harmonics.default_half_width_hz`), so 8 lines per spindle period leave at least one
#: line of background force between two neighbouring harmonics.
HARMONIC_CLEARANCE_LINES = 8


def _wrapped_deg(d):
    """Angle differences folded into [-180, 180) degrees."""
    return (np.asarray(d, dtype=float) + 180.0) % 360.0 - 180.0


def check_same_pose(records) -> None:
    """Raise :class:`RecordError` when a record's ``robot.joints_deg`` differs from the first
    record that gives one by more than :data:`SAME_POSE_TOLERANCE_DEG` in any joint.

    Records without a pose are not checked (nothing to compare).
    """
    ref = next(((i, r) for i, r in enumerate(records) if r.joints_deg is not None), None)
    if ref is None:
        return
    i_ref, first = ref
    q0 = np.asarray(first.joints_deg, dtype=float)
    for r in records[i_ref + 1:]:
        if r.joints_deg is None:
            continue
        q = np.asarray(r.joints_deg, dtype=float)
        if q.shape != q0.shape:
            raise RecordError(r.path, "robot.joints_deg", f"{q0.size} joint angles like the first record",
                              f"{q.size}")
        d = np.abs(_wrapped_deg(q - q0))
        if np.max(d) > SAME_POSE_TOLERANCE_DEG:
            j = int(np.argmax(d))
            pose0 = ", ".join(f"{v:g}" for v in q0)
            pose = ", ".join(f"{v:g}" for v in q)
            raise RecordError(
                r.path, "robot.joints_deg",
                f"the pose of {first.path or first.name or 'the first record'} ([{pose0}] deg) within "
                f"{SAME_POSE_TOLERANCE_DEG:g} deg per joint: records identified together must share a pose",
                f"[{pose}] deg (joint {j + 1} differs by {d[j]:.1f} deg)")


def min_samples_for_harmonics(sample_rate_hz: float, spindle_hz: float) -> int:
    """Fewest samples of a cut window whose force spectrum (default Welch segments,
    :func:`oma.spectra.default_nperseg`) has :data:`HARMONIC_CLEARANCE_LINES` lines per spindle
    period."""
    need = HARMONIC_CLEARANCE_LINES * sample_rate_hz / spindle_hz  # segment length, samples
    n = max(int(np.ceil(2.0 * np.sqrt(2.0) * need)), 16)  # default_nperseg ~ n / 4, rounded to a power of 2
    while default_nperseg(n) < need:
        n += 1
    while n > 16 and default_nperseg(n - 1) >= need:
        n -= 1
    return n


def check_duration(record, n_samples: int) -> None:
    """Raise :class:`RecordError` when the cut window (``n_samples`` long) is too short for the
    force spectrum to tell the milling harmonics from the background force
    (:func:`min_samples_for_harmonics`). Records without a spindle speed are not checked."""
    rpm = record.cut.spindle_rpm
    if rpm is None or not rpm > 0:
        return
    fs = float(record.sample_rate_hz)
    spindle_hz = float(rpm) / 60.0
    need = min_samples_for_harmonics(fs, spindle_hz)
    if n_samples < need:
        raise RecordError(
            record.path, "cut.window_s",
            f"at least {need / fs:.3g} s of cut window to tell the background force from the milling harmonics "
            f"({spindle_hz:.1f} Hz apart) in the force spectrum",
            f"{n_samples / fs:.3g} s (record too short)")


# --------------------------------------------------------------------------- what was found
#: Cross-check of an unquantised time-domain fit (records whose Welch lines resolve the modes): it
#: is replaced by the H1 fit when, on some axis, it misses the H1 estimate more than this many
#: times as much as the H1 fit does, and by :data:`H1_DISAGREEMENT_FLOOR` more. Without rounding
#: the two estimate the same FRF and agree to within their random errors (the audit's 10 s
#: records: 0.5 % against 0.5-2.8 %); a fit led astray by a record's edge artefacts missed it by
#: 11-27 % against 0.5 %. (Rounded displacement is not cross-checked: its H1 estimate is itself
#: biased, :mod:`oma.quantised`.)
H1_DISAGREEMENT = 3.0
H1_DISAGREEMENT_FLOOR = 0.05


def h1_misfit(model, est, weights, band) -> np.ndarray:
    """Relative misfit per axis of ``model`` against the H1 estimate ``est``: direct entries,
    weighted by ``weights`` (the inverse random error), in ``band`` (Hz); NaN for axes not
    measured."""
    f = est.freq_hz
    sel = (f >= band[0]) & (f <= band[1])
    g = model.receptance(f[sel])
    out = np.full(3, np.nan)
    for a in range(3):
        if est.table.measured[a, a]:
            out[a] = float(relative_fit_error(est.receptance_m_N[a, a, sel], g[a, a], weights[a, a, sel]))
    return out


def h1_disagreement(time_model, h1_model, est, weights, band) -> str | None:
    """The warning when an unquantised time-domain model misses the H1 estimate far more than the
    H1 model does (:data:`H1_DISAGREEMENT`); None when they agree."""
    e_time, e_h1 = h1_misfit(time_model, est, weights, band), h1_misfit(h1_model, est, weights, band)
    worse = (e_time > H1_DISAGREEMENT * e_h1) & (e_time - e_h1 > H1_DISAGREEMENT_FLOOR)
    if not np.any(worse):
        return None
    axes = ", ".join(f"{AXES[a]} {100 * e_time[a]:.1f} % against {100 * e_h1[a]:.1f} %" for a in np.flatnonzero(worse))
    modes = ", ".join(f"{v:.2f}" for v in time_model.natural_frequency_hz)
    return (f"the time-domain fit ({modes} Hz) misses the H1 estimate far more than the H1 fit does ({axes}): "
            "the records hold response the time-domain model cannot follow (artefacts it did not find, or modes "
            "above the band the records resolve); the H1 fit is reported")


def keep_in_band(model, time_fit, sample_rate_hz: float):
    """The model without modes outside the band the records resolve, and the warnings.

    The time-domain fit (``time_fit``, None when its model is not the one reported) pins a mode
    that response from outside the band needs at the band's end and leaves it out of its model
    (:attr:`oma.timefit.TimeFit.above_band_hz`); any mode above :func:`oma.timefit.resolved_band_hz`
    (an H1 fit's) is dropped here. Every such mode gives a warning: the model is not trusted.

    Raises
    ------
    ValueError
        Every mode lies above the band.
    """
    f_top = resolved_band_hz(sample_rate_hz)
    above = list(time_fit.above_band_hz) if time_fit is not None else []
    below = list(time_fit.below_band_hz) if time_fit is not None else []
    out = model.natural_frequency_hz > f_top
    if np.all(out) and out.size:
        raise ValueError(f"every identified mode lies above {f_top:.0f} Hz, the highest natural frequency "
                         f"records sampled at {sample_rate_hz:g} Hz resolve")
    if np.any(out):
        above += [float(v) for v in model.natural_frequency_hz[out]]
        keep = ~out
        model = model.with_modes(natural_frequency_hz=model.natural_frequency_hz[keep],
                                 damping_ratio=model.damping_ratio[keep], stiffness_N_m=model.stiffness_N_m[keep],
                                 directions=model.directions[keep])
    warnings = []
    if below:
        warnings.append(
            f"the fit needed {len(below)} mode(s) at the bottom of the band the records resolve "
            f"({time_fit.band_hz[0]:.2f} Hz: {MIN_CYCLES:g} cycles in the longest record) for slow response no "
            "mode in the band explains (drift, or artefacts at the records' ends); left out of the model")
    if above:
        warnings.append(
            f"the records respond to modes above {f_top:.0f} Hz ({RESOLVED_BAND_FRACTION:g} x the "
            f"{sample_rate_hz:g} Hz sample rate, where the anti-alias filter begins), which they cannot identify: "
            f"the fit needed {len(above)} mode(s) there ({', '.join(f'{v:.0f}' for v in above)} Hz), left out of "
            "the model. Spindle and tool modes belong in a separate model from a tap test (tool_mode.yaml; "
            "--tool-model), or record faster")
    return model, warnings


def artefact_warnings(artefacts, names, sample_rate_hz: float) -> list[str]:
    """Warnings naming the samples left out of the time-domain fit
    (:class:`oma._timefit_artefacts.Artefacts`)."""
    out = []
    for i, name in enumerate(names):
        if artefacts.share(i) > 0:
            out.append(
                f"{name}: {int(np.sum(artefacts.excluded[i]))} samples ({100 * artefacts.share(i):.1f} %) "
                f"{artefacts.where(i, sample_rate_hz)} are far from anything the model explains (up to "
                f"{artefacts.peak_sd:.0f} robust sd of the residual): spikes, dropouts or edge artefacts (as a "
                "derivative or integral taken with the FFT leaves at a record's ends); left out of the "
                "time-domain fit")
    if not artefacts.resolved:
        out.append(f"the time-domain fit still leaves outlying samples after {MAX_ROUNDS} refits")
    return out
