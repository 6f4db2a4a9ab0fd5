"""How many processes a computation may use, an ordered map over forked worker processes, and the
progress bar of long runs.

Shared by the workspace atlas (its local Dask cluster's size) and ``learn``'s limit tables (the
tables of ``learn``, ``plan --model POSTERIOR`` and ``lobes --model POSTERIOR``, seconds to minutes).
"""

from __future__ import annotations

import os
import sys

__all__ = ["available_cores", "default_workers", "process_map", "progress_bar", "WORKERS_ENV", "PROGRESS_DELAY_S"]

#: Environment variable that sets the process count of :func:`default_workers`.
WORKERS_ENV = "ROBOMILL_WORKERS"
#: A progress bar appears only once its run has lasted this long, s: quick runs show none.
PROGRESS_DELAY_S = 2.0


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


def progress_bar(total: float, desc: str | None, *, unit: str = "job", **options):
    """A tqdm progress bar on standard error, shown only when standard error is a terminal
    (``disable=None``: never in tests, pipes or logs) and once the run has lasted
    ``PROGRESS_DELAY_S``; none without ``desc``. Removed when done (``leave=False``: a command's
    stages follow one another). ``options`` go to tqdm."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=None if desc else True,
                delay=PROGRESS_DELAY_S, leave=False, dynamic_ncols=True, **options)


def process_map(fn, jobs: list, *, workers: int, desc: str | None = None) -> list:
    """``[fn(j) for j in jobs]``, over ``workers`` forked processes (each with one BLAS thread)
    where the platform forks (Linux), else here; results in the order of ``jobs``.

    ``desc``: the label of a progress bar counting the jobs done (:func:`progress_bar`; None, or a
    single job: none).
    """
    desc = desc if len(jobs) >= 2 else None
    workers = min(int(workers), len(jobs))
    if workers <= 1 or sys.platform != "linux":
        with progress_bar(len(jobs), desc) as bar:
            out = []
            for j in jobs:
                out.append(fn(j))
                bar.update(1)
            return out
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                             initializer=_one_blas_thread) as pool:
        futures = [pool.submit(fn, j) for j in jobs]
        # the bar (and its monitor thread) only once every worker has been forked
        with progress_bar(len(jobs), desc) as bar:
            for _ in as_completed(futures):
                bar.update(1)
        return [f.result() for f in futures]


def _one_blas_thread():
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
