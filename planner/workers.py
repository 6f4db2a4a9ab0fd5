"""How many processes a computation may use, and an ordered map over forked worker processes.

Shared by the workspace atlas (its local Dask cluster's size) and ``learn``'s limit tables.
"""

from __future__ import annotations

import os
import sys

__all__ = ["available_cores", "default_workers", "process_map", "WORKERS_ENV"]

#: Environment variable that sets the process count of :func:`default_workers`.
WORKERS_ENV = "ROBOMILL_WORKERS"


def available_cores() -> int:
    """The cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def default_workers() -> int:
    """``ROBOMILL_WORKERS`` if set, else :func:`available_cores`."""
    env = os.environ.get(WORKERS_ENV, "").strip()
    return max(1, int(env)) if env else available_cores()


def process_map(fn, jobs: list, *, workers: int) -> list:
    """``[fn(j) for j in jobs]``, over ``workers`` forked processes (each with one BLAS thread)
    where the platform forks (Linux), else here; results in the order of ``jobs``."""
    workers = min(int(workers), len(jobs))
    if workers <= 1 or sys.platform != "linux":
        return [fn(j) for j in jobs]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                             initializer=_one_blas_thread) as pool:
        return list(pool.map(fn, jobs))


def _one_blas_thread():
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
