"""Scale-out of Monte-Carlo chunks on Dask (``dask.distributed``): a ``LocalCluster`` of worker
processes on this machine, or any running cluster by its scheduler address. Dask is optional
(the ``[dask]`` extra) and imported only here, only when asked for.

Each chunk is one task (:func:`uavdyn.montecarlo.chunks.evaluate_and_write`); the spec is sent
to every worker once. Workers that see the output folder (those of a ``LocalCluster`` always;
those of a remote cluster when the caller says so, e.g. on a shared file system) write their
chunk files themselves, so compression and writes run in parallel; otherwise the client writes
each chunk file as its result arrives and the workers need no shared file system. Either way
every chunk's table and history come back to the client, which needs them for the statistics.
A remote worker needs uavdyn and a C compiler (the compiled batch Function is built and cached
per worker machine).

A :class:`DaskSession` connects in a background thread, so that a ``LocalCluster`` starts its
worker processes while the client loads the compiled batch Function, and can close in the
background while the client computes the statistics. A ``LocalCluster``'s workers run without
Dask's statistical profiler (a thread sampling the task's stack every 10 ms) and without the
fixed glibc trim threshold Dask gives worker processes by default (which turns every large
temporary array into fresh pages): both cost CPU time inside each chunk.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

from uavdyn.montecarlo.chunks import ChunkResult, evaluate_and_write
from uavdyn.montecarlo.spec import MonteCarloError, StudySpec

CONNECT_TIMEOUT_S = 30
# Dask configuration a LocalCluster's workers start with
LOCAL_WORKER_CONFIG = {"distributed.worker.profile.enabled": False}
_TRIM_VARIABLE = "MALLOC_TRIM_THRESHOLD_"
_NO_DASK = ("running on several workers or a scheduler needs Dask: pip install "
            "'dask[distributed]' (or uavdyn's [dask] extra)")


def _distributed():
    try:
        import distributed
    except ImportError:
        raise MonteCarloError(_NO_DASK) from None
    return distributed


def _check_distributed() -> None:
    """Refuse at once when Dask is missing (without importing it)."""
    try:
        found = importlib.util.find_spec("distributed") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise MonteCarloError(_NO_DASK)


def _connect(workers: int, scheduler: str | None) -> tuple[object, object]:
    """``(client, cluster)``; ``cluster`` is None for a running cluster at ``scheduler``."""
    distributed = _distributed()
    if scheduler is not None:
        try:
            return distributed.Client(scheduler, timeout=CONNECT_TIMEOUT_S), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise MonteCarloError(f"cannot reach the Dask scheduler at {scheduler}: "
                                  f"{' '.join(str(exc).split()) or type(exc).__name__}") from None
    import dask

    environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ",
                                                {}).items() if k != _TRIM_VARIABLE}
    # each nanny takes its workers' configuration and environment when it is created
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ,
                          **LOCAL_WORKER_CONFIG}):
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                           processes=True, dashboard_address=None,
                                           silence_logs=logging.ERROR)
    try:
        return distributed.Client(cluster), cluster
    except BaseException:
        cluster.close()
        raise


class DaskSession:
    """A Dask client connecting in a background thread: to a new ``LocalCluster`` of
    ``workers`` single-threaded worker processes, or to the running cluster at ``scheduler``
    (an address such as ``tcp://host:8786``).

    Use :attr:`client` (it waits for the connection), then :meth:`close` (``wait=False``
    closes in the background; :meth:`join` waits for it). As a context manager it closes and
    waits on exit.

    Raises
    ------
    MonteCarloError
        Without Dask installed (at once, before Dask is imported in the background), or when
        the scheduler cannot be reached (from :attr:`client`).
    """

    def __init__(self, workers: int = 2, scheduler: str | None = None) -> None:
        _check_distributed()
        if scheduler is None and not (isinstance(workers, int) and workers >= 1):
            raise MonteCarloError(f"workers must be >= 1, got {workers}")
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="uavdyn-dask")
        self._connected = self._pool.submit(_connect, workers, scheduler)
        self._closing = None

    @property
    def client(self):
        """The connected ``distributed.Client`` (waits until it is)."""
        return self._connected.result()[0]

    def close(self, wait: bool = True) -> None:
        """Close the client and its ``LocalCluster``; with ``wait=False`` in the background."""
        if self._closing is None:
            self._closing = self._pool.submit(self._close)
        if wait:
            self.join()

    def join(self) -> None:
        """Wait until the connection attempt and any closing have finished."""
        self._pool.shutdown(wait=True)

    def _close(self) -> None:
        try:
            client, cluster = self._connected.result()
        except BaseException:  # nothing was connected
            return
        try:
            client.close()
        finally:
            if cluster is not None:
                cluster.close()

    def __enter__(self) -> DaskSession:
        return self

    def __exit__(self, *exc) -> None:
        self.close(wait=True)


@contextmanager
def dask_client(workers: int = 2, scheduler: str | None = None) -> Iterator[object]:
    """A ``distributed.Client`` of a :class:`DaskSession`, closed (with its cluster) on exit.

    Raises
    ------
    MonteCarloError
        Without Dask installed, or when the scheduler cannot be reached.
    """
    with DaskSession(workers, scheduler) as session:
        yield session.client


def run_on_dask(client, spec: StudySpec, chunks: list[int], threads: int,
                on_result: Callable[[ChunkResult], None],
                folder: str | Path | None = None) -> None:
    """Evaluate ``chunks`` as Dask tasks and hand each result to ``on_result`` as it finishes
    (in completion order). With ``folder`` (which the workers must see at that path) each
    worker also writes its chunk files there. A failed task cancels the rest and re-raises
    its error."""
    if not chunks:
        return
    distributed = _distributed()
    where = None if folder is None else os.path.abspath(folder)
    spec_future = client.scatter(spec, broadcast=True)
    token = uuid.uuid4().hex[:8]
    pending = {}  # futures not yet returned: a worker keeps a result only until then
    for index in chunks:
        future = client.submit(evaluate_and_write, spec_future, index, threads, where,
                               pure=False,
                               key=f"uavdyn-montecarlo-{spec.key[:12]}-{token}-{index}")
        pending[future.key] = future
    try:
        for future in distributed.as_completed(list(pending.values())):
            result = future.result()
            del pending[future.key]
            on_result(result)
    finally:
        for future in pending.values():
            future.cancel()
