"""Stability lobes and operating-point predictions: the two entry points of ``robomill lobes`` and
``robomill predict``.

* :func:`lobe_diagram` -> :class:`LobeDiagram`: the limit depth versus spindle speed by the
  zero-order approximation (:mod:`stability.zoa`, works on a modal model or a measured FRF table)
  or by semi-discretization (:mod:`stability.sdm`, needs a modal model; finds flip lobes, helix and
  process damping).
* :func:`predict_point` -> :class:`OperatingPoint`: at one speed and depth, the stability limit by
  the chosen method, whether the depth is stable, and the forced vibration
  (:mod:`stability.forced`): surface location error, peak force, torque, power, removal rate.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, fields
from typing import Literal

import numpy as np

from oma.cutting import CuttingCoefficients, Cut, Tool

from . import zoa
from .forced import ForcedResponse, forced_response
from .oriented import _readonly as _ro
from .sdm import Resolution, SDMProblem, as_modal_model, choose_resolution, steps_per_period

__all__ = ["LobeDiagram", "OperatingPoint", "lobe_diagram", "predict_point", "METHODS"]

Method = Literal["zoa", "sdm"]
METHODS = ("zoa", "sdm")



def _json_float(x):
    """A float for JSON: ``None`` for inf/NaN (JSON has no infinity)."""
    x = float(x)
    return x if math.isfinite(x) else None


def _json_list(a):
    return [_json_float(v) for v in np.asarray(a, dtype=float)]


def _check_method(method):
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(repr(m) for m in METHODS)}, found {method!r}")


def _check_rpm_range(rpm_range):
    lo, hi = (float(v) for v in rpm_range)
    if not (0 < lo < hi and math.isfinite(hi)):
        raise ValueError(f"rpm_range must be (low, high) with 0 < low < high, found {tuple(rpm_range)}")
    return lo, hi


@dataclass(frozen=True)
class LobeDiagram:
    """A stability lobe diagram.

    Attributes
    ----------
    method : str
        ``'zoa'`` or ``'sdm'``.
    rpm : ndarray, shape (n,)
        Spindle speeds, increasing, rpm (for ZOA the grid plus the cusps between lobes).
    depth_limit_m : ndarray, shape (n,)
        Axial depth at the stability boundary, m (``inf``: none found below the search limit).
    chatter_frequency_hz : ndarray, shape (n,)
        Frequency of the onset vibration, Hz.
    kind : ndarray of str, shape (n,)
        ``'hopf'`` (complex multiplier pair; every ZOA point), ``'flip'`` (period doubling),
        ``'fold'`` or ``'none'``.
    is_intersection : ndarray of bool, shape (n,)
        ZOA cusps between adjacent lobes (exact intersections); all False for SDM.
    steps : ndarray of int, shape (n,)
        SDM steps per tooth period at each speed (0 for ZOA).
    resolution : Resolution or None
        SDM step-count rule and its convergence history.
    lobe_rpm, lobe_depth_m : ndarray, shape (n_pts,)
        ZOA: every lobe sampled on the chatter-frequency grid, lobes separated by NaN (for plots).
    process_damping_N_m : float
    elapsed_s : float
        Wall time of the computation, s.
    """

    method: str
    rpm: np.ndarray
    depth_limit_m: np.ndarray
    chatter_frequency_hz: np.ndarray
    kind: np.ndarray
    is_intersection: np.ndarray
    steps: np.ndarray
    resolution: Resolution | None = None
    lobe_rpm: np.ndarray = field(default_factory=lambda: _ro(np.zeros(0)))
    lobe_depth_m: np.ndarray = field(default_factory=lambda: _ro(np.zeros(0)))
    process_damping_N_m: float = 0.0
    elapsed_s: float = 0.0

    @property
    def min_depth_limit_m(self) -> float:
        """Smallest limit over the diagram, m."""
        return float(np.min(self.depth_limit_m))

    def to_dict(self) -> dict:
        """JSON-ready mapping: ``method``, ``rpm``, ``depth_limit_m`` (``None`` where unbounded),
        ``chatter_frequency_hz``, ``kind``, and for SDM ``steps`` and the chosen resolution."""
        out = {
            "method": self.method,
            "rpm": [float(r) for r in self.rpm],
            "depth_limit_m": _json_list(self.depth_limit_m),
            "chatter_frequency_hz": _json_list(self.chatter_frequency_hz),
            "kind": [str(k) for k in self.kind],
            "min_depth_limit_m": _json_float(self.min_depth_limit_m),
        }
        if self.method == "sdm":
            out["steps"] = [int(s) for s in self.steps]
            if self.resolution is not None:
                r = self.resolution
                out["resolution"] = {
                    "steps_per_mode_period": r.steps_per_mode_period, "min_steps": r.min_steps,
                    "rtol": r.rtol, "converged": r.converged, "probe_rpm": list(r.probe_rpm),
                    "history": [list(h) for h in r.history],
                }
            out["process_damping_N_m"] = self.process_damping_N_m
        else:
            out["is_intersection"] = [bool(b) for b in self.is_intersection]
        return out

    def plot(self, ax=None, **kwargs):
        """Plot the diagram (see :func:`stability.plots.plot_lobes`)."""
        from .plots import plot_lobes

        return plot_lobes(self, ax=ax, **kwargs)


def _zoa_diagram(structure, tool, cut, coefficients, rpm, *, freq_hz, n_freq) -> LobeDiagram:
    f = zoa.default_chatter_frequencies(structure, n_freq=n_freq) if freq_hz is None else freq_hz
    curves = zoa.limit_curves(structure, tool, cut, coefficients, f)
    env = zoa.envelope(structure, tool, cut, coefficients, rpm, curves=curves)
    # the individual lobes, for plotting: up to 5x the largest finite envelope depth
    finite = env.depth_limit_m[np.isfinite(env.depth_limit_m)]
    cap = 5.0 * float(finite.max()) if finite.size else np.inf
    lobe_r, lobe_d = zoa.lobe_segments(curves, rpm[0], rpm[-1], max_depth_m=cap)
    n = env.rpm.size
    return LobeDiagram(
        method="zoa", rpm=env.rpm, depth_limit_m=env.depth_limit_m,
        chatter_frequency_hz=env.chatter_frequency_hz,
        kind=_ro(np.where(np.isfinite(env.depth_limit_m), "hopf", "none")),
        is_intersection=env.is_intersection, steps=_ro(np.zeros(n, dtype=int)),
        lobe_rpm=lobe_r, lobe_depth_m=lobe_d,
    )


def _sdm_setup(structure, tool, cut, coefficients, rpm_range, *, rtol, process_damping_N_m,
               steps_per_mode_period, min_steps):
    problem = SDMProblem(structure, tool, cut, coefficients, process_damping_N_m=process_damping_N_m)
    if steps_per_mode_period is None:
        res = choose_resolution(problem, rpm_range, rtol=rtol)
    else:
        res = Resolution(float(steps_per_mode_period), int(min_steps), float(rtol), (), (), False)
    return problem, res


def lobe_diagram(structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients, *,
                 rpm_range, method: Method = "zoa", n_rpm: int | None = None, rpm=None,
                 rtol: float = 0.01, process_damping_N_m: float = 0.0, freq_hz=None,
                 n_freq: int = 10_000, steps_per_mode_period: float | None = None,
                 min_steps: int = 20, max_depth_m: float = 1.0) -> LobeDiagram:
    """Stability lobe diagram of a cut.

    Parameters
    ----------
    structure : ModalModel or FRFTable
        Tool-tip dynamics, machine frame. ``method='sdm'`` needs a ``ModalModel``.
    tool, cut, coefficients
        The cut (``cut.spindle_rpm`` and ``cut.axial_depth_m`` are not used).
    rpm_range : (float, float)
        Lowest and highest spindle speed, rpm.
    method : {'zoa', 'sdm'}
        Zero-order approximation or semi-discretization.
    n_rpm : int, optional
        Grid speeds, evenly spaced (default 1000 for ZOA, 200 for SDM).
    rpm : array_like, optional
        Explicit increasing speed grid instead of ``rpm_range``/``n_rpm`` spacing.
    rtol : float
        SDM: accuracy of the limit depth; the step count is doubled until halving the step
        changes the limit at probe speeds by less than this (:func:`stability.sdm.choose_resolution`).
    process_damping_N_m : float
        SDM only: process-damping coefficient ``C``, N/m.
    freq_hz : array_like, optional
        ZOA chatter-frequency grid (default :func:`stability.zoa.default_chatter_frequencies`).
    n_freq : int
        Size of the default chatter-frequency grid.
    steps_per_mode_period : float, optional
        SDM: skip the convergence test and use this resolution (with ``min_steps``).
    min_steps : int
        SDM: fewest steps per tooth period when ``steps_per_mode_period`` is given.
    max_depth_m : float
        SDM: search the limit up to this depth, m.

    Returns
    -------
    LobeDiagram
    """
    _check_method(method)
    lo, hi = _check_rpm_range(rpm_range)
    if rpm is None:
        rpm = np.linspace(lo, hi, int(n_rpm or (1000 if method == "zoa" else 200)))
    rpm = np.asarray(rpm, dtype=float).ravel()
    if rpm.size == 0 or np.any(rpm <= 0) or np.any(np.diff(rpm) <= 0):
        raise ValueError("rpm must be positive and strictly increasing")
    t0 = time.perf_counter()
    if method == "zoa":
        if process_damping_N_m:
            raise ValueError("process damping needs method 'sdm' (the ZOA has no velocity term)")
        diagram = _zoa_diagram(structure, tool, cut, coefficients, rpm, freq_hz=freq_hz, n_freq=n_freq)
        return _with_time(diagram, t0)
    model = as_modal_model(structure)
    problem, res = _sdm_setup(model, tool, cut, coefficients, (rpm[0], rpm[-1]), rtol=rtol,
                              process_damping_N_m=process_damping_N_m,
                              steps_per_mode_period=steps_per_mode_period, min_steps=min_steps)
    guess = zoa.envelope(model, tool, cut, coefficients, rpm, n_freq=2000)
    guess_d = np.asarray(guess.depth_limit_m)[~guess.is_intersection]
    steps = steps_per_period(problem, rpm, steps_per_mode_period=res.steps_per_mode_period,
                             min_steps=res.min_steps)
    out = problem.limits(rpm, steps, guess_m=guess_d, depth_rtol=rtol / 10, max_depth_m=max_depth_m)
    diagram = LobeDiagram(
        method="sdm", rpm=_ro(rpm), depth_limit_m=_ro([o.depth_limit_m for o in out]),
        chatter_frequency_hz=_ro([o.chatter_frequency_hz for o in out]),
        kind=_ro([o.kind for o in out]), is_intersection=_ro(np.zeros(rpm.size, dtype=bool)),
        steps=_ro(steps), resolution=res, process_damping_N_m=float(process_damping_N_m),
    )
    return _with_time(diagram, t0)


def _with_time(diagram: LobeDiagram, t0: float) -> LobeDiagram:
    from dataclasses import replace

    return replace(diagram, elapsed_s=time.perf_counter() - t0)


@dataclass(frozen=True)
class OperatingPoint:
    """Prediction at one spindle speed and axial depth.

    Attributes
    ----------
    method : str
    spindle_rpm, axial_depth_m : float
    stable : bool
        ZOA: depth below the limit. SDM: spectral radius of the monodromy at this depth below 1.
    depth_limit_m : float
        Stability limit at this speed by the method, m.
    kind : str
        Type of the boundary at the limit (``'hopf'``, ``'flip'``, ``'fold'``, ``'none'``).
    chatter_frequency_hz : float
        Frequency at the limit, Hz.
    spectral_radius : float or None
        SDM: ``max |mu|`` at this depth.
    surface_location_error_m : float
        Steady forced-vibration surface location error at the tool tip, m (positive: material left
        on). Meaningful only when ``stable``.
    surface_location_error_profile_m : ndarray
        Along the depth at ``forced.sle_profile_z_m``.
    peak_force_N, peak_torque_N_m, mean_torque_N_m, power_W, mrr_m3_s : float
    steps : int
        SDM steps per tooth period (0 for ZOA).
    forced : ForcedResponse
        The full forced-vibration result (time series over one tooth period).
    """

    method: str
    spindle_rpm: float
    axial_depth_m: float
    stable: bool
    depth_limit_m: float
    kind: str
    chatter_frequency_hz: float
    spectral_radius: float | None
    surface_location_error_m: float
    surface_location_error_profile_m: np.ndarray
    peak_force_N: float
    peak_torque_N_m: float
    mean_torque_N_m: float
    power_W: float
    mrr_m3_s: float
    steps: int
    forced: ForcedResponse

    def to_dict(self) -> dict:
        """JSON-ready mapping of the scalars and the SLE profile."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "forced":
                continue
            if f.name == "surface_location_error_profile_m":
                out["surface_location_error_profile"] = {
                    "z_m": [float(z) for z in self.forced.sle_profile_z_m],
                    "sle_m": [float(s) for s in v]}
            elif isinstance(v, (bool, np.bool_)):
                out[f.name] = bool(v)
            elif isinstance(v, str) or v is None or isinstance(v, (int, np.integer)):
                out[f.name] = v if not isinstance(v, np.integer) else int(v)
            else:
                out[f.name] = _json_float(v)
        out["margin"] = _json_float(self.axial_depth_m / self.depth_limit_m) if self.depth_limit_m else None
        return out

    def plot(self, ax=None):
        """Force and surface-normal displacement over one tooth period (see
        :func:`stability.plots.plot_operating_point`)."""
        from .plots import plot_operating_point

        return plot_operating_point(self, ax=ax)


def predict_point(structure, tool: Tool, cut: Cut, coefficients: CuttingCoefficients, *,
                  spindle_rpm: float, axial_depth_m: float, method: Method = "zoa",
                  rtol: float = 0.01, process_damping_N_m: float = 0.0, harmonics: int | None = None,
                  n_freq: int = 10_000, steps_per_mode_period: float | None = None,
                  min_steps: int = 20, max_depth_m: float = 1.0) -> OperatingPoint:
    """Stability and forced vibration at one spindle speed and depth.

    Parameters
    ----------
    structure : ModalModel or FRFTable
        Tool-tip dynamics, machine frame (``method='sdm'`` needs a ``ModalModel``).
    tool, cut, coefficients
        The cut and the force model.
    spindle_rpm : float
        Spindle speed, rpm.
    axial_depth_m : float
        Axial depth of cut, m.
    method : {'zoa', 'sdm'}
    rtol : float
        SDM accuracy (step count chosen by the convergence test at this speed).
    process_damping_N_m : float
        SDM only, N/m.
    harmonics : int, optional
        Forced vibration: harmonics of the tooth-passing frequency.
    n_freq, steps_per_mode_period, min_steps, max_depth_m
        As in :func:`lobe_diagram`.

    Returns
    -------
    OperatingPoint
    """
    _check_method(method)
    rpm, depth = float(spindle_rpm), float(axial_depth_m)
    if not (rpm > 0 and depth > 0):
        raise ValueError(f"spindle_rpm and axial_depth_m must be > 0, found {spindle_rpm} and {axial_depth_m}")
    if method == "zoa":
        if process_damping_N_m:
            raise ValueError("process damping needs method 'sdm' (the ZOA has no velocity term)")
        env = zoa.envelope(structure, tool, cut, coefficients, [rpm], n_freq=n_freq)
        limit = float(env.depth_limit_m[0])
        stable, kind, f_c, radius, steps = depth < limit, ("hopf" if math.isfinite(limit) else "none"), \
            float(env.chatter_frequency_hz[0]), None, 0
    else:
        model = as_modal_model(structure)
        problem, res = _sdm_setup(model, tool, cut, coefficients, (rpm, rpm), rtol=rtol,
                                  process_damping_N_m=process_damping_N_m,
                                  steps_per_mode_period=steps_per_mode_period, min_steps=min_steps)
        steps = int(steps_per_period(problem, rpm, steps_per_mode_period=res.steps_per_mode_period,
                                     min_steps=res.min_steps))
        guess = float(zoa.envelope(model, tool, cut, coefficients, [rpm], n_freq=2000).depth_limit_m[0])
        lim = problem.limit(rpm, steps, guess_m=guess, depth_rtol=rtol / 10, max_depth_m=max_depth_m)
        radius = problem.spectral_radius(rpm, depth, steps)
        limit, kind, f_c, stable = lim.depth_limit_m, lim.kind, lim.chatter_frequency_hz, radius < 1.0
    forced = forced_response(structure, tool, cut, coefficients, spindle_rpm=rpm, axial_depth_m=depth,
                             harmonics=harmonics)
    return OperatingPoint(
        method=method, spindle_rpm=rpm, axial_depth_m=depth, stable=bool(stable), depth_limit_m=limit,
        kind=kind, chatter_frequency_hz=f_c, spectral_radius=radius,
        surface_location_error_m=forced.surface_location_error_m,
        surface_location_error_profile_m=forced.sle_profile_m, peak_force_N=forced.peak_force_N,
        peak_torque_N_m=forced.peak_torque_N_m, mean_torque_N_m=forced.mean_torque_N_m,
        power_W=forced.power_W, mrr_m3_s=forced.mrr_m3_s, steps=steps, forced=forced,
    )
