"""Practical floors: a cause is named only when it is big enough to change what an engineer does.

Statistical significance alone names effects of no consequence: on a long record the force
harmonics are measured so precisely that a size-effect exponent of -0.008 lowers the validation
error significantly (robomill issue 10). So beside ``z >= 3`` and the share of the error removed,
every cause's fitted size must exceed (1) twice its own standard error, where the fit gives one,
and (2) a floor argued from the prediction it changes (the reasons are in ``notes/diag.md`` and
the README):

=====================  ==========================================================  =========
cause                  size measured                                               floor
=====================  ==========================================================  =========
runout                 1x (spindle) line over the tooth line of the force           3 %
force_sensor_dynamics  largest deviation of the sensor gain from 1 at the           5 %
                       compared harmonics
channel_delay          phase of the delay at the model's highest mode inside the    5 deg
                       records' band (:func:`~planner.diagnosis.response.
                       visible_band_hz`)
process_damping        largest relative rise of a mode's damping in the cut         20 %
unmodeled_mode         peak compliance of the new mode over the model's largest     10 %
cross_coupling         rotation of the mode's direction                             5 deg
pose_drift             change of the natural frequencies over the record            3 %
nonlinear_cutting      size-effect exponent ``|p|`` (a chip halved changes the      0.05
                       specific force by 3.5 %)
cutting_coefficients   largest relative change of Ktc or of Krc / Ktc               10 %
=====================  ==========================================================  =========
"""

from __future__ import annotations

import math

import numpy as np

from oma.cutting import engagement_angles

from .response import views_band_hz

__all__ = ["FLOORS", "practical_size"]

#: cause -> (floor, what is measured, the parameter whose standard error is checked, its null value).
FLOORS = {
    "runout": (0.03, "1x line / tooth line", "runout_amplitude_m", 0.0),
    "force_sensor_dynamics": (0.05, "max | |H| - 1 | at the compared harmonics", None, None),
    "channel_delay": (5.0, "phase at the highest mode the records resolve, deg", "delay_s", 0.0),
    "process_damping": (0.20, "largest relative rise of a mode's damping", None, None),
    "unmodeled_mode": (0.10, "peak compliance / the model's largest", None, None),
    "cross_coupling": (5.0, "rotation, deg", None, None),
    "pose_drift": (0.03, "|relative change of the natural frequencies|", "relative_change", 0.0),
    "nonlinear_cutting": (0.05, "|exponent p|", "exponent_p", 0.0),
    "cutting_coefficients": (0.10, "max |relative change| of Ktc, Krc / Ktc", None, None),
}

#: A parameter differs from its null value when it is this many standard errors away.
SIGMA_MULTIPLE = 2.0


def _line_amplitudes(c):
    """Amplitude of each harmonic of the resultant force, shape (H + 1,)."""
    return np.sqrt(np.sum(np.abs(np.asarray(c)) ** 2, axis=0))


def _size(cause: str, params: dict, parts, extension) -> float:
    views = parts.views
    model = parts.model
    if cause == "runout":
        out = 0.0
        for i, v in enumerate(views):
            teeth = int(v.tool.teeth)
            if v.n_harm < teeth:
                continue
            a = _line_amplitudes(extension.prediction[i])
            b = _line_amplitudes(parts.force.baseline[i])
            out = max(out, (a[1] - b[1]) / max(a[teeth], 1e-30))
        return out
    if cause == "force_sensor_dynamics":
        from .forcemodel import sensor_gain

        f_top = max(v.n_harm * v.spindle_hz for v in views)
        f = np.linspace(0.0, f_top, 200)
        return float(np.max(np.abs(np.abs(sensor_gain(f, params["sensor_frequency_hz"],
                                                      params["sensor_damping_ratio"])) - 1.0)))
    if cause == "channel_delay":
        # the highest mode the records resolve: a delay's phase at a mode above their band (a
        # spindle/tool mode) is not measured by them, and the fit never saw that mode's resonance
        fn = np.asarray(model.natural_frequency_hz, dtype=float)
        fn = fn[fn <= views_band_hz(views)]
        f_max = float(np.max(fn)) if fn.size else 0.0
        return 360.0 * f_max * abs(params["delay_s"])
    if cause == "process_damping":
        return _process_damping_rise(params["process_damping_coefficient_N_m"], parts)
    if cause == "unmodeled_mode":
        if model.n_modes == 0:
            return math.inf
        own = 1.0 / (2.0 * np.asarray(model.damping_ratio) * np.asarray(model.stiffness_N_m))
        new = 1.0 / (2.0 * params["damping_ratio"] * params["stiffness_N_m"])
        return float(new / np.max(own))
    if cause == "cross_coupling":
        return float(params["rotation_deg"])
    if cause == "pose_drift":
        return abs(float(params["relative_change"]))
    if cause == "nonlinear_cutting":
        return abs(float(params["exponent_p"]))
    if cause == "cutting_coefficients":
        return max(abs(params["Ktc_relative_change"]), abs(params["ratio_relative_change"]))
    raise ValueError(f"no practical floor for {cause!r}")


def _process_damping_rise(c_N_m: float, parts) -> float:
    """Largest ``delta zeta / zeta`` of a mode: the flank force ``C v_r / V`` per unit width acts on
    the engaged length ``a_p`` of each tooth in the cut along the radial direction ``r``; averaged
    over a revolution it is a viscous damper ``c = C a_p / V x (engaged share) x <(u . r)^2>``
    on a mode of direction ``u``, against the mode's own ``2 zeta k / w``."""
    model = parts.model
    if model.n_modes == 0 or c_N_m <= 0:
        return 0.0
    out = 0.0
    for v in parts.views:
        speed = math.pi * v.tool.diameter_m * 60.0 * v.spindle_hz / 60.0
        st, ex = engagement_angles(v.tool, v.cut)
        phi = np.linspace(st, ex, 64)
        frame = np.asarray(v.cut.frame)
        r = np.sin(phi)[:, None] * frame[0] + np.cos(phi)[:, None] * frame[1]
        share = int(v.tool.teeth) * (ex - st) / (2.0 * math.pi)
        for m in range(model.n_modes):
            u = model.directions[m]
            proj = float(np.mean((r @ u) ** 2))
            c_pd = c_N_m * float(v.cut.axial_depth_m) / speed * share * proj
            c_mode = 2.0 * model.damping_ratio[m] * model.stiffness_N_m[m] / model.omega_rad_s[m]
            out = max(out, c_pd / c_mode)
    return float(out)


def practical_size(cause: str, params: dict, parts, extension) -> dict:
    """The cause's size against its floor and its standard error.

    Returns
    -------
    dict
        ``size``, ``floor``, ``measure`` (what the size is), ``sigma_ratio`` (the main parameter's
        distance from its null value in standard errors, NaN when the fit gives none), and
        ``passes``.
    """
    floor, measure, key, null = FLOORS[cause]
    try:
        size = float(_size(cause, params, parts, extension))
    except (KeyError, TypeError, ValueError, IndexError):
        size = float("nan")
    ratio = float("nan")
    if key is not None and f"{key}_sigma" in params:
        sig = float(params[f"{key}_sigma"])
        ratio = abs(float(params[key]) - null) / sig if sig > 0 else math.inf
    if cause == "cutting_coefficients":
        ratios = [abs(params[k]) / params[f"{k}_sigma"] for k in ("Ktc_relative_change", "ratio_relative_change")
                  if params.get(f"{k}_sigma", 0) > 0]
        ratio = max(ratios) if ratios else float("nan")
    ok = bool(math.isfinite(size) and size >= floor and (math.isnan(ratio) or ratio >= SIGMA_MULTIPLE))
    return {"size": size, "floor": floor, "measure": measure, "sigma_ratio": ratio, "passes": ok}
