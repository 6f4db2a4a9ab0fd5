"""Which test cuts next: the best stable removal rate, or the stability boundary over the speed range.

Candidates are cuts at the setup's own engagement (the production cut) on a grid of speeds and
depths, inside the setup's limits (:func:`allowed_depths`: speed, depth, and at the setup's feed
the mean spindle power and torque and the peak force, as ``plan`` computes them). Two criteria
(``robomill learn --suggest N [--suggest-for mrr|boundary]``):

``mrr`` (the default): expected improvement of the best *proven* stable MRR. The incumbent is the
best MRR the posterior already guarantees, the largest ``ap * rpm`` with P(stable) >= ``confidence``
(0.95); a candidate's expected improvement is

    EI(c) = P(stable at c) * max(0, MRR(c) - MRR_incumbent),

the gain in the best proven-stable removal rate if the test cut at ``c`` comes out stable (the
expected-improvement rule of Jones, Schonlau & Welch, J. Global Optim. 13, 1998, for a pass/fail
outcome; Karandikar et al. choose test cuts in the same spirit). ``N`` cuts are picked greedily,
each at least ``min_speed_gap`` (relative) away in speed from those already picked, so that one
test does not make the next redundant.

``boundary``: the expected reduction of the posterior variance of the log limit, summed over the
speed range (log-spaced speeds, so each decade of speed counts alike): the cuts that teach most
about where the boundary lies everywhere, not only near the best pocket (integrated-variance
reduction for a level set, as in Bryan et al., NIPS 2005, with the outcome model of the likelihood:
the soft boundary, the forward model's error and the share of wrong marks). For a candidate ``c``
the two outcomes reweight the posterior samples by ``P(mark | theta)``; the expected variance
after the cut is ``E[L^2] - sum_y P(y) mean_y(L)^2``, so the score is computable for every
candidate at once from two weighted sums over the samples. Greedy batch: after each pick the
samples are reweighted by the pick's more probable outcome (the "believer" heuristic of
Ginsbourger, Le Riche & Carraro 2010), so the next pick is scored on what the first would leave
unknown. When the test cuts will be judged from records (``detected``), their outcome model is the
detector's lagged, wider boundary (:mod:`.likelihood`): such a cut teaches less, and most where
the detector's chance of calling chatter is near one half, above the limit by the lag.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit

from .likelihood import Likelihood
from .outcomes_io import CutTable
from .predictive import ProbabilityLobes

__all__ = ["suggest_cuts", "best_proven_mrr", "allowed_depths", "CRITERIA", "MIN_SPEED_GAP"]

CRITERIA = ("mrr", "boundary")
#: Least relative gap in speed between two suggested cuts.
MIN_SPEED_GAP = 0.03


def suggest_cuts(lobes: ProbabilityLobes, n: int, *, criterion: str = "mrr", likelihood: Likelihood | None = None,
                 depth_range_m=None, allowed_depth_m=None, n_depth: int = 60, confidence: float = 0.95,
                 min_speed_gap: float = MIN_SPEED_GAP,
                 detected: bool = False) -> tuple[CutTable, np.ndarray, float]:
    """The ``n`` test cuts that teach most by ``criterion``.

    Parameters
    ----------
    lobes : ProbabilityLobes
        The posterior's limits over speed at the production engagement.
    n : int
    criterion : {'mrr', 'boundary'}
        See the module notes.
    likelihood : Likelihood, optional
        The outcome model of the posterior (``boundary``; default :class:`Likelihood()`).
    depth_range_m : (float, float), optional
        Depths considered (default: from half the lowest 95 % depth to twice the highest 5 % one).
    allowed_depth_m : (array_like, array_like), optional
        The least and the largest depth (m) the setup allows at each of the lobes' speeds, scalars
        or shape (n_rpm,) (:func:`allowed_depths`); a speed whose largest is below its least is
        not allowed. Candidates are the depths considered clipped to them, per speed, and the
        incumbent is the best allowed cut. Default: every depth, every speed.
    detected : bool
        ``boundary``: the suggested cuts' outcomes will be detected from records, not marked
        (their outcome model is the detector's; ``mrr`` scores the cut's stability itself).

    Returns
    -------
    cuts : CutTable
        Suggested cuts, no outcome; fewer than ``n`` when fewer speeds are allowed.
    score : ndarray, shape (n_cuts,)
        ``mrr``: the expected improvement in units of ``ap * rpm`` (m rpm; multiply by
        ``ae fz N / 60`` for m^3/s). ``boundary``: the expected reduction of the summed variance
        of the log limit, as a share of what it was before the batch.
    incumbent : float
        Best allowed ``ap * rpm`` with P(stable) >= ``confidence`` (0 when none).
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, found {n}")
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {', '.join(CRITERIA)}, found {criterion!r}")
    cand = _candidates(lobes, depth_range_m, allowed_depth_m, n_depth, confidence)
    if cand is None:
        return _no_cuts(lobes), np.zeros(0), 0.0
    depth, p, mrr, allowed, incumbent = cand
    if criterion == "mrr":
        ei = np.where(allowed[None, :], p * np.maximum(0.0, mrr - incumbent), -1.0)
        picks, scores = _greedy_improvement(ei, lobes.rpm, n, min_speed_gap)
    else:
        picks, scores = _greedy_boundary(lobes, depth, allowed, n, likelihood or Likelihood(), min_speed_gap,
                                         detected)
    rpm = np.array([lobes.rpm[j] for _, j in picks], dtype=float)
    ap = np.array([depth[i, j] for i, j in picks], dtype=float)
    return _cuts(lobes, rpm, ap), np.asarray(scores, dtype=float), incumbent


def best_proven_mrr(lobes: ProbabilityLobes, *, depth_range_m=None, allowed_depth_m=None, n_depth: int = 60,
                    confidence: float = 0.95) -> float:
    """The incumbent of :func:`suggest_cuts` (same options): the best allowed ``ap * rpm`` (m rpm)
    with P(stable) >= ``confidence`` among its candidates (0 when none)."""
    cand = _candidates(lobes, depth_range_m, allowed_depth_m, n_depth, confidence)
    return 0.0 if cand is None else cand[-1]


def _candidates(lobes: ProbabilityLobes, depth_range_m, allowed_depth_m, n_depth: int, confidence: float):
    """The candidate depths (n_depth, n_rpm), their P(stable) and ``ap * rpm``, the speeds allowed
    (n_rpm,) and the incumbent (:func:`suggest_cuts`); None when no speed is allowed."""
    n_rpm = lobes.rpm.size
    lo_q = lobes.quantiles.get(0.95, np.quantile(lobes.limits, 0.05, axis=0))
    hi_q = lobes.quantiles.get(0.05, np.quantile(lobes.limits, 0.95, axis=0))
    if depth_range_m is None:
        depth_range_m = (0.5 * float(np.min(lo_q)), 2.0 * float(np.max(hi_q)))
    if allowed_depth_m is None:
        least, most = np.zeros(n_rpm), np.full(n_rpm, np.inf)
    else:
        least, most = (np.broadcast_to(np.asarray(v, dtype=float), (n_rpm,)) for v in allowed_depth_m)
    allowed = most >= least
    if not allowed.any():
        return None
    # the grid spans what is both considered and allowed (when nothing is, the allowed depth
    # nearest to what is considered), then each speed's column is clipped to its allowed depths
    a_lo, a_hi = float(np.min(least[allowed])), float(np.max(most[allowed]))
    lo, hi = max(depth_range_m[0], a_lo), min(depth_range_m[1], a_hi)
    grid = np.geomspace(lo, hi, n_depth) if lo < hi else np.array([min(max(depth_range_m[0], a_lo), a_hi)])
    depth = np.clip(grid[:, None], least[None, :], np.where(allowed, most, least)[None, :])  # (n_depth, n_rpm)
    p = lobes.probability_stable(depth)  # (n_depth, n_rpm)
    mrr = depth * lobes.rpm[None, :]
    safe = (p >= confidence) & allowed[None, :]
    incumbent = float(mrr[safe].max()) if safe.any() else 0.0
    return depth, p, mrr, allowed, incumbent


def _cuts(lobes: ProbabilityLobes, rpm: np.ndarray, ap: np.ndarray) -> CutTable:
    k = rpm.size
    return CutTable(rpm, ap, np.full(k, lobes.radial_depth_m), np.full(k, lobes.milling == "down"),
                    np.full(k, -1), np.ones(k), np.full(k, np.nan), np.zeros(k, bool))


def _no_cuts(lobes: ProbabilityLobes) -> CutTable:
    return _cuts(lobes, np.zeros(0), np.zeros(0))


def allowed_depths(setup, rpm, model) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """The depths the setup's limits allow for a test cut at its engagement and feed, per speed.

    The limits that ``plan`` also uses, evaluated as it does (:class:`planner.cut_model.CutModel`
    with the setup's cutting coefficients, its ``cut.feed_per_tooth_m``): ``limits.spindle_rpm``,
    ``limits.axial_depth_m``, and the mean spindle power (``spindle_power_W``) and torque
    (``spindle_torque_N_m``), both linear in depth, and the peak force (``max_force_N``, the largest
    depth below it, independent of speed). Not applied: the stability margin (a test cut is meant
    to find the limit) and the surface location error (a test cut's wall is not the part).

    Parameters
    ----------
    setup : stability.setup.Setup
    rpm : array_like, shape (n_rpm,)
    model : ModalModel
        Only for :class:`CutModel`'s construction (power, torque and force do not depend on it).

    Returns
    -------
    least, most : ndarray, shape (n_rpm,)
        Least and largest allowed depth, m (``most < least`` where the speed is not allowed; ``0``
        and ``inf`` where the setup sets no bound).
    limits : tuple of str
        The names of the limits applied.
    """
    rpm = np.asarray(rpm, dtype=float)
    lim = setup.limits
    least, most = np.zeros(rpm.size), np.full(rpm.size, np.inf)
    used = []
    if lim.spindle_rpm is not None:
        lo, hi = (float(v) for v in lim.spindle_rpm)
        most = np.where((rpm >= lo * (1 - 1e-9)) & (rpm <= hi * (1 + 1e-9)), most, -1.0)
        used.append("spindle_rpm")
    if lim.axial_depth_m is not None:
        least = np.full(rpm.size, float(lim.axial_depth_m[0]))
        most = np.minimum(most, float(lim.axial_depth_m[1]))
        used.append("axial_depth_m")
    process = [name for name in ("spindle_power_W", "spindle_torque_N_m", "max_force_N")
               if getattr(lim, name) is not None]
    coef = setup.material.cutting_coefficients
    if process and coef is not None:
        from planner.cut_model import CutModel

        cm = CutModel(model, setup.tool, setup.cut, coef)
        fz = float(setup.cut.feed_per_tooth_m)
        per_depth = float(cm.mean_torque(1.0, fz))  # N m per m of depth
        if lim.spindle_torque_N_m is not None and per_depth > 0:
            most = np.minimum(most, float(lim.spindle_torque_N_m) / per_depth)
        if lim.spindle_power_W is not None and per_depth > 0:
            most = np.minimum(most, float(lim.spindle_power_W) / (2.0 * np.pi * rpm / 60.0 * per_depth))
        if lim.max_force_N is not None:
            top = float(lim.axial_depth_m[1]) if lim.axial_depth_m is not None else 10.0 * setup.tool.diameter_m
            bottom = float(lim.axial_depth_m[0]) if lim.axial_depth_m is not None else 1e-3 * top
            most = np.minimum(most, float(cm.depth_boundary(0, float(lim.max_force_N), [fz], bottom, top)[0]))
        used += process
    return least, most, tuple(used)


def _too_close(rpm: np.ndarray, picked: list[float], gap: float) -> np.ndarray:
    """Speeds within ``gap`` (relative) of a picked one."""
    close = np.zeros(rpm.size, bool)
    for r in picked:
        close |= np.abs(rpm / r - 1.0) < gap
    return close


def _greedy_improvement(ei: np.ndarray, rpm: np.ndarray, n: int, gap: float):
    picks, gains = [], []
    for _ in range(n):
        score = np.where(_too_close(rpm, [rpm[j] for _, j in picks], gap)[None, :], -1.0, ei)
        i, j = np.unravel_index(int(np.argmax(score)), score.shape)
        if score[i, j] < 0:
            break
        picks.append((int(i), int(j)))
        gains.append(float(ei[i, j]))
    return picks, gains


def _greedy_boundary(lobes: ProbabilityLobes, depth: np.ndarray, allowed: np.ndarray, n: int,
                     likelihood: Likelihood, gap: float, detected: bool = False):
    """Greedy expected reduction of the summed variance of the log limit (module notes); ``depth``
    (n_depth, n_rpm) the candidates per speed, ``allowed`` (n_rpm,) the speeds allowed."""
    log_lim = np.log(lobes.limits)  # (S, R)
    s_count = log_lim.shape[0]
    eps = float(likelihood.mislabel)
    # P(outcome 'chatter' | sample) at every candidate (depth i, speed j): (S, D * R)
    x = likelihood.mark_logit(np.log(depth)[None, :, :] - log_lim[:, None, :], bool(detected))
    q = (eps + (1.0 - 2.0 * eps) * expit(x)).reshape(s_count, -1)
    sq = log_lim**2
    w = np.full(s_count, 1.0 / s_count)

    def total_variance(w):
        m = w @ log_lim / w.sum()
        return float(np.sum(w @ sq / w.sum() - m**2))

    v0 = total_variance(w)
    picks, scores = [], []
    n_rpm = lobes.rpm.size
    for _ in range(n):
        w = w / w.sum()
        explained = np.zeros(q.shape[1])
        for like in (q, 1.0 - q):  # outcomes chatter, stable
            wy = w[:, None] * like  # (S, C)
            py = wy.sum(axis=0)
            m1 = wy.T @ log_lim  # (C, R): P(y) * mean_y
            explained += np.sum(m1**2, axis=1) / np.maximum(py, 1e-300)
        # expected variance after the cut = E[L^2] - sum_y P(y) mean_y^2; its reduction:
        reduction = explained - np.sum((w @ log_lim) ** 2)
        blocked = _too_close(lobes.rpm, [lobes.rpm[j] for _, j in picks], gap) | ~allowed
        reduction = np.where(np.tile(blocked, depth.shape[0]), -np.inf, reduction)
        c = int(np.argmax(reduction))
        if not np.isfinite(reduction[c]):
            break
        i, j = divmod(c, n_rpm)
        picks.append((int(i), int(j)))
        scores.append(float(reduction[c]) / v0 if v0 > 0 else 0.0)
        qc = q[:, c]
        w = w * (qc if float(w @ qc) >= 0.5 else 1.0 - qc)  # believe the more probable outcome
    return picks, scores
