"""Limit-depth tables of test cuts over the learned parameters (the fast forward model of ``learn``).

The posterior over the modal parameters and cutting coefficients needs, for every parameter set
and every test cut, the stability limit depth at that cut's speed and engagement. Two exact
scalings of the milling equations (any number of modes, ZOA and SDM alike) remove two of the five
parameter directions from the computation:

* scaling every modal stiffness by ``s`` and the cutting coefficients by ``c`` (same ``Krc/Ktc``)
  scales the limit depth by ``s / c`` (the equations see only ``a Ktc / k``);
* scaling every natural frequency by ``F`` (damping ratios kept) is a change of time scale: the
  limit at speed ``n`` equals the reference structure's limit at ``n / F``.

So ``log b(theta) = T_j(log F, log zeta-factor, log ratio-factor) + log s - log c`` where the
table ``T_j`` of cut ``j`` is the log limit of the *reference* structure (the prior) at the speeds
``n_j / F`` for a grid of damping and ratio factors: multilinear interpolation on that grid is the
only approximation (its error against direct ZOA/SDM runs is measured in
``tests/test_learn_posterior.py``). One SDM problem per (engagement, damping node, ratio node)
solves all the cuts' speeds of that engagement at once (:meth:`stability.sdm.SDMProblem.limits`),
one ZOA envelope likewise.

The groups are shared by all modes ("frequency", "stiffness", "damping" multiply every mode):
for a one-mode tool this is each mode's own parameters; for several modes it is a restriction
(notes/learn.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from oma.cutting import Cut, CuttingCoefficients, Tool
from oma.modal import ModalModel

from ..workers import default_workers, process_map

__all__ = ["Grid", "LimitTable", "build_table", "direct_log_limits", "mode_shares", "reference_limits", "MAX_DEPTH_M"]

MAX_DEPTH_M = 1.0  # a limit above this (or none) counts as this: no test cut is that deep
SDM_BELOW_IMMERSION = 0.2  # ae/D below which the SDM is used (as `plan --method auto`)
SDM_STEPS_PER_MODE_PERIOD, SDM_MIN_STEPS = 20.0, 40  # about 0.5 % from converged (bench_learn)
# Most damping and Krc/Ktc nodes of a fine (posterior-covering) table, and of the coarse first stage.
# The posterior of both is weakly pinned, so the tables span most of the prior (+-3 sds: damping x0.24..4,
# ratio x0.35..2.8) and the log limit is far from linear over that: 3 x 2 nodes (the first version) put
# the limit at the TRUE parameters off by up to a factor 2.4 at half and full immersion (docs/learn.md).
FINE_NODES, COARSE_NODES = (5, 4), (4, 3)
# Tables of fewer limits than this are filled in this process (a fork costs more than it saves).
PARALLEL_MIN_LIMITS = 400


@dataclass(frozen=True)
class Grid:
    """Nodes of the tables in log-multiplier space, and the SDM resolution used to fill them.

    ``log_f_range``: the frequency factor's range ``(lo, hi)`` in log; ``log_speed_step``: spacing
    of the log-speed lattice (the frequency axis, by the time scaling); ``log_zeta`` and
    ``log_ratio``: increasing nodes of the damping and ``Krc/Ktc`` factors (one node fixes it);
    ``sdm_steps``: (steps per period of the highest mode, fewest steps per tooth period).
    """

    log_f_range: tuple[float, float]
    log_speed_step: float
    log_zeta: np.ndarray
    log_ratio: np.ndarray
    sdm_steps: tuple[float, int] = (SDM_STEPS_PER_MODE_PERIOD, SDM_MIN_STEPS)

    @classmethod
    def around(cls, sd_f: float, sd_zeta: float, sd_ratio: float, *, step: float = 0.015, n_zeta: int = 4,
               n_ratio: int = 3, span: float = 3.0, sdm_steps=(SDM_STEPS_PER_MODE_PERIOD, SDM_MIN_STEPS)) -> "Grid":
        """Nodes over ``+-span`` standard deviations of each log factor (fixed when its sd is 0)."""
        def nodes(sd, n):
            return np.zeros(1) if sd <= 0 else np.linspace(-span * sd, span * sd, n)
        return cls((-span * sd_f, span * sd_f), float(step), nodes(sd_zeta, n_zeta), nodes(sd_ratio, n_ratio),
                   tuple(sdm_steps))

    @classmethod
    def covering(cls, u_f, u_zeta, u_ratio, *, bounds: "Grid", margin_sd: float = 2.0, step: float = 0.015,
                 zeta_spacing: float = 0.3, ratio_spacing: float = 0.4, max_zeta: int = 4,
                 max_ratio: int = 3) -> "Grid":
        """Nodes covering samples (log factors) with ``margin_sd`` of their sd beyond the extreme
        ones, inside ``bounds`` (the prior's grid): the fine grid of the second stage."""
        def span(x, lo, hi, floor):
            x = np.asarray(x, dtype=float)
            m = margin_sd * max(float(np.std(x)), floor)
            return max(lo, float(x.min()) - m), min(hi, float(x.max()) + m)

        def nodes(x, prior_nodes, spacing, most):
            if prior_nodes.size == 1:
                return prior_nodes
            lo, hi = span(x, prior_nodes[0], prior_nodes[-1], spacing / 4)
            return np.linspace(lo, hi, int(np.clip(np.ceil((hi - lo) / spacing) + 1, 2, most)))

        return cls(span(u_f, *bounds.log_f_range, step), float(step),
                   nodes(u_zeta, bounds.log_zeta, zeta_spacing, max_zeta),
                   nodes(u_ratio, bounds.log_ratio, ratio_spacing, max_ratio), bounds.sdm_steps)


@dataclass(frozen=True)
class LimitTable:
    """``log`` limit depth (m) of the reference structure (the prior) per engagement.

    For engagement ``g``: ``values[g]`` of shape ``(n_lattice_g, n_zeta, n_ratio)`` at the log
    speeds ``lattice[g] * step``. Cut ``j`` has engagement ``group[j]`` and speed ``rpm[j]``.
    A table built for given samples (``build_table(..., samples=)``) holds NaN at the entries none
    of them reads: other parameter sets read NaN there, never a value that was not computed.
    """

    grid: Grid
    engagements: tuple[tuple[float, bool], ...]
    lattice: tuple[np.ndarray, ...]
    values: tuple[np.ndarray, ...]
    group: np.ndarray
    rpm: np.ndarray
    methods: tuple[str, ...]

    @property
    def n_cuts(self) -> int:
        return int(self.rpm.size)

    def contains(self, u_f, u_zeta, u_kt, u_kr) -> np.ndarray:
        """Whether each parameter set lies inside the table's range (frequency, damping and
        ``Krc/Ktc`` factors; stiffness and ``Ktc`` enter exactly): outside it :meth:`log_limit`
        clips to the edge, which is no forward model at all, so ``learn`` keeps its posterior
        inside."""
        u_f, u_zeta, u_ratio = (np.atleast_1d(np.asarray(x, dtype=float)) for x in (u_f, u_zeta,
                                                                                     np.subtract(u_kr, u_kt)))
        tol = 1e-9
        ok = (u_f >= self.grid.log_f_range[0] - tol) & (u_f <= self.grid.log_f_range[1] + tol)
        for nodes, x in ((self.grid.log_zeta, u_zeta), (self.grid.log_ratio, u_ratio)):
            if nodes.size > 1:
                ok &= (x >= nodes[0] - tol) & (x <= nodes[-1] + tol)
        return ok

    def log_limit(self, u_f, u_k, u_zeta, u_kt, u_kr, *, cuts=None) -> np.ndarray:
        """``log`` limit depth, shape ``(n_samples, n_cuts)``, for log-multipliers each of shape
        ``(n_samples,)``: frequency, stiffness, damping, ``Ktc``, ``Krc`` factors.

        ``cuts`` (indices) restricts the result to those cuts.
        """
        u_f, u_k, u_zeta, u_kt, u_kr = (np.atleast_1d(np.asarray(x, dtype=float)) for x in
                                        (u_f, u_k, u_zeta, u_kt, u_kr))
        cuts = np.arange(self.n_cuts) if cuts is None else np.asarray(cuts, dtype=int)
        out = np.empty((u_f.size, cuts.size))
        zw = _bracket(self.grid.log_zeta, u_zeta)
        rw = _bracket(self.grid.log_ratio, u_kr - u_kt)
        for g in np.unique(self.group[cuts]):
            cols = np.flatnonzero(self.group[cuts] == g)
            val = self.values[g]
            r0, t = _lattice_bracket(self.grid, self.lattice[g], self.rpm[cuts[cols]], u_f)
            acc = np.zeros(t.shape)
            for (iz, wz) in zw:
                for (ir, wr) in rw:
                    w = (wz * wr)[:, None]
                    acc += w * ((1.0 - t) * val[r0, iz[:, None], ir[:, None]] +
                                t * val[r0 + 1, iz[:, None], ir[:, None]])
            out[:, cols] = acc
        return out + (u_k - u_kt)[:, None]


def _lattice_bracket(grid: Grid, lattice: np.ndarray, rpm, u_f):
    """Row ``r0`` of the lower of the two lattice points bracketing each speed for each frequency
    factor (the speed scaled by ``exp(-u_f)``, ``u_f`` clipped to the grid's range), and the
    weight ``t`` of the upper one: both (n_samples, n_speeds)."""
    uf = np.clip(u_f, *grid.log_f_range)
    x = (np.log(rpm)[None, :] - uf[:, None]) / grid.log_speed_step  # lattice units
    i0 = np.floor(x).astype(np.int64)
    return np.clip(np.searchsorted(lattice, i0), 0, lattice.size - 2), x - i0


def _bracket(nodes: np.ndarray, x: np.ndarray):
    """Lower/upper node index and weight of linear interpolation, clipped to the nodes' range:
    ``[(i_lo, w_lo), (i_hi, w_hi)]``."""
    if nodes.size == 1:
        z = np.zeros(x.shape, dtype=int)
        return [(z, np.ones(x.shape)), (z, np.zeros(x.shape))]
    xc = np.clip(x, nodes[0], nodes[-1])
    i = np.clip(np.searchsorted(nodes, xc, side="right") - 1, 0, nodes.size - 2)
    t = (xc - nodes[i]) / (nodes[i + 1] - nodes[i])
    return [(i, 1.0 - t), (i + 1, t)]


def scaled_model(model: ModalModel, *, log_f=0.0, log_k=0.0, log_zeta=0.0) -> ModalModel:
    """The model with every frequency, stiffness and damping ratio multiplied by ``exp(.)``
    (damping ratios kept below 1)."""
    return replace(model, natural_frequency_hz=model.natural_frequency_hz * np.exp(log_f),
                   stiffness_N_m=model.stiffness_N_m * np.exp(log_k),
                   damping_ratio=np.minimum(model.damping_ratio * np.exp(log_zeta), 0.95))


def scaled_coefficients(coefficients: CuttingCoefficients, *, log_kt=0.0, log_kr=0.0) -> CuttingCoefficients:
    return replace(coefficients, Ktc_N_m2=coefficients.Ktc_N_m2 * np.exp(log_kt),
                   Krc_N_m2=coefficients.Krc_N_m2 * np.exp(log_kr))


def method_for(tool: Tool, radial_depth_m: float, method: str = "sdm") -> str:
    """The method of one engagement: ``'sdm'`` or ``'zoa'`` as given; ``'auto'``: the SDM below
    ``SDM_BELOW_IMMERSION`` radial immersion, else the ZOA (the rule of ``plan --method auto``).

    The default is the SDM everywhere: for a 2-flute straight tool even slotting, the ZOA limit
    is 50 % above the converged SDM's at high speed (measured, notes/learn.md), far more than the
    3 % soft boundary of the likelihood.
    """
    if method not in ("auto", "sdm", "zoa"):
        raise ValueError(f"method must be one of 'auto', 'sdm', 'zoa', found {method!r}")
    if method != "auto":
        return method
    return "sdm" if radial_depth_m / tool.diameter_m < SDM_BELOW_IMMERSION else "zoa"


def reference_limits(model: ModalModel, tool: Tool, cut: Cut, coefficients: CuttingCoefficients, rpm, *,
                     method: str, steps_per_mode_period: float = SDM_STEPS_PER_MODE_PERIOD,
                     min_steps: int = SDM_MIN_STEPS, zoa_start: bool = False) -> np.ndarray:
    """Limit depth (m, capped at ``MAX_DEPTH_M``) of one engagement at many speeds, any order.

    The SDM's search is :meth:`stability.sdm.SDMProblem.limits` (at low speed its multipliers
    are found without forming the monodromy: :meth:`stability.sdm.SDMProblem._radii`).

    ``zoa_start``: each SDM search starts from the ZOA limit at its speed (the envelope's values,
    its cusps left out). Without it a search starts from the envelope only when the envelope has
    no cusps between the speeds, which over more than a few lobes it always has: then from 1 mm,
    and the bracketing takes ~5 evaluations instead of ~2 (measured on the kr500 example's
    nodes: 11-16 evaluations per limit against 10-10.5, 22 % of a table's time). The limits agree
    to the search's tolerance (2e-4 in log at most) except where a thin island of instability
    lies below the boundary (narrower in depth than the islands ladder's rungs,
    :meth:`stability.sdm.SDMProblem.limits`): which of the two ends a search finds depends on
    where it starts (the example's probability-lobe table: 10 of 4561 entries, up to 0.14 in log,
    8 of them lower with the ZOA start, i.e. on the island). The default keeps the 1 mm start so
    that the tables of ``learn`` (and its posterior) and ``plan``'s stay as they were; the
    probability lobes use the ZOA start.
    """
    from stability import zoa
    from stability.sdm import SDMProblem, steps_per_period

    rpm = np.asarray(rpm, dtype=float).ravel()
    uniq, inverse = np.unique(rpm, return_inverse=True)
    if method == "zoa":
        env = zoa.envelope(model, tool, cut, coefficients, uniq, n_freq=2000)
        depth = np.asarray(env.depth_limit_m)[~np.asarray(env.is_intersection)]
    else:
        problem = SDMProblem(model, tool, cut, coefficients)
        steps = steps_per_period(problem, uniq, steps_per_mode_period=steps_per_mode_period,
                                 min_steps=min_steps)
        env = zoa.envelope(model, tool, cut, coefficients, uniq, n_freq=2000)
        guess = np.asarray(env.depth_limit_m)
        if zoa_start:
            guess = guess[~np.asarray(env.is_intersection)]
        guess = guess[: uniq.size] if guess.size == uniq.size else np.full(uniq.size, np.nan)
        out = problem.limits(uniq, steps, guess_m=np.where(np.isfinite(guess), guess, np.nan),
                             depth_rtol=2e-3, max_depth_m=MAX_DEPTH_M, chatter_frequency=False)
        depth = np.array([o.depth_limit_m for o in out])
    depth = np.where(np.isfinite(depth), np.minimum(depth, MAX_DEPTH_M), MAX_DEPTH_M)
    return depth[inverse]


def _log_limits_job(job) -> np.ndarray:
    """``log`` limits of one parameter set (five log-multipliers ``u`` of the reference) at speeds
    of one engagement, computed directly: a table node (damping and ratio factors only) or the
    check of a table (``zoa_start``: :func:`reference_limits`)."""
    model, tool, cut, coefficients, u, rpm, how, sdm_steps, zoa_start = job
    return np.log(reference_limits(scaled_model(model, log_f=u[0], log_k=u[1], log_zeta=u[2]), tool, cut,
                                   scaled_coefficients(coefficients, log_kt=u[3], log_kr=u[4]), rpm, method=how,
                                   steps_per_mode_period=sdm_steps[0], min_steps=sdm_steps[1], zoa_start=zoa_start))


def direct_log_limits(model: ModalModel, tool: Tool, base_cut: Cut, coefficients: CuttingCoefficients, rpm,
                      radial_depth_m, down, samples, *, method: str = "sdm", sdm_steps=None,
                      workers: int | None = None, desc: str | None = "direct limits") -> np.ndarray:
    """``log`` limit depth of each parameter set (rows of ``samples``: five log-multipliers of the
    reference) at each cut, computed directly by the cut's method: the check of a table's
    interpolation, shape (n_samples, n_cuts). ``desc``: the label of the progress bar over its
    jobs (one per sample and engagement; :func:`planner.workers.progress_bar`; None: none)."""
    rpm = np.asarray(rpm, dtype=float).ravel()
    ae = np.asarray(radial_depth_m, dtype=float).ravel()
    down = np.asarray(down, dtype=bool).ravel()
    samples = np.atleast_2d(np.asarray(samples, dtype=float))
    steps = tuple(sdm_steps) if sdm_steps is not None else (SDM_STEPS_PER_MODE_PERIOD, SDM_MIN_STEPS)
    keys = np.stack([ae, down.astype(float)], axis=1)
    uniq, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.ravel()
    jobs, where = [], []
    for i, u in enumerate(samples):
        for g, (a, d) in enumerate(uniq):
            cols = np.flatnonzero(group == g)
            cut = replace(base_cut, radial_depth_m=float(a), milling="down" if d else "up")
            jobs.append((model, tool, cut, coefficients, u, rpm[cols], method_for(tool, float(a), method), steps,
                         False))
            where.append((i, cols))
    if workers is None:  # its jobs solve a few speeds each: forking pays at fewer limits than for a table
        workers = default_workers() if samples.shape[0] * rpm.size >= PARALLEL_MIN_LIMITS / 4 else 1
    out = np.empty((samples.shape[0], rpm.size))
    for (i, cols), val in zip(where, process_map(_log_limits_job, jobs, workers=workers, desc=desc)):
        out[i, cols] = val
    return out


def build_table(model: ModalModel, tool: Tool, base_cut: Cut, coefficients: CuttingCoefficients,
                rpm, radial_depth_m, down, grid: Grid, *, method: str = "sdm",
                workers: int | None = None, known: LimitTable | None = None, samples=None,
                zoa_start: bool = False, desc: str | None = "limit table") -> LimitTable:
    """The :class:`LimitTable` of cuts given by speed, radial depth and milling.

    Per engagement, the log-speed lattice holds every lattice point of ``log n_j - log_f_range``
    (plus one step each side) for each cut ``j``, so a cut costs ``range / step`` limits at most
    and cuts of one engagement at nearby speeds share them.

    Parameters
    ----------
    model, tool, coefficients
        The reference (prior) structure and force model.
    base_cut : Cut
        Supplies the cutting frame (feed and normal directions) of the setup.
    rpm, radial_depth_m : array_like, shape (n_cuts,)
    down : array_like of bool, shape (n_cuts,)
        Down milling (else up).
    grid : Grid
    method : {'sdm', 'zoa', 'auto'}
        See :func:`method_for`.
    workers : int, optional
        Processes filling the table; by default :func:`planner.workers.default_workers`, or this process alone for
        tables of fewer than ``PARALLEL_MIN_LIMITS`` limits. The values do not depend on it.
    known : LimitTable, optional
        A table already built from the same model, coefficients and cutting frame on the same
        lattice step, nodes and SDM resolution (e.g. over a narrower speed range): the lattice
        points it holds for an engagement (same radial depth, milling and method) are copied from
        it, only the others are solved (a range extended downward costs only its new speeds).
    samples : array_like, shape (n_samples, 5), optional
        Only the entries these parameter sets (log-multipliers of the reference) read at these
        cuts are solved (the lattice points and damping and ratio nodes their interpolation
        brackets); the others are NaN. The values solved are those of the whole table (each is
        its own limit search), so every result for these samples is the whole table's, at a
        fraction of the cost when the samples fill the box unevenly (a posterior whose damping
        and ``Krc/Ktc`` are correlated leaves corners of the node grid empty: on the kr500
        example 3 of 20 nodes, 21 % of the entries). For a table read only by these samples
        (the probability lobes of a posterior).
    zoa_start : bool
        Each SDM search starts from the ZOA limit at its speed (:func:`reference_limits`: ~22 %
        faster, the same limits to the search's tolerance).
    desc : str, optional
        The label of the progress bar over the table's jobs (one per engagement, damping node and
        ratio node; :func:`planner.workers.progress_bar`: on a terminal, for runs over a few
        seconds); None: none. The values do not depend on it.
    """
    if known is not None and not _same_nodes(known.grid, grid):
        raise ValueError("known must be a table of the same lattice step, damping and ratio nodes and SDM steps")
    rpm = np.asarray(rpm, dtype=float).ravel()
    ae = np.asarray(radial_depth_m, dtype=float).ravel()
    down = np.asarray(down, dtype=bool).ravel()
    h = grid.log_speed_step
    f_lo, f_hi = grid.log_f_range
    keys = np.stack([ae, down.astype(float)], axis=1)
    uniq, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.ravel()
    lattices, cuts, hows = [], [], []
    for g, (a, d) in enumerate(uniq):
        x = np.log(rpm[group == g]) / h
        lo, hi = np.floor(x - f_hi / h) - 1, np.ceil(x - f_lo / h) + 1
        lattices.append(np.unique(np.concatenate([np.arange(l0, h0 + 1) for l0, h0 in zip(lo, hi)]).astype(np.int64)))
        cuts.append(replace(base_cut, radial_depth_m=float(a), milling="down" if d else "up"))
        hows.append(method_for(tool, float(a), method))
    # values already in `known` (entry by entry: a table built for samples holds NaN elsewhere),
    # and the entries left to solve (those the samples read, when given), per engagement
    tables, todo = [], []
    for g, (lat, a, d, how) in enumerate(zip(lattices, uniq[:, 0], uniq[:, 1], hows)):
        val = np.full((lat.size, grid.log_zeta.size, grid.log_ratio.size), np.nan)
        kg = None if known is None else _engagement_of(known, float(a), bool(d), how)
        if kg is not None:
            shared = np.isin(lat, known.lattice[kg])
            val[shared] = known.values[kg][np.searchsorted(known.lattice[kg], lat[shared])]
        need = np.ones(val.shape, dtype=bool) if samples is None else _entries_read(
            grid, lat, rpm[group == g], np.atleast_2d(np.asarray(samples, dtype=float)))
        tables.append(val)
        todo.append(need & np.isnan(val))
    # one job per (engagement, damping node, ratio node): independent SDM searches over the lattice
    # points left at that node
    nodes = [(iz, ir) for iz in range(grid.log_zeta.size) for ir in range(grid.log_ratio.size)]
    jobs = [(model, tool, cuts[g], coefficients, (0.0, 0.0, float(grid.log_zeta[iz]), 0.0, float(grid.log_ratio[ir])),
             np.exp(lattices[g][todo[g][:, iz, ir]] * h), hows[g], grid.sdm_steps, bool(zoa_start))
            for g in range(len(cuts)) for iz, ir in nodes if todo[g][:, iz, ir].any()]
    work = sum(int(t.sum()) for t in todo)
    if workers is None:
        workers = default_workers() if work >= PARALLEL_MIN_LIMITS else 1
    results = iter(process_map(_log_limits_job, jobs, workers=workers, desc=desc))
    for val, left in zip(tables, todo):
        for iz, ir in nodes:
            if left[:, iz, ir].any():
                val[left[:, iz, ir], iz, ir] = next(results)
        val.setflags(write=False)
    engagements = [(float(a), bool(d)) for a, d in uniq]
    methods = tuple(method_for(tool, a, method) for a in ae)
    return LimitTable(grid=grid, engagements=tuple(engagements), lattice=tuple(lattices), values=tuple(tables),
                      group=group, rpm=rpm, methods=methods)


def _same_nodes(a: Grid, b: Grid) -> bool:
    """Whether two grids give a lattice point the same value (the frequency range only says which
    points a table holds)."""
    return (a.log_speed_step == b.log_speed_step and tuple(a.sdm_steps) == tuple(b.sdm_steps)
            and np.array_equal(a.log_zeta, b.log_zeta) and np.array_equal(a.log_ratio, b.log_ratio))


def _entries_read(grid: Grid, lattice: np.ndarray, rpm: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Which entries ``(n_lattice, n_zeta, n_ratio)`` of one engagement's values
    :meth:`LimitTable.log_limit` reads for the ``samples`` at the speeds ``rpm``: the two lattice
    points and the damping and ratio nodes bracketing each (a bracket's node counts even at
    weight 0: the product with a NaN would be NaN)."""
    r0, _ = _lattice_bracket(grid, lattice, rpm, samples[:, 0])
    need = np.zeros((lattice.size, grid.log_zeta.size, grid.log_ratio.size), dtype=bool)
    for iz, _ in _bracket(grid.log_zeta, samples[:, 2]):
        for ir, _ in _bracket(grid.log_ratio, samples[:, 4] - samples[:, 3]):
            for row in (r0, r0 + 1):
                need[row, iz[:, None], ir[:, None]] = True
    return need


def _engagement_of(table: LimitTable, radial_depth_m: float, down: bool, method: str) -> int | None:
    """The index of ``table``'s engagement with this radial depth, milling and method, or None."""
    for g, (a, d) in enumerate(table.engagements):
        cut = np.flatnonzero(table.group == g)
        if a == radial_depth_m and d == down and cut.size and table.methods[cut[0]] == method:
            return g
    return None


def mode_shares(model: ModalModel, tool: Tool, base_cut: Cut, coefficients: CuttingCoefficients, rpm, radial_depth_m,
                down, *, method: str = "sdm", sdm_steps=None, step: float = 0.1, workers: int | None = None) -> np.ndarray:
    """How much each mode's stiffness sets the limit of each cut: ``d log b / d log k_r``, shape
    (n_cuts, n_modes), by central differences of direct limits (``step`` in log stiffness).

    The limit scales exactly with a common stiffness factor (module notes), so by Euler's theorem
    on homogeneous functions the shares of a cut sum to one (less with a residual compliance, which
    no modal stiffness scales): they say which modes the cut's outcome is evidence about. A share can be negative: a mode above the chatter frequency adds a
    positive real part to the receptance there, and making it stiffer can lower the limit. A cut
    whose limit is capped (``MAX_DEPTH_M``: no limit) gets NaN.
    """
    def log_limits(m):
        return direct_log_limits(m, tool, base_cut, coefficients, rpm, radial_depth_m, down, np.zeros((1, 5)),
                                 method=method, sdm_steps=sdm_steps, workers=workers, desc="mode shares")[0]

    base = log_limits(model)
    out = np.empty((base.size, model.n_modes))
    for r in range(model.n_modes):
        bump = step * (np.arange(model.n_modes) == r)
        up, dn = (log_limits(replace(model, stiffness_N_m=model.stiffness_N_m * np.exp(s * bump))) for s in (1, -1))
        out[:, r] = (up - dn) / (2.0 * step)
    return np.where((base < np.log(MAX_DEPTH_M) - 1e-9)[:, None], out, np.nan)
