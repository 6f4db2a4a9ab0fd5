"""What :func:`planner.optimize.plan` takes and returns: its settings (:class:`PlanSettings`), the
setup's limits as it reads them (:class:`PlanBounds`), the answer per pocket
(:class:`PocketResult`) and the plan (:class:`Plan`), with the constraint names
(:data:`CONSTRAINTS`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from oma.errors import SetupError
from stability.lobes import LobeDiagram, OperatingPoint

__all__ = ["PlanSettings", "PlanBounds", "plan_bounds", "PocketResult", "Plan", "CONSTRAINTS"]

#: Names used in ``active_constraints`` and ``infeasible_constraint``.
CONSTRAINTS = ("stability", "surface_error", "force", "power", "torque",
               "rpm_min", "rpm_max", "depth_min", "depth_max", "feed_min", "feed_max")


@dataclass(frozen=True)
class PlanSettings:
    """Options of :func:`plan`.

    Attributes
    ----------
    sdm_below_immersion : float
        ``method='auto'`` uses the SDM when ``ae / D`` is below this (flip lobes, missed by the
        ZOA, matter at low radial immersion), the ZOA otherwise.
    n_rpm_zoa, n_rpm_sdm : int
        Speed grid of the lobe diagram that locates the pockets.
    min_pocket_rel_width : float
        Pockets narrower than this fraction of their centre speed are merged (lower hull).
    cheb_rtol : float
        Relative accuracy of a ZOA pocket's Chebyshev series (checked at the nodes not used).
    seed_speeds, seed_depths, seed_feeds : int
        Start grid per pocket.
    force_feed_nodes : int
        Feeds at which the depth boundary of the peak force is computed (>= 8).
    recheck_rtol : float
        A re-checked value may exceed its limit by this fraction (rounding of the limit search).
    backoff_slack : float
        A violated constraint is tightened to ``limit / ratio * (1 - backoff_slack)``.
    max_backoffs : int
        Re-solves of one pocket after failed re-checks.
    max_iter : int
        IPOPT iterations.
    n_freq : int
        ZOA chatter-frequency grid (as :func:`stability.lobes.predict_point`).
    sdm_rtol : float
        SDM accuracy (as :func:`stability.lobes.lobe_diagram`).
    sdm_cusp_iterations : int
        Golden-section steps that locate each SDM cusp (a local maximum of the sampled diagram)
        between its neighbouring samples: each shrinks the bracket by 0.618 for one SDM limit per
        cusp.
    sdm_refine_rounds, sdm_refine_within : int, float
        SDM: rounds of local refinement of the limit around the answers of the pockets whose
        removal rate is within this fraction of the best (three new SDM limits each, at the answer
        and on either side at a quarter of the local sample spacing, then the pocket solved again).
    """

    sdm_below_immersion: float = 0.2
    n_rpm_zoa: int = 2000
    n_rpm_sdm: int = 100
    min_pocket_rel_width: float = 0.02
    cheb_rtol: float = 1e-5
    seed_speeds: int = 13
    seed_depths: int = 48
    seed_feeds: int = 9
    force_feed_nodes: int = 17
    recheck_rtol: float = 1e-4
    backoff_slack: float = 2e-4
    max_backoffs: int = 4
    max_iter: int = 500
    n_freq: int = 10_000
    sdm_rtol: float = 0.01
    sdm_cusp_iterations: int = 8
    sdm_refine_rounds: int = 3
    sdm_refine_within: float = 0.1

    def __post_init__(self):
        for name in ("n_rpm_zoa", "n_rpm_sdm", "seed_speeds", "seed_depths", "seed_feeds"):
            if int(getattr(self, name)) < 3:
                raise ValueError(f"{name} must be >= 3, found {getattr(self, name)}")
        if self.force_feed_nodes < 8:  # a cubic B-spline interpolant needs 8 points
            raise ValueError(f"force_feed_nodes must be >= 8, found {self.force_feed_nodes}")
        if not 0 < self.recheck_rtol < 0.1 or not 0 <= self.backoff_slack < 0.1:
            raise ValueError("recheck_rtol must be in (0, 0.1) and backoff_slack in [0, 0.1)")


@dataclass(frozen=True)
class PlanBounds:
    """The setup's limits as :func:`plan` reads them (:func:`plan_bounds`).

    Attributes
    ----------
    rpm, ap, fz : (float, float)
        Speed (rpm), depth (m) and feed per tooth (m) ranges; a feed range of one value when the
        limits give none (the cut's feed).
    margin : float
        Fraction of the limit depth that may be planned (1 when no margin is given).
    sle, force, torque, power : float or None
        ``|SLE|`` on the finished wall (m), peak force (N), mean torque (N m), mean power (W);
        None: not constrained.
    """

    rpm: tuple[float, float]
    ap: tuple[float, float]
    fz: tuple[float, float]
    margin: float
    sle: float | None
    force: float | None
    torque: float | None
    power: float | None


def plan_bounds(setup) -> PlanBounds:
    """:class:`PlanBounds` of a setup; SetupError without cutting coefficients or speed or depth
    range, or with an empty speed range."""
    lim = setup.limits
    if setup.material.cutting_coefficients is None:
        raise SetupError(None, "material.cutting_coefficients", "cutting coefficients to plan with", "none")
    if lim.spindle_rpm is None:
        raise SetupError(None, "limits.spindle_rpm", "a [low, high] speed range to plan in", "none")
    if lim.axial_depth_m is None:
        raise SetupError(None, "limits.axial_depth_m", "a [low, high] depth range to plan in", "none")
    fz = lim.feed_per_tooth_m or (setup.cut.feed_per_tooth_m,) * 2
    rpm = tuple(float(v) for v in lim.spindle_rpm)
    if not rpm[0] < rpm[1]:
        raise SetupError(None, "limits.spindle_rpm", "low < high", f"{list(rpm)}")
    return PlanBounds(rpm, tuple(float(v) for v in lim.axial_depth_m), tuple(float(v) for v in fz),
                      float(lim.stability_margin or 1.0), lim.surface_location_error_m, lim.max_force_N,
                      lim.spindle_torque_N_m, lim.spindle_power_W)


# --------------------------------------------------------------------------------------- results

def _jf(x):
    return None if x is None or not math.isfinite(float(x)) else float(x)


@dataclass(frozen=True)
class PocketResult:
    """The NLP of one pocket.

    Attributes
    ----------
    rpm_range : (float, float)
        Speed interval of the pocket, rpm.
    kind : str
        ``'lobe'`` (exact ZOA branch), ``'sampled'`` (SDM samples), ``'hull'`` (merged narrow pockets).
    start : ndarray, shape (3,)
        Start point ``(rpm, ap_m, fz_m)`` (best point of the pocket's seed grid).
    solution : ndarray, shape (3,)
        NLP answer ``(rpm, ap_m, fz_m)``.
    mrr_m3_s : float
        Removal rate of the answer (NaN when the pocket has no feasible answer).
    solver_status : str
        IPOPT's return status of the last solve.
    feasible : bool
        The answer meets the pocket's (surrogate) constraints.
    verified : bool or None
        Re-checked with :func:`stability.lobes.predict_point` (None: not re-checked, because a
        better pocket was verified first).
    backoffs : int
        Re-solves after failed re-checks.
    """

    rpm_range: tuple[float, float]
    kind: str
    start: np.ndarray
    solution: np.ndarray
    mrr_m3_s: float
    solver_status: str
    feasible: bool
    verified: bool | None = None
    backoffs: int = 0

    def to_dict(self) -> dict:
        return {"rpm_range": [float(v) for v in self.rpm_range], "kind": self.kind,
                "start": {"spindle_rpm": float(self.start[0]), "axial_depth_m": float(self.start[1]),
                          "feed_per_tooth_m": float(self.start[2])},
                "solution": {"spindle_rpm": float(self.solution[0]), "axial_depth_m": float(self.solution[1]),
                             "feed_per_tooth_m": float(self.solution[2])},
                "mrr_m3_s": _jf(self.mrr_m3_s), "solver_status": self.solver_status,
                "feasible": bool(self.feasible), "verified": self.verified, "backoffs": int(self.backoffs)}


@dataclass(frozen=True)
class Plan:
    """Recommended cutting parameters (the answer of :func:`plan`).

    Attributes
    ----------
    success : bool
        A verified optimum was found.
    status : str
        ``'optimal'``; ``'infeasible'`` (no point meets every constraint); ``'unverified'``
        (answers of the NLP failed the re-check); ``'not_converged'`` (IPOPT stopped short in the
        best pocket: the point is verified feasible but not certified optimal; ``success`` is
        False, the parameters are still given).
    message : str
        One line for people.
    method : str
        ``'zoa'`` or ``'sdm'`` (the stability model used).
    spindle_rpm, axial_depth_m, feed_per_tooth_m, mrr_m3_s : float or None
        The optimum (None when no point was verified). MRR in m^3/s.
    active_constraints : tuple of str
        Constraints at their limit at the optimum (names in :data:`CONSTRAINTS`).
    infeasible_constraint : str or None
        Without success: the constraint that cannot be met even alone, or two joined by ``'+'``
        when each can be met alone but not both together.
    stability_margin : float
        Fraction of the limit depth planned.
    point : OperatingPoint or None
        :func:`stability.lobes.predict_point` at the optimum.
    pockets : tuple of PocketResult
        Every pocket's start and answer.
    diagram : LobeDiagram
        The lobe diagram that located the pockets.
    elapsed_s : float
    surface_error_height_m : float or None
        When ``surface_error`` is active: the height above the tool tip, m, at which ``|SLE|`` on
        the finished wall is largest (the limit binds there; :func:`planner.wall.wall_error` at
        :attr:`point`); None otherwise.
    surface_error_max_m, surface_error_max_height_m : float or None
        The surface location error where ``|SLE|`` on the finished wall is largest (signed,
        m) and its height above the tip (:func:`planner.wall.wall_extremum` at :attr:`point`),
        whether the limit binds or not; in the JSON's ``predicted`` block beside the tip's
        ``surface_location_error_m``, as ``predict`` reports them. None without a point.
    """

    success: bool
    status: str
    message: str
    method: str
    spindle_rpm: float | None
    axial_depth_m: float | None
    feed_per_tooth_m: float | None
    mrr_m3_s: float | None
    active_constraints: tuple[str, ...]
    infeasible_constraint: str | None
    stability_margin: float
    point: OperatingPoint | None
    pockets: tuple[PocketResult, ...]
    diagram: LobeDiagram
    elapsed_s: float = 0.0
    surface_error_height_m: float | None = None
    surface_error_max_m: float | None = None
    surface_error_max_height_m: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready mapping: the cli.md keys of ``plan`` and the details."""
        return {
            "success": bool(self.success), "status": self.status, "message": self.message,
            "method": self.method, "spindle_rpm": _jf(self.spindle_rpm),
            "axial_depth_m": _jf(self.axial_depth_m), "feed_per_tooth_m": _jf(self.feed_per_tooth_m),
            "mrr_m3_s": _jf(self.mrr_m3_s), "active_constraints": list(self.active_constraints),
            "infeasible_constraint": self.infeasible_constraint,
            "surface_error_height_m": _jf(self.surface_error_height_m),
            "stability_margin": float(self.stability_margin),
            "predicted": None if self.point is None else {
                **self.point.to_dict(), "surface_error_max_m": _jf(self.surface_error_max_m),
                "surface_error_max_height_m": _jf(self.surface_error_max_height_m)},
            "pockets": [p.to_dict() for p in self.pockets], "elapsed_s": float(self.elapsed_s),
        }

    def plot(self, ax=None, *, limit_label: str | None = None):
        """Lobes, the planned-depth line, pocket answers and the optimum (see
        :func:`planner.plan_plots.plot_plan`)."""
        from .plan_plots import plot_plan

        return plot_plan(self, ax=ax, limit_label=limit_label)
