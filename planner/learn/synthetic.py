"""Synthetic test-cut problems with a known truth (tests and ``benchmarks/bench_learn.py``)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Material, Tool
from oma.modal import ModalModel
from stability.setup import Limits, Setup

from .likelihood import CHATTER, STABLE
from .outcomes_io import CutTable, record_outcome
from .tables import reference_limits

__all__ = ["Problem", "tool_problem", "two_mode_problem", "true_limits", "random_cuts", "label", "record_labels"]


@dataclass(frozen=True)
class Problem:
    setup: Setup
    truth: ModalModel
    truth_coefficients: CuttingCoefficients
    prior: ModalModel  # the prior's model; its coefficients are in setup.material


def tool_problem(*, u_prior=(0.0, 0.0, 0.0, 0.0, 0.0), fn_hz=900.0, zeta=0.03, stiffness_N_m=1.5e7,
                 ktc=7.0e8, krc=2.1e8, rpm_range=(6000.0, 24000.0)) -> Problem:
    """A one-mode tool (mode along the cut normal and 45 deg, 2 flutes, 12.7 mm): the truth, and a
    prior whose five log-multipliers are ``-u_prior`` away from it (the prior is off by ``u``)."""
    tool = Tool(teeth=2, diameter_m=0.0127, helix_rad=0.0)
    truth = ModalModel([fn_hz], [zeta], [stiffness_N_m], [[0.6, 0.8, 0.0]])
    coef = CuttingCoefficients(ktc, krc)
    u = np.asarray(u_prior, dtype=float)
    prior = replace(truth, natural_frequency_hz=truth.natural_frequency_hz * np.exp(u[0]),
                    stiffness_N_m=truth.stiffness_N_m * np.exp(u[1]),
                    damping_ratio=truth.damping_ratio * np.exp(u[2]))
    prior_coef = CuttingCoefficients(ktc * np.exp(u[3]), krc * np.exp(u[4]))
    cut = Cut(feed_per_tooth_m=1e-4, radial_depth_m=0.5 * tool.diameter_m, milling="down",
              feed_direction=[1, 0, 0], normal_direction=[0, 1, 0])
    setup = Setup(tool=tool, cut=cut, material=Material("synthetic", prior_coef),
                  limits=Limits(spindle_rpm=tuple(rpm_range)))
    return Problem(setup=setup, truth=truth, truth_coefficients=coef, prior=prior)


def two_mode_problem(*, u_prior=(0.0,) * 8, fn_hz=(900.0, 1250.0), zeta=(0.03, 0.03),
                     stiffness_N_m=(1.5e7, 2.0e7), directions=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
                     ktc=7.0e8, krc=2.1e8, rpm_range=(6000.0, 24000.0)) -> Problem:
    """A two-mode tool (by default one mode along the feed, one along the cut normal, as in the
    two-mode study of Cornelius et al.): the truth, and a prior whose per-mode log-multipliers
    (frequency[0, 1], stiffness[0, 1], damping[0, 1], Ktc, Krc) are ``-u_prior`` away from it:
    ``learn`` moves both modes by one factor per group, so modes off apart are outside its model
    (``benchmarks/bench_learn_modes.py``)."""
    base = tool_problem(fn_hz=fn_hz[0], zeta=zeta[0], stiffness_N_m=stiffness_N_m[0], ktc=ktc, krc=krc,
                        rpm_range=rpm_range)
    truth = ModalModel(list(fn_hz), list(zeta), list(stiffness_N_m), [list(d) for d in directions])
    u = np.asarray(u_prior, dtype=float)
    prior = replace(truth, natural_frequency_hz=truth.natural_frequency_hz * np.exp(u[0:2]),
                    stiffness_N_m=truth.stiffness_N_m * np.exp(u[2:4]),
                    damping_ratio=truth.damping_ratio * np.exp(u[4:6]))
    setup = replace(base.setup, material=Material("synthetic", CuttingCoefficients(ktc * np.exp(u[6]),
                                                                                    krc * np.exp(u[7]))))
    return Problem(setup=setup, truth=truth, truth_coefficients=base.truth_coefficients, prior=prior)


def true_limits(problem: Problem, rpm, radial_depth_m, down, *, converged: bool = True) -> np.ndarray:
    """Limit depth of the truth at each cut: SDM (finer steps when ``converged``) at every
    immersion, the labelling rule of the benchmark."""
    rpm, ae, down = (np.atleast_1d(np.asarray(x)) for x in (rpm, radial_depth_m, down))
    out = np.empty(rpm.size)
    keys = np.stack([ae.astype(float), down.astype(float)], axis=1)
    uniq, grp = np.unique(keys, axis=0, return_inverse=True)
    for g, (a, d) in enumerate(uniq):
        rows = np.flatnonzero(grp.ravel() == g)
        cut = replace(problem.setup.cut, radial_depth_m=float(a), milling="down" if d else "up")
        out[rows] = reference_limits(problem.truth, problem.setup.tool, cut, problem.truth_coefficients,
                                     rpm[rows], method="sdm", steps_per_mode_period=40.0 if converged else 20.0,
                                     min_steps=80 if converged else 40)
    return out


def random_cuts(problem: Problem, n: int, rng: np.random.Generator, *, immersions=(0.1, 0.25, 0.5, 1.0),
                depth_range=None) -> CutTable:
    """``n`` cuts: speeds uniform in the setup's range, radial immersions from ``immersions``,
    up/down at random, axial depths log-uniform in ``depth_range`` (default 0.2 .. 5 x the
    truth's smallest slotting limit), no outcome."""
    lo, hi = problem.setup.limits.spindle_rpm
    d = problem.setup.tool.diameter_m
    rpm = rng.uniform(lo, hi, n)
    ae = rng.choice(np.asarray(immersions), n) * d
    down = rng.random(n) < 0.5
    if depth_range is None:
        ref = float(np.min(true_limits(problem, np.linspace(lo, hi, 25), np.full(25, d), np.ones(25, bool),
                                       converged=False)))
        depth_range = (0.3 * ref, 8.0 * ref)
    ap = np.exp(rng.uniform(np.log(depth_range[0]), np.log(depth_range[1]), n))
    return CutTable(rpm, ap, ae, down, np.full(n, -1), np.ones(n), np.full(n, np.nan), np.zeros(n, bool))


def label(cuts: CutTable, limits: np.ndarray, rng: np.random.Generator, *, flip: float = 0.05) -> CutTable:
    """Outcomes from the limits, a share ``flip`` of them flipped (mislabelled)."""
    chatter = cuts.axial_depth_m >= limits
    flipped = rng.random(cuts.n_cuts) < flip
    out = np.where(chatter ^ flipped, CHATTER, STABLE)
    return replace(cuts, outcome=out)


def record_labels(problem: Problem, cuts: CutTable, *, duration_s: float = 2.0, sample_rate_hz: float = 10_000.0,
                  background_N2: float = 1.0, seed: int = 0) -> tuple[CutTable, np.ndarray]:
    """Outcomes as a shop gets them from records: each cut simulated in the time domain (the
    truth's structure and coefficients, the tool leaving the cut, a weak broadband background
    force, ``duration_s`` from rest) and judged by ``diagnose``'s chatter detection, its
    confidence the label's weight (:func:`planner.learn.outcomes_io.record_outcome`). A cut whose
    vibration grows past the tool diameter is chatter with weight 1. No labels are flipped: the
    detector's own misses near the limit (slowly growing chatter, a line weaker than the forced
    one) are the noise. Returns the labelled table and which cuts diverged."""
    from stability.simulate import BackgroundForce, SimulationDiverged, simulate

    outcome, weight = np.empty(cuts.n_cuts, int), np.empty(cuts.n_cuts)
    diverged = np.zeros(cuts.n_cuts, bool)
    background = BackgroundForce(variance_N2=(background_N2,) * 3, bandwidth_hz=0.4 * sample_rate_hz)
    for i in range(cuts.n_cuts):
        cut = replace(problem.setup.cut, radial_depth_m=float(cuts.radial_depth_m[i]),
                      milling="down" if cuts.down[i] else "up", spindle_rpm=float(cuts.spindle_rpm[i]),
                      axial_depth_m=float(cuts.axial_depth_m[i]))
        try:
            sim = simulate(problem.truth, problem.setup.tool, cut, problem.truth_coefficients, duration_s=duration_s,
                           sample_rate_hz=sample_rate_hz, background=background, seed=seed + i)
        except SimulationDiverged:
            outcome[i], weight[i], diverged[i] = CHATTER, 1.0, True
            continue
        outcome[i], weight[i] = record_outcome(sim.to_record(problem.setup.tool, cut))
    return replace(cuts, outcome=outcome, weight=weight, detected=np.ones(cuts.n_cuts, bool)), diverged
