"""Run a pure chunk function over many chunks: serially, on a local Dask cluster, or on an
existing one (``robomill atlas --scheduler tcp://HOST:PORT``).

The computation is a plain function ``fn(payload, chunk) -> result`` of plain, picklable inputs
(STYLE.md, Dask): the same function runs in a loop here (``scheduler='serial'``, the reference of
the tests) and as Dask tasks. The cluster is chosen at the edge:

* ``scheduler=None``: a :class:`distributed.LocalCluster` of processes on this machine, one worker
  per core (``threads_per_worker=1``; BLAS/OpenMP threads limited to one per worker through the
  workers' environment and :func:`threadpoolctl.threadpool_limits`, so that ``n`` workers use ``n``
  cores, not ``n`` x cores);
* ``scheduler='tcp://HOST:PORT'``: an existing scheduler. An address that does not answer within
  ``connect_timeout_s`` raises :class:`SchedulerError` (an :class:`~oma.errors.InputError`: exit 2);
* ``scheduler='serial'``: no Dask at all.

The payload (robot, setup, options) is scattered once to every worker; each task carries only its
chunk. Tasks are submitted with ``client.map(..., retries=...)`` and collected with
``as_completed``: a worker that dies takes its running and queued tasks with it, the scheduler
reassigns them to the surviving workers (``distributed.scheduler.allowed-failures`` bounds how often
a task may be in flight on a dying worker), and ``retries`` re-runs a task that raised. Results are
put back in chunk order, so the assembled table does not depend on which worker ran what, or when.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from oma.errors import InputError

from ..workers import available_cores

__all__ = ["SchedulerError", "Engine", "open_engine", "run_chunks", "default_workers", "WORKER_ENV"]

log = logging.getLogger(__name__)

#: Environment of local worker processes: one BLAS/OpenMP thread each (the cores are the workers).
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "NUMBA_NUM_THREADS": "1"}


class SchedulerError(InputError):
    """A ``--scheduler`` address that cannot be used (exit 2)."""

    def __init__(self, address: str, found: str):
        super().__init__(None, "--scheduler", "the address of a running Dask scheduler (tcp://HOST:PORT)", found)
        self.address = address

    def __str__(self) -> str:
        return f"{self.field}: expected {self.expected}, found {self.found}"


def default_workers() -> int:
    """Worker processes of the local cluster: the cores this process may use."""
    return available_cores()


def _call(fn, payload, chunk):
    """One task: ``fn(payload, chunk)`` with BLAS threads limited to one (a worker is one core)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return fn(payload, chunk)


def _connect(address: str, timeout_s: float):
    """A :class:`distributed.Client` on an existing scheduler, or :class:`SchedulerError`.

    A plain TCP connection is tried first (refused or silent within ``timeout_s``: the error at
    once, without a client left to tear down), then the client's handshake (within the same time).
    """
    import socket
    from urllib.parse import urlsplit

    from distributed import Client

    if not address.startswith("tcp://"):
        raise SchedulerError(address, f"{address!r} (write tcp://HOST:PORT)")
    try:
        parts = urlsplit(address)
        host, port = parts.hostname, parts.port
    except ValueError:
        host = port = None
    if not host or not port:
        raise SchedulerError(address, f"{address!r} (write tcp://HOST:PORT)")
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except OSError as exc:
        raise SchedulerError(address, f"{address} (no connection within {timeout_s:g} s: "
                                      f"{exc.strerror or type(exc).__name__})") from None
    try:
        return Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except Exception as exc:  # noqa: BLE001 - whatever answered there is not a usable scheduler
        raise SchedulerError(address, f"{address} (not a Dask scheduler that answered within {timeout_s:g} s: "
                                      f"{type(exc).__name__})") from None


class Engine:
    """An open engine: ``serial``, or a Dask client (on a local cluster it owns, or on a scheduler).

    Use :func:`open_engine`; :meth:`map` runs one batch of chunks (several batches share the
    cluster, e.g. the atlas and then its SDM verification).
    """

    def __init__(self, client=None, name: str = "serial"):
        self.client = client
        self.name = name

    def map(self, fn: Callable[[Any, Any], Any], payload: Any, chunks: Sequence[Any], *, retries: int = 3,
            progress: bool = True, desc: str = "atlas",
            on_chunk_done: Callable[[int, int], None] | None = None) -> list:
        """``[fn(payload, c) for c in chunks]`` (see :func:`run_chunks`)."""
        from tqdm import tqdm

        total = len(chunks)
        results: list = [None] * total
        bar = tqdm(total=total, desc=desc, unit="chunk", file=sys.stderr, disable=not progress, smoothing=0.1)
        try:
            if self.client is None:
                for i, chunk in enumerate(chunks):
                    results[i] = _call(fn, payload, chunk)
                    bar.update(1)
                    if on_chunk_done is not None:
                        on_chunk_done(i + 1, total)
                return results
            from distributed import as_completed

            client = self.client
            shared = client.scatter(payload, broadcast=True)
            futures = client.map(_call, [fn] * total, [shared] * total, list(chunks), retries=int(retries),
                                 pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            done = 0
            with client.as_current():  # as_completed finds its event loop through the current client
                completed = as_completed(futures)
            for future in completed:
                results[index[future.key]] = future.result()
                future.release()
                done += 1
                bar.update(1)
                if on_chunk_done is not None:
                    on_chunk_done(done, total)
            return results
        finally:
            bar.close()


@contextmanager
def open_engine(scheduler: str | None = None, *, n_workers: int | None = None,
                connect_timeout_s: float = 5.0) -> Iterator[Engine]:
    """An :class:`Engine` for the block: ``'serial'``, a local cluster (``None``, closed at the end)
    or a client on the scheduler at ``tcp://HOST:PORT`` (:class:`SchedulerError` if it does not
    answer within ``connect_timeout_s``)."""
    if scheduler == "serial":
        yield Engine()
        return
    cluster = None
    if scheduler is None:
        cluster = _local_cluster(n_workers)
        client = cluster.get_client()
    else:
        client = _connect(str(scheduler), float(connect_timeout_s))
    try:
        yield Engine(client, "local" if cluster is not None else str(scheduler))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_chunks(fn: Callable[[Any, Any], Any], payload: Any, chunks: Sequence[Any], *,
               scheduler: str | None = None, n_workers: int | None = None, retries: int = 3,
               progress: bool = True, desc: str = "atlas", connect_timeout_s: float = 5.0,
               on_chunk_done: Callable[[int, int], None] | None = None) -> list:
    """``[fn(payload, c) for c in chunks]``, computed serially or on a Dask cluster.

    Parameters
    ----------
    fn : callable
        A pure function of picklable inputs, importable by the workers (a module-level function).
    payload : object
        What every task shares (scattered once to each worker).
    chunks : sequence
        One task each.
    scheduler : str, optional
        ``None``: a local cluster of ``n_workers`` processes; ``'serial'``: no Dask; otherwise the
        address of a running scheduler (``tcp://HOST:PORT``).
    n_workers : int, optional
        Local cluster size (default :func:`default_workers`).
    retries : int
        Times a task that raised is run again.
    progress : bool
        A tqdm progress bar on standard error.
    desc : str
        The bar's label.
    connect_timeout_s : float
        How long an existing scheduler has to answer, s.
    on_chunk_done : callable, optional
        ``on_chunk_done(done, total)`` after each completed chunk (in completion order).

    Returns
    -------
    list
        The results in the order of ``chunks``.

    Raises
    ------
    SchedulerError
        ``scheduler`` does not answer.
    """
    with open_engine(scheduler, n_workers=n_workers, connect_timeout_s=connect_timeout_s) as engine:
        return engine.map(fn, payload, chunks, retries=retries, progress=progress, desc=desc,
                          on_chunk_done=on_chunk_done)


def _local_cluster(n_workers: int | None):
    """A LocalCluster of single-threaded worker processes bound to 127.0.0.1, no dashboard."""
    import dask
    from distributed import LocalCluster

    n = default_workers() if n_workers is None else int(n_workers)
    if n < 1:
        raise ValueError(f"n_workers must be at least 1, found {n_workers!r}")
    with dask.config.set({"distributed.worker.daemon": True, "logging.distributed": "error"}):
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None, env=dict(WORKER_ENV), silence_logs=logging.ERROR)
