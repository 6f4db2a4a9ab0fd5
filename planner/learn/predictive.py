"""What a posterior predicts: P(stable) of cuts, lobes with probability contours, the chance-
constrained limit depth used by ``plan``.

One probability throughout: the posterior predictive probability that a cut is stable,

    P(stable | a) = mean over samples s of  1 - p_chatter(log(a / b_s)),

with ``p_chatter`` the likelihood's soft boundary, whose width is the boundary scale and the forward
model's error (the tables' error and, with ``mode_correlation`` below 1, the modes' own
deviations, measured by ``learn``) in quadrature. ``--predict`` reports it, the lobes' contours
are its level sets and ``plan``'s chance constraint keeps it at or above the stated level. (Before
session 11 the contours and the chance constraint were quantiles of the samples' limits alone:
a 95 % depth above the depth ``--predict`` gave 95 % at, ignoring the tables' error and the soft
boundary.) The distribution of the limit itself, without the soft boundary (the limit band the
benchmark checks against the true limit), is :meth:`ProbabilityLobes.limit_quantile`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import expit, ndtr

from oma._arrays import readonly

from .outcomes_io import CutTable
from .posterior import Posterior
from .tables import FINE_NODES, Grid, LimitTable, build_table, direct_log_limits

__all__ = ["ProbabilityLobes", "predictive_grid", "predict_cuts", "checked_predictions", "table_error",
           "probability_lobes", "lobes_from_table",
           "ChanceLimit", "depth_at_probability", "UNTABULATED_DEPTH_M"]

#: The chance depth outside a :class:`ChanceLimit`'s speed range: none certified (1 nm rather
#: than 0, which ``plan``'s pocket fit would divide by).
UNTABULATED_DEPTH_M = 1e-9


def predictive_grid(posterior: Posterior, *, step: float = 0.015) -> Grid:
    """Table nodes covering the posterior samples (2 sds beyond the extremes; at most
    ``FINE_NODES`` damping and ratio nodes, as the fine table of ``learn``: fewer put the limit
    off by up to x2.4 when those posteriors stay wide, docs/learn.md)."""
    u = posterior.samples
    sd = posterior.prior_log_sd
    bounds = Grid.around(float(sd[0]), float(sd[2]), float(np.hypot(sd[3], sd[4])), span=4.0)
    return Grid.covering(u[:, 0], u[:, 2], u[:, 4] - u[:, 3], bounds=bounds, step=step, max_zeta=FINE_NODES[0],
                         max_ratio=FINE_NODES[1])


def _table(posterior: Posterior, setup, rpm, radial_depth_m, down, *, method: str | None,
           grid: Grid | None, known: LimitTable | None = None, desc: str | None = "limit table",
           for_samples: bool = False) -> LimitTable:
    """The posterior's limit table at these cuts. ``for_samples``: a table only the posterior's
    own samples read (the probability lobes): only the entries they read are solved
    (``build_table(..., samples=)``: the same values for them, NaN elsewhere) and each SDM search
    starts from the ZOA limit (``zoa_start``); on the kr500 example 4561 of 5760 entries solved,
    the 5/50/95 % depths within 1.2e-4 in log of the whole table's (benchmarks/bench_learn_lobes.py)."""
    return build_table(posterior.reference, setup.tool, setup.cut, posterior.coefficients, rpm, radial_depth_m,
                       down, grid or predictive_grid(posterior), method=method or posterior.method, known=known,
                       samples=posterior.samples if for_samples else None, zoa_start=for_samples, desc=desc)


def _drawn(posterior: Posterior, n: int, *, seed: int) -> np.ndarray:
    """``n`` of the posterior's samples (log-multipliers), drawn without replacement, reproducibly."""
    return posterior.samples[np.random.default_rng(seed).permutation(posterior.samples.shape[0])[:int(n)]]


def table_error(posterior: Posterior, setup, table: LimitTable, cols, *, samples: int = 8,
                method: str | None = None, desc: str = "limit table: check") -> float:
    """RMS log error of ``table`` at its cuts ``cols`` (indices) against the limits of ``samples``
    of the posterior's samples (drawn reproducibly) solved directly: the table's own error where it
    is read, which the error ``learn`` measured at its training cuts (``model_error``) need not be
    (the cuts may lie where the table is accurate, high speeds, and the reads where it is not,
    low speeds and lobe cusps)."""
    cols = np.asarray(cols, dtype=int)
    u = _drawn(posterior, samples, seed=0)
    ae = np.array([table.engagements[g][0] for g in table.group[cols]])
    down = np.array([table.engagements[g][1] for g in table.group[cols]])
    direct = direct_log_limits(posterior.reference, setup.tool, setup.cut, posterior.coefficients, table.rpm[cols], ae,
                               down, u, method=method or posterior.method, sdm_steps=table.grid.sdm_steps, desc=desc)
    err = posterior.log_limits(table, samples=u)[:, cols] - direct
    return float(np.sqrt(np.mean(err ** 2)))


def spread(n: int, k: int, order=None) -> np.ndarray:
    """``k`` of ``n`` indices spread evenly along ``order`` (default: as they come), ends kept."""
    order = np.arange(n) if order is None else np.asarray(order)
    return np.unique(order[np.round(np.linspace(0, n - 1, min(int(k), n))).astype(int)])


def predict_cuts(posterior: Posterior, setup, cuts: CutTable, *, method: str | None = None,
                 grid: Grid | None = None, check: int = 8, check_cuts: int = 12) -> np.ndarray:
    """Posterior probability that each cut is stable, shape (n_cuts,).

    The table is checked where it is read (:func:`table_error`: ``check`` samples solved directly
    at ``check_cuts`` of the cuts, spread over their speeds), and the predictions carry the larger
    of that error and ``model_error`` in their soft boundary (``check=0``: ``model_error`` alone;
    :func:`checked_predictions` also returns the error measured)."""
    return checked_predictions(posterior, setup, cuts, method=method, grid=grid, check=check,
                               check_cuts=check_cuts)[0]


def checked_predictions(posterior: Posterior, setup, cuts: CutTable, *, method: str | None = None,
                        grid: Grid | None = None, check: int = 8, check_cuts: int = 12) -> tuple[np.ndarray, float]:
    """:func:`predict_cuts` and the table error its predictions carry (0: not checked)."""
    table = _table(posterior, setup, cuts.spindle_rpm, cuts.radial_depth_m, cuts.down, method=method, grid=grid,
                   desc="predictions: limit table")
    err = 0.0
    if check > 0 and cuts.n_cuts:
        cols = spread(cuts.n_cuts, check_cuts, np.argsort(cuts.spindle_rpm, kind="stable"))
        err = table_error(posterior, setup, table, cols, samples=check, method=method, desc="predictions: check")
    lk = posterior.likelihood
    ratio = np.log(np.asarray(cuts.axial_depth_m, dtype=float))[None, :] - posterior.log_limits(table)
    return np.mean(1.0 - lk.p_chatter(ratio, model_error=max(lk.model_error, err)), axis=0), err


def depth_at_probability(log_limits: np.ndarray, probability: float, scale: float, *,
                         kernel: str = "logistic") -> np.ndarray:
    """The depth (per column) at which ``mean_s K((log b_s - log a) / scale)`` equals
    ``probability``: ``K`` the logistic (the predictive P(stable), module notes) or the normal
    ``cdf`` (the limit's own distribution with a forward-model error ``scale``); ``scale = 0`` is
    the samples' empirical ``1 - probability`` quantile. ``log_limits`` (n_samples, n_cols)."""
    ll = np.asarray(log_limits, dtype=float)
    if not scale > 0:
        return np.exp(np.quantile(ll, 1.0 - probability, axis=0))
    cdf = expit if kernel == "logistic" else ndtr
    lo = ll.min(axis=0) - 40.0 * scale
    hi = ll.max(axis=0) + 40.0 * scale
    for _ in range(60):  # bisection on log a: P falls from ~1 at lo to ~0 at hi
        mid = 0.5 * (lo + hi)
        above = np.mean(cdf((ll - mid[None, :]) / scale), axis=0) >= probability
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    return np.exp(0.5 * (lo + hi))


@dataclass(frozen=True)
class ProbabilityLobes:
    """The posterior's limit depth over speed at one engagement.

    ``quantiles`` maps a probability of stability ``p`` to the depth (m, per speed) at which the
    posterior predictive P(stable) is ``p`` (the module notes: the samples' limits and the soft
    boundary of width ``scale``); ``limits`` holds every sample's limit (n_samples, n_rpm);
    ``model_error`` is the log-sd of the forward model's error that ``learn`` measured at its
    training cuts, ``table_error`` the RMS log error of these lobes' own table against limits
    solved directly at some of their speeds (:func:`probability_lobes`; 0: not checked): the
    larger is carried (:meth:`limit_quantile`, ``scale``).
    """

    rpm: np.ndarray
    limits: np.ndarray
    levels: tuple[float, ...]
    quantiles: dict
    radial_depth_m: float
    milling: str
    scale: float = 0.0
    model_error: float = 0.0
    table_error: float = 0.0

    def probability_stable(self, axial_depth_m) -> np.ndarray:
        """P(stable) at every speed for each depth: shape (n_depths, n_rpm); ``axial_depth_m``
        is (n_depths,), or (n_depths, n_rpm) for depths that differ between speeds. One depth at a
        time: samples x speeds in memory, not depths x samples x speeds (58 MB for the plot's grid)."""
        a = np.log(np.atleast_1d(np.asarray(axial_depth_m, dtype=float)))
        ll = np.log(self.limits)
        kernel = (lambda d: d > 0) if not self.scale > 0 else (lambda d: expit(d / self.scale))
        return np.array([np.mean(kernel(ll - x), axis=0) for x in a]).reshape(a.shape[0], ll.shape[1])

    def limit_quantile(self, p: float) -> np.ndarray:
        """The depth (m, per speed) below which the limit itself lies with probability ``p``: the
        samples' limits with the forward model's log-normal error, no soft boundary."""
        return depth_at_probability(np.log(self.limits), 1.0 - p, max(self.model_error, self.table_error),
                                    kernel="normal")

    def to_dict(self) -> dict:
        return {"rpm": self.rpm.tolist(), "radial_depth_m": self.radial_depth_m, "milling": self.milling,
                "depth_at_probability_m": {f"{p:g}": self.quantiles[p].tolist() for p in self.levels},
                "boundary_width": self.scale, "model_error": self.model_error, "table_error": self.table_error}

    def plot(self, ax=None, *, cuts: CutTable | None = None, mislabelled=None):
        from .plots import plot_probability_lobes

        return plot_probability_lobes(self, ax=ax, cuts=cuts, mislabelled=mislabelled)


def probability_lobes(posterior: Posterior, setup, rpm_range, *, n_rpm: int = 150, method: str | None = None,
                      levels=(0.05, 0.5, 0.95), radial_depth_m: float | None = None, milling: str | None = None,
                      max_samples: int = 400, grid: Grid | None = None, check: int = 8,
                      check_speeds: int = 12) -> ProbabilityLobes:
    """Lobes with probability contours at the setup's engagement (or the one given).

    The table is checked where it is drawn, as :class:`ChanceLimit`'s: ``check`` of the samples
    are solved directly at ``check_speeds`` of the lobes' speeds (spread over the range), and the
    contours carry the larger of that RMS log error (``table_error``) and the error ``learn``
    measured at its training cuts (``model_error``): the training cuts may lie where the table is
    accurate (e.g. high speeds) and the lobes where it is not (low speeds, lobe cusps)."""
    ae = float(setup.cut.radial_depth_m if radial_depth_m is None else radial_depth_m)
    mill = setup.cut.milling if milling is None else milling
    rpm = np.geomspace(float(rpm_range[0]), float(rpm_range[1]), int(n_rpm))
    post = posterior.thinned(max_samples)
    table = _table(post, setup, rpm, np.full(rpm.size, ae), np.full(rpm.size, mill == "down"), method=method,
                   grid=grid, desc="probability lobes: limit table", for_samples=True)
    err = 0.0 if check <= 0 else table_error(post, setup, table, spread(rpm.size, check_speeds), samples=check,
                                             method=method, desc="probability lobes: check")
    return lobes_from_table(post, table, rpm, levels=levels, radial_depth_m=ae, milling=mill, table_error=err)


def lobes_from_table(posterior: Posterior, table: LimitTable, rpm, *, radial_depth_m: float, milling: str,
                     levels=(0.05, 0.5, 0.95), table_error: float = 0.0) -> ProbabilityLobes:
    """The lobes of every sample of ``posterior`` through ``table``, a limit table over the speeds
    ``rpm`` at the engagement ``radial_depth_m``, ``milling`` (e.g. one table built over the
    samples of several posteriors, each then interpolated); ``table_error``: the table's own
    measured RMS log error, carried where larger than the training cuts' ``model_error``."""
    log_lim = posterior.log_limits(table)
    lk = posterior.likelihood
    scale = float(lk.scale(max(lk.model_error, table_error)))
    quant = {float(p): readonly(depth_at_probability(log_lim, p, scale)) for p in levels}
    return ProbabilityLobes(rpm=readonly(np.asarray(rpm, dtype=float)), limits=readonly(np.exp(log_lim)),
                            levels=tuple(float(p) for p in levels), quantiles=quant,
                            radial_depth_m=float(radial_depth_m), milling=milling, scale=scale,
                            model_error=float(lk.model_error), table_error=float(table_error))


class ChanceLimit:
    """The depth (m) below which the cut of ``setup`` is stable with ``probability``, at any speed
    in ``rpm_range``: where the posterior predictive P(stable) (module notes; what ``--predict``
    reports) falls to ``probability`` (the chance constraint of ``plan``). The limit table is
    built once over the range; each call interpolates. Outside the range the depth is
    ``UNTABULATED_DEPTH_M`` (1 nm): no depth is certified where no limit was computed
    (:mod:`.speed_range` tabulates only the speeds where a cut could beat the best plan, and
    ``plan`` over the setup's whole range finds no cut at the others).

    The table is checked where it is used: ``check`` samples are solved directly at
    ``check_speeds`` speeds over the range, and the soft boundary is widened by the larger of
    that RMS log error (``table_error``) and the error ``learn`` measured at its training cuts
    (``likelihood.model_error``, which also carries the modes' own deviations): the training cuts'
    tables are not this engagement's.

    Parameters
    ----------
    posterior : Posterior
    setup : stability.setup.Setup
        Its cut (engagement) is the one planned.
    rpm_range : (float, float)
    probability : float
        In (0, 1), e.g. 0.95.
    check, check_speeds : int
        Samples and speeds of the table check (0 samples: no check, the training cuts' error).
    known : ChanceLimit, optional
        A chance limit of the same posterior, setup, method and ``max_samples`` over part of the
        range: its table's values are reused, only the speeds it lacks are solved (the range
        extended downward by :func:`planner.learn.speed_range.chance_limit_for_plan`). The table
        check is made again over the new range.

    Attributes
    ----------
    table_error, boundary_width : float
        The check's RMS log error and the soft boundary's width (the larger error in quadrature
        with the boundary scale).
    timings_s : dict
        Wall time of the table (``table``: the new speeds only) and of its check (``check``), s.
    """

    def __init__(self, posterior: Posterior, setup, rpm_range, *, probability: float = 0.95,
                 method: str | None = None, max_samples: int = 400, check: int = 8, check_speeds: int = 12,
                 known: "ChanceLimit | None" = None):
        if not 0 < probability < 1:
            raise ValueError(f"probability must be in (0, 1), found {probability}")
        self.probability = float(probability)
        self.rpm_range = (float(min(rpm_range)), float(max(rpm_range)))
        self.posterior = posterior.thinned(max_samples)
        self._setup, self._method = setup, method or self.posterior.method
        # grid speeds closer than the lattice step, so the lattice covers the whole range
        step = predictive_grid(self.posterior).log_speed_step
        n_rpm = int(np.ceil(np.log(self.rpm_range[1] / self.rpm_range[0]) / step)) + 2
        rpm = np.geomspace(*self.rpm_range, n_rpm)
        t0 = time.perf_counter()
        self._table = _table(self.posterior, setup, rpm, np.full(rpm.size, setup.cut.radial_depth_m),
                             np.full(rpm.size, setup.cut.milling == "down"), method=self._method, grid=None,
                             known=None if known is None else known._table, desc="chance limit: table")
        t1 = time.perf_counter()
        self.table_error = 0.0
        if check > 0:
            r = np.geomspace(*self.rpm_range, int(check_speeds))
            self.table_error = table_error(self.posterior, setup, self._at(r), np.arange(r.size), samples=check,
                                           method=self._method, desc="chance limit: check")
        self.timings_s = {"table": t1 - t0, "check": time.perf_counter() - t1}
        lk = self.posterior.likelihood
        self.boundary_width = float(lk.scale(max(lk.model_error, self.table_error)))

    def _direct(self, rpm, u, *, desc: str = "chance limit: direct limits") -> np.ndarray:
        """The log limits of the samples ``u`` at the speeds ``rpm`` solved directly (no table),
        (n_samples, n_rpm); ``desc`` labels the progress bar."""
        rpm = np.atleast_1d(np.asarray(rpm, dtype=float))
        post, setup = self.posterior, self._setup
        return direct_log_limits(post.reference, setup.tool, setup.cut, post.coefficients, rpm,
                                 np.full(rpm.size, setup.cut.radial_depth_m),
                                 np.full(rpm.size, setup.cut.milling == "down"), u, method=self._method,
                                 sdm_steps=self._table.grid.sdm_steps, desc=desc)

    def _at(self, rpm) -> LimitTable:
        """The range's table read at the speeds ``rpm`` (clipped to the range)."""
        rpm = np.clip(np.atleast_1d(np.asarray(rpm, dtype=float)), *self.rpm_range)
        return replace(self._table, rpm=rpm, group=np.zeros(rpm.size, dtype=int))

    def samples(self, rpm) -> np.ndarray:
        """Every sample's limit at the speeds, (n_samples, n_rpm), m."""
        return np.exp(self.posterior.log_limits(self._at(rpm)))

    def __call__(self, rpm) -> np.ndarray:
        """The chance depth (m) at the speeds ``rpm``; ``UNTABULATED_DEPTH_M`` outside
        :attr:`rpm_range` (class notes)."""
        rpm = np.atleast_1d(np.asarray(rpm, dtype=float))
        depth = depth_at_probability(np.log(self.samples(rpm)), self.probability, self.boundary_width)
        lo, hi = self.rpm_range
        return np.where((rpm >= lo * (1 - 1e-12)) & (rpm <= hi * (1 + 1e-12)), depth, UNTABULATED_DEPTH_M)

    def verify(self, rpm: float, axial_depth_m: float, *, samples: int = 64) -> dict:
        """The planned cut checked without any table: ``samples`` posterior samples solved directly
        at its speed, and its P(stable) from them with the training cuts' soft boundary (no table
        error to widen by: these limits are direct), with the Monte Carlo standard error of that
        mean. ``holds``: not below the level by more than two standard errors. The plan's speed is
        usually on a lobe's peak, where a table interpolates least well; this is where it matters."""
        lk, log_a = self.posterior.likelihood, np.log(axial_depth_m)
        direct = self._direct(rpm, _drawn(self.posterior, samples, seed=1), desc="plan check: direct limits")[:, 0]
        p = 1.0 - lk.p_chatter(log_a - direct)
        se = float(np.std(p, ddof=1) / np.sqrt(p.size)) if p.size > 1 else float("nan")
        table = np.log(self.samples([rpm])[:, 0])
        p_table = float(np.mean(1.0 - lk.p_chatter(log_a - table, model_error=max(lk.model_error, self.table_error))))
        return {"spindle_rpm": float(rpm), "axial_depth_m": float(axial_depth_m), "samples": int(p.size),
                "probability_stable": float(np.mean(p)), "standard_error": se,
                "table_probability_stable": p_table, "holds": bool(np.mean(p) >= self.probability - 2 * se)}


def with_engagement(setup, radial_depth_m: float, milling: str):
    return replace(setup, cut=replace(setup.cut, radial_depth_m=radial_depth_m, milling=milling))
