"""Scale-out of Monte-Carlo chunks on Dask (``dask.distributed``): a ``LocalCluster`` of worker
processes on this machine, or any running cluster by its scheduler address. Dask is optional
(the ``[dask]`` extra) and imported only here, only when asked for.

Each chunk is one task (:func:`uavdyn.montecarlo.chunks.evaluate_chunk`); the spec is sent to
every worker once; results come back to the client, which writes each chunk file as it
arrives, so the workers need no shared file system. A remote worker needs uavdyn and a C
compiler (the compiled batch Function is built and cached per worker machine).
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from uavdyn.montecarlo.chunks import ChunkResult, evaluate_chunk
from uavdyn.montecarlo.spec import MonteCarloError, StudySpec

CONNECT_TIMEOUT_S = 30


def _distributed():
    try:
        import distributed
    except ImportError:
        raise MonteCarloError("running on several workers or a scheduler needs Dask: pip "
                              "install 'dask[distributed]' (or uavdyn's [dask] extra)") from None
    return distributed


@contextmanager
def dask_client(workers: int = 2, scheduler: str | None = None) -> Iterator[object]:
    """A ``distributed.Client``: connected to ``scheduler`` (an address such as
    ``tcp://host:8786``), else to a new ``LocalCluster`` of ``workers`` single-threaded worker
    processes, closed (with its cluster) on exit.

    Raises
    ------
    MonteCarloError
        Without Dask installed, or when the scheduler cannot be reached.
    """
    distributed = _distributed()
    if scheduler is not None:
        try:
            client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise MonteCarloError(f"cannot reach the Dask scheduler at {scheduler}: "
                                  f"{' '.join(str(exc).split()) or type(exc).__name__}") from None
        try:
            yield client
        finally:
            client.close()
        return
    if workers < 1:
        raise MonteCarloError(f"workers must be >= 1, got {workers}")
    cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                       processes=True, dashboard_address=None,
                                       silence_logs=logging.ERROR)
    try:
        client = distributed.Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def run_on_dask(client, spec: StudySpec, chunks: list[int], threads: int,
                on_result: Callable[[ChunkResult], None]) -> None:
    """Evaluate ``chunks`` as Dask tasks and hand each result to ``on_result`` as it finishes
    (in completion order). A failed task cancels the rest and re-raises its error."""
    if not chunks:
        return
    distributed = _distributed()
    spec_future = client.scatter(spec, broadcast=True)
    token = uuid.uuid4().hex[:8]
    futures = [client.submit(evaluate_chunk, spec_future, index, threads, pure=False,
                             key=f"uavdyn-montecarlo-{spec.key[:12]}-{token}-{index}")
               for index in chunks]
    try:
        for future in distributed.as_completed(futures):
            on_result(future.result())
    finally:
        for future in futures:
            future.cancel()
