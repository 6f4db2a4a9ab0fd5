"""An atlas end to end: the grid cut into chunks, the chunks evaluated on the chosen engine, the
table assembled in chunk order, the best placement and the best rotation per position.

Chunks are sized for the scheduler: a task should hold ~0.5-2 s of work (Dask's overhead is a few
ms per task, and a killed worker loses at most a few tasks), and there should be at least 16 tasks
so that two or more workers share the load. The cost model behind ``target_task_s`` was measured on
this machine (benchmarks/bench_atlas.py): ~0.25 ms of CPU per (position, rotation) with the
default 500 chatter frequencies, about proportional to ``n_freq``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from oma._arrays import readonly as _ro

from .engine import open_engine
from .evaluate import COLUMNS, CONSTRAINT_NAMES, evaluate_chunk
from .grid import Region, RegionError
from .problem import AtlasProblem
from .verify import sdm_chunk, sdm_cut

__all__ = ["AtlasResult", "run_atlas", "chunk_points", "SECONDS_PER_GROUP"]

#: CPU seconds per (position, rotation) at ``n_freq = 500`` (measured, see the module docstring).
SECONDS_PER_GROUP = 2.5e-4


def chunk_points(n_points: int, n_rotations: int, n_freq: int, *, target_task_s: float = 1.0,
                 min_tasks: int = 16) -> int:
    """Positions per task: about ``target_task_s`` of work, and at least ``min_tasks`` tasks."""
    per_point = n_rotations * SECONDS_PER_GROUP * max(n_freq, 50) / 500.0
    size = max(1, int(target_task_s / per_point))
    return max(1, min(size, math.ceil(n_points / min_tasks)))


@dataclass(frozen=True)
class AtlasResult:
    """The atlas table and its summary.

    Attributes
    ----------
    columns : dict of str to ndarray
        One row per (position, rotation), position-major: ``point``, ``x_m``, ``y_m``, ``z_m``
        (workpiece frame), then :data:`planner.atlas.evaluate.COLUMNS` (``active_constraint`` as
        a name).
    region : Region
    problem : dict
        :meth:`AtlasProblem.to_dict`.
    best_row_per_point : ndarray of int, shape (n_points,)
        Row of each position's best rotation (largest MRR, then the largest stability reserve at
        the chosen speed, then the largest limit over the speed range, then the first rotation;
        -1: no stable cut at any rotation).
    best : dict or None
        The best of these rows by the same rule (ties: the first position).
    engine : dict
        Scheduler, chunks, points per chunk, wall time.
    """

    columns: dict
    region: Region
    problem: dict
    best_row_per_point: np.ndarray
    best: dict | None
    engine: dict = field(default_factory=dict)

    @property
    def n_points(self) -> int:
        return self.region.n_points

    @property
    def n_rows(self) -> int:
        return int(self.columns["point"].size)

    def counts(self) -> dict:
        c = self.columns
        return {"rows": self.n_rows, "reachable": int(np.count_nonzero(c["reachable"])),
                "near_singularity": int(np.count_nonzero(c["near_singularity"])),
                "stable_cut": int(np.count_nonzero(np.isfinite(c["mrr_m3_s"]))),
                "positions_with_a_stable_cut": int(np.count_nonzero(self.best_row_per_point >= 0))}

    def per_point(self, name: str) -> np.ndarray:
        """Column ``name`` at each position's best rotation (NaN where there is none), (n_points,)."""
        rows = self.best_row_per_point
        values = np.asarray(self.columns[name], float)
        return np.where(rows >= 0, values[np.maximum(rows, 0)], np.nan)

    def to_dict(self) -> dict:
        return {"points": self.n_points, "rotations": int(self.region.rotations_deg.size),
                "region": self.region.to_dict(), "problem": self.problem, "counts": self.counts(), "best": self.best,
                "engine": self.engine}

    def plot(self, which: str = "mrr", **kwargs):
        """``which='mrr'``: :func:`planner.atlas.plots.plot_mrr_map`; ``'rotation'``:
        :func:`planner.atlas.plots.plot_best_rotation`."""
        from . import plots

        if which == "mrr":
            return plots.plot_mrr_map(self, **kwargs)
        if which == "rotation":
            return plots.plot_best_rotation(self, **kwargs)
        raise ValueError(f"which must be 'mrr' or 'rotation', found {which!r}")


def _keys(columns, rows=None):
    """Ranking keys of rows (larger is better, in order): MRR, stability reserve at the chosen
    speed, the smallest limit over the speed range. Rows without a stable cut rank last."""
    sel = slice(None) if rows is None else rows
    mrr = np.asarray(columns["mrr_m3_s"], float)[sel]
    ok = np.isfinite(mrr)
    keys = [np.where(ok, mrr, -np.inf)]
    for name in ("stability_reserve", "min_depth_limit_m"):
        v = np.asarray(columns[name], float)[sel]
        keys.append(np.where(ok, np.nan_to_num(v, nan=-np.inf, posinf=np.inf), -np.inf))
    return ok, keys


def best_rows(columns, n_points: int, n_rot: int) -> np.ndarray:
    """Each position's best row by :func:`_keys` (ties: the first rotation), -1: none."""
    ok, keys = _keys(columns)
    ok = ok.reshape(n_points, n_rot)
    keys = [k.reshape(n_points, n_rot) for k in keys]
    best = np.empty(n_points, dtype=np.int64)
    idx = np.arange(n_rot)
    for i in range(n_points):  # n_rot values per position: a lexsort each is clear and cheap
        j = np.lexsort((idx,) + tuple(-k[i] for k in reversed(keys)))[0]
        best[i] = i * n_rot + j if ok[i, j] else -1
    return best


def _row_dict(columns, i: int, *, sdm: bool = False) -> dict:
    out = {"stability": "sdm" if sdm else "zoa"}
    for name in ("point", "x_m", "y_m", "z_m", "rotation_deg", "branch", "q1_deg", "q2_deg", "q3_deg", "q4_deg",
                 "q5_deg", "q6_deg", "joint_limit_distance_deg", "singularity_measure", "lowest_mode_hz",
                 "dominant_mode_hz", "min_depth_limit_m", "spindle_rpm", "depth_limit_m", "axial_depth_m",
                 "feed_per_tooth_m", "mrr_m3_s", "mean_torque_N_m", "power_W", "stability_reserve",
                 "active_constraint", "sdm_depth_limit_m", "sdm_axial_depth_m", "sdm_mrr_m3_s"):
        v = columns[name][i]
        v = v.item() if hasattr(v, "item") else v
        out[name] = None if isinstance(v, float) and math.isnan(v) else v  # NaN: not computed
    return out


def _assemble(parts, local, region, n_rot):
    """The table from the chunks' columns (in chunk order) and each position's best row."""
    n = local.shape[0]
    columns = {"point": np.repeat(np.arange(n), n_rot)}
    for j, axis in enumerate(("x_m", "y_m", "z_m")):
        columns[axis] = np.repeat(local[:, j], n_rot)
    for name in COLUMNS:
        columns[name] = np.concatenate([p[name] for p in parts])
    if not np.any(columns["reachable"]):
        raise RegionError("--box-m", "a region the robot reaches with the setup's tool axis",
                          f"none of the {n} positions at any of the {n_rot} rotations "
                          f"({region.lower_m.tolist()} .. {region.upper_m.tolist()} m)")
    codes = columns["active_constraint"]
    columns["active_constraint"] = np.array([CONSTRAINT_NAMES[int(c)] for c in codes], dtype=object)
    for name in ("sdm_depth_limit_m", "sdm_axial_depth_m", "sdm_mrr_m3_s"):
        columns[name] = np.full(n * n_rot, np.nan)
    return columns, best_rows(columns, n, n_rot)


def _top_rows(columns, best_rows_, n_verify: int) -> np.ndarray:
    """The best rows of the ``n_verify`` best positions (by :func:`_keys`)."""
    cand = best_rows_[best_rows_ >= 0]
    _, keys = _keys(columns, cand)
    order = np.lexsort((cand,) + tuple(-k for k in reversed(keys)))
    return np.sort(cand[order[:max(0, n_verify)]])


def run_atlas(problem: AtlasProblem, region: Region, *, scheduler: str | None = None, n_workers: int | None = None,
              points_per_chunk: int | None = None, target_task_s: float = 1.0, progress: bool = True,
              connect_timeout_s: float = 5.0, on_chunk_done=None, method: str = "auto",
              n_verify: int = 16, sdm_below_immersion: float = 0.2) -> AtlasResult:
    """Evaluate the atlas of ``problem`` over ``region``.

    Parameters
    ----------
    problem : AtlasProblem
    region : Region
    scheduler : str, optional
        ``None`` (a local cluster), ``'serial'`` or ``tcp://HOST:PORT`` (:func:`run_chunks`).
    n_workers : int, optional
        Local cluster size.
    points_per_chunk : int, optional
        Positions per task (default :func:`chunk_points`).
    target_task_s : float
        Work per task the default chunking aims at, s.
    progress : bool
        Progress bar on standard error.
    connect_timeout_s : float
        See :func:`run_chunks`.
    on_chunk_done : callable, optional
        See :func:`run_chunks`.
    method : {'auto', 'zoa', 'sdm'}
        ``'sdm'``: the best rows of the ``n_verify`` best positions are checked by
        semi-discretization (:mod:`planner.atlas.verify`); ``'auto'``: so when ``ae / D`` is below
        ``sdm_below_immersion`` (as ``robomill plan --method auto``); ``'zoa'``: never.
    n_verify : int
        Positions whose best row is checked by SDM.
    sdm_below_immersion : float
        See ``method``.

    Returns
    -------
    AtlasResult

    Raises
    ------
    oma.errors.InputError
        No position of the region is reachable at any rotation; an unreachable scheduler.
    """
    t0 = time.perf_counter()
    local = region.positions_m()
    machine = region.to_machine(local)
    n, n_rot = local.shape[0], region.rotations_deg.size
    size = int(points_per_chunk) if points_per_chunk else chunk_points(n, n_rot, problem.n_freq,
                                                                        target_task_s=target_task_s)
    if size < 1:
        raise RegionError("--chunk-points", "a positive number of positions per task", repr(points_per_chunk))
    if method not in ("auto", "zoa", "sdm"):
        raise RegionError("--method", "one of 'auto', 'zoa', 'sdm'", repr(method))
    use_sdm = method == "sdm" or (method == "auto" and problem.immersion < sdm_below_immersion)
    chunks = [machine[i:i + size] for i in range(0, n, size)]
    with open_engine(scheduler, n_workers=n_workers, connect_timeout_s=connect_timeout_s) as engine:
        parts = engine.map(evaluate_chunk, problem, chunks, progress=progress, on_chunk_done=on_chunk_done)
        columns, best_rows_ = _assemble(parts, local, region, n_rot)
        verified = np.zeros(0, dtype=np.int64)
        if use_sdm and np.any(best_rows_ >= 0):
            verified = _top_rows(columns, best_rows_, int(n_verify))
            q = np.radians(np.column_stack([columns[f"q{j}_deg"][verified] for j in range(1, 7)]))
            rows = np.column_stack([q, columns["spindle_rpm"][verified]])
            res = engine.map(sdm_chunk, problem, [rows[i:i + 1] for i in range(rows.shape[0])], progress=progress,
                             desc="atlas: SDM")
            res = np.vstack(res)
            columns["sdm_depth_limit_m"][verified] = res[:, 0]
            ap, mrr = sdm_cut(problem, columns["spindle_rpm"][verified], res[:, 0])
            columns["sdm_axial_depth_m"][verified] = ap
            columns["sdm_mrr_m3_s"][verified] = mrr
    best = None
    if verified.size:
        keys = _keys({"mrr_m3_s": columns["sdm_mrr_m3_s"][verified],
                      "stability_reserve": problem.margin * columns["sdm_depth_limit_m"][verified]
                      / columns["sdm_axial_depth_m"][verified],
                      "min_depth_limit_m": columns["min_depth_limit_m"][verified]})[1]
        if np.isfinite(columns["sdm_mrr_m3_s"][verified]).any():
            i = int(verified[np.lexsort((verified,) + tuple(-k for k in reversed(keys)))[0]])
            best = _row_dict(columns, i, sdm=True)
    elif np.any(best_rows_ >= 0):
        cand = best_rows_[best_rows_ >= 0]
        _, keys = _keys(columns, cand)
        i = int(cand[np.lexsort((cand,) + tuple(-k for k in reversed(keys)))[0]])
        best = _row_dict(columns, i)
    if best is not None:
        best["position_m"] = [best["x_m"], best["y_m"], best["z_m"]]
        best["position_machine_m"] = region.to_machine(np.array(best["position_m"])[None])[0].tolist()
    engine = {"scheduler": "local" if scheduler is None else str(scheduler), "chunks": len(chunks),
              "points_per_chunk": size, "wall_s": time.perf_counter() - t0,
              "stability": "zoa, sdm at the best rows" if use_sdm else "zoa", "sdm_verified_rows": int(verified.size)}
    return AtlasResult(columns={k: (v if v.dtype == object else _ro(v, v.dtype)) for k, v in columns.items()},
                       region=region, problem=problem.to_dict(), best_row_per_point=_ro(best_rows_, np.int64),
                       best=best, engine=engine)
