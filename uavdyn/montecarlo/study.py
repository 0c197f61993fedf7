"""Running a Monte-Carlo study: chunks of runs in this process (CasADi threads) or as Dask
tasks, each chunk file written atomically as it finishes (by the process that computed it,
when that process sees the folder), a re-run into the same folder resuming from the chunks that
verify, and the assembled :class:`MonteCarloResult`.

Only the statistics are serial: the client reads each reused chunk once, keeps every chunk it
receives in memory (no re-reading of files just written), computes the envelopes on as many
threads as the study was given cores, and a Dask cluster starts while the compiled batch
Function is loaded and closes while the statistics are computed.

Output folder (``out``)::

    .uavdyn-output.json    marker: a 'uavdyn montecarlo' output (see uavdyn.outputs)
    study.json             settings and the study key
    chunks/chunk_*.npz     one per chunk (compressed; key, run range and content digest)
    summary.csv, envelopes.csv, results.json, summary.md, figures/*.png

A folder holding another study (another key) is refused unless ``force``, which first removes
that study's chunks and outputs; a folder that is not a montecarlo output is refused unless
``force`` (uavdyn's rule for every command). One study at a time writes into a folder (a lock
file), and temporary files of a killed writer are removed.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from uavdyn.interrupts import CheckedBar
from uavdyn.montecarlo.batch import SIGNALS
from uavdyn.montecarlo.chunks import (
    ChunkResult,
    chunk_path,
    compiled_batch,
    evaluate_and_write,
    read_chunk,
    table_columns,
    write_chunk,
)
from uavdyn.montecarlo.report import OUTPUT_FILES, json_text, prepare_figures, write_outputs
from uavdyn.montecarlo.result import MonteCarloResult
from uavdyn.montecarlo.spec import MonteCarloError, StudySpec
from uavdyn.montecarlo.statistics import RunTable, envelopes, exceedances
from uavdyn.outputs import MARKER, check_output_folder, write_text_atomic

try:  # POSIX; elsewhere two studies in one folder are not prevented
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

COMMAND = "montecarlo"
LOCK_NAME = ".montecarlo.lock"
_TEMP = re.compile(r"^\..+\.(tmp|partial|old)-(\d+)-\d+-[0-9a-f]{8}$")


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    if fcntl is None:  # pragma: no cover - Windows
        yield
        return
    with open(folder / LOCK_NAME, "a") as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise MonteCarloError(f"{folder}: another uavdyn montecarlo is writing into this "
                                  "folder") from None
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _remove_dead_temporaries(folder: Path) -> None:
    """Temporary files left by a killed writer (their process is gone)."""
    for sub in (folder, folder / "chunks", folder / "figures"):
        if not sub.is_dir():
            continue
        for path in sub.iterdir():
            m = _TEMP.match(path.name)
            if not m or not path.is_file():
                continue
            try:
                os.kill(int(m.group(2)), 0)
            except ProcessLookupError:
                path.unlink(missing_ok=True)
            except (PermissionError, OverflowError):
                continue


def _write_marker(folder: Path, files: list[str]) -> None:
    write_text_atomic(folder / MARKER, json.dumps({"command": COMMAND, "files": files},
                                                  indent=1))


def _prepare(folder: Path, spec: StudySpec, force: bool) -> None:
    """Set up the output folder (checked by the caller; see the module docstring)."""
    prepare_folder(folder, spec.key, json_text(spec.describe()), force,
                   "airframe, model, dispersions, input, grid, seed or chunk size",
                   OUTPUT_FILES)


def prepare_folder(folder: Path, key: str, study_text: str, force: bool, differs: str,
                   output_files) -> None:
    """A study's output folder, ready to (re)fill: one holding another study (another
    ``key`` in its ``study.json``) is refused, naming what ``differs``, unless ``force``,
    which discards that study's chunks and ``output_files`` (nothing stale is reused); then
    the chunk folder, the marker and ``study.json`` (``study_text``)."""
    study_file = folder / "study.json"
    if study_file.is_file():
        try:
            old_key = json.loads(study_file.read_text()).get("key")
        except (OSError, ValueError, AttributeError):
            old_key = None
        if old_key != key:
            if not force:
                raise MonteCarloError(
                    f"{folder}: holds another Monte-Carlo study (different {differs}); "
                    "choose another folder, or give --force to discard its chunks")
            for path in (folder / "chunks").glob("*.npz"):  # any study's chunks
                path.unlink()
            for name in output_files:
                (folder / name).unlink(missing_ok=True)
    (folder / "chunks").mkdir(parents=True, exist_ok=True)
    if not (folder / MARKER).is_file() or force:
        _write_marker(folder, ["study.json"])
    write_text_atomic(study_file, study_text)


def run_study(spec: StudySpec, out: str | Path | None = None, workers: int = 1,
              threads: int = 1, scheduler: str | None = None, progress: bool = True,
              force: bool = False, on_chunk: Callable[[ChunkResult], None] | None = None,
              workers_write: bool | None = None) -> MonteCarloResult:
    """Run (or resume) a study.

    Parameters
    ----------
    spec : StudySpec
        From :func:`uavdyn.montecarlo.build_spec`.
    out : path, optional
        Output folder (chunk files, table, envelopes, figures, summary); None keeps
        everything in memory (no resume).
    workers : int
        1: chunks run in this process; more: a Dask ``LocalCluster`` of that many worker
        processes (needs ``dask[distributed]``).
    threads : int
        CasADi threads per chunk (the batch Function's ``thread`` map).
    scheduler : str, optional
        Address of a running Dask scheduler (instead of a LocalCluster).
    progress : bool
        Show a progress bar over runs.
    force : bool
        Write into a folder holding something else (see the module docstring).
    on_chunk : callable, optional
        Called with each :class:`ChunkResult` once it is stored.
    workers_write : bool, optional
        Whether Dask workers write their chunk files into ``out`` themselves (they must see it
        at the same path). Default: yes on a ``LocalCluster``, no on a ``scheduler`` (the
        client writes each chunk as it arrives).

    Returns
    -------
    MonteCarloResult

    Raises
    ------
    MonteCarloError
        Bad settings, a folder that may not be written, Dask missing or unreachable, an
        impossible draw, or a chunk file a worker wrote that this machine cannot see.
    """
    if not (isinstance(workers, int) and workers >= 1):
        raise MonteCarloError(f"workers must be an integer >= 1, got {workers}")
    if not (isinstance(threads, int) and threads >= 1):
        raise MonteCarloError(f"threads must be an integer >= 1, got {threads}")
    started = time.perf_counter()
    folder = Path(out) if out is not None else None
    write_on_workers = scheduler is None if workers_write is None else bool(workers_write)
    if folder is None:
        return _run(spec, None, workers, threads, scheduler, progress, on_chunk, started,
                    False)
    check_output_folder(folder, COMMAND, force)
    folder.mkdir(parents=True, exist_ok=True)
    with _locked(folder):
        _remove_dead_temporaries(folder)
        _prepare(folder, spec, force)
        return _run(spec, folder, workers, threads, scheduler, progress, on_chunk, started,
                    write_on_workers)


def _run(spec: StudySpec, folder: Path | None, workers: int, threads: int,
         scheduler: str | None, progress: bool, on_chunk, started: float,
         write_on_workers: bool) -> MonteCarloResult:
    columns = table_columns(spec)
    data = np.empty((spec.runs, len(columns)))
    history = np.empty((spec.runs, len(SIGNALS), len(spec.history_time)), np.float32)
    have = np.zeros(spec.n_chunks, bool)

    def place(chunk: ChunkResult) -> None:
        data[chunk.run_start:chunk.run_stop] = chunk.table
        history[chunk.run_start:chunk.run_stop] = chunk.history
        have[chunk.index] = True

    reused = []
    if folder is not None:  # each verified chunk is read once, straight into the result
        for index in range(spec.n_chunks):
            found = read_chunk(folder, spec, index)
            if found is not None:
                place(found)
                reused.append(index)
    todo = [c for c in range(spec.n_chunks) if not have[c]]
    on_dask = bool(todo) and (workers > 1 or scheduler is not None)
    done_runs = sum(np.subtract(*reversed(spec.chunk_runs(c))) for c in reused)
    bar = CheckedBar(total=spec.runs, initial=int(done_runs), unit="run",
                     disable=not progress, desc=f"montecarlo {spec.airframe.name}",
                     dynamic_ncols=True)
    # with Dask, once fewer chunks are left than workers one of them is idle: matplotlib is
    # imported for the figures meanwhile
    preload = threading.Thread(target=prepare_figures, name="uavdyn-matplotlib", daemon=True)
    stored = []

    def store(result: ChunkResult) -> None:
        if folder is not None and result.file is None:
            write_chunk(folder, spec, result)
        elif folder is not None and not Path(result.file).is_file():
            raise MonteCarloError(
                f"{result.file}: a Dask worker wrote this chunk file but this machine does not "
                "see it; the workers do not share the output folder (let the client write the "
                "chunks: leave out --workers-write)")
        place(result)
        stored.append(result.index)
        bar.update(result.run_stop - result.run_start)
        if on_dask and folder is not None and len(todo) - len(stored) < workers \
                and preload.ident is None:
            preload.start()
        if on_chunk is not None:
            on_chunk(result)

    session = None
    try:
        if on_dask:
            from uavdyn.montecarlo.scaleout import DaskSession, run_on_dask

            session = DaskSession(workers, scheduler)  # starts while this process warms up
        if todo:
            _warm(spec, todo, threads)
        if session is not None:
            run_on_dask(session.client, spec, todo, threads, store,
                        folder if write_on_workers else None)
            session.close(wait=False)  # while the statistics are computed
        else:
            for index in todo:
                store(evaluate_and_write(spec, index, threads, folder))
        if not have.all():  # pragma: no cover - every chunk was read or stored above
            raise MonteCarloError(f"chunks {np.flatnonzero(~have).tolist()} are missing")
        bar.close()
        if preload.ident is not None:
            preload.join()
        # the statistics use the cores the study was given on this machine
        cores = max(threads, workers if scheduler is None else 1)
        result = _assemble(spec, RunTable(columns, data), history, cores, todo, reused,
                           folder, workers, threads, scheduler, started)
    finally:
        bar.close()
        if session is not None:
            session.close(wait=True)
    result.wall_s = time.perf_counter() - started
    return result


def _assemble(spec: StudySpec, table: RunTable, history: np.ndarray, cores: int,
              todo: list[int], reused: list[int], folder: Path | None, workers: int,
              threads: int, scheduler: str | None, started: float) -> MonteCarloResult:
    """The result of a study whose chunks are all in ``table`` and ``history``, with its
    output files written into ``folder``."""
    keep = (table["trim_ok"] == 1) & (table["diverged"] == 0)
    result = MonteCarloResult(
        spec=spec, table=table, history=history,
        envelopes=envelopes(history, spec.history_time, keep, threads=cores),
        exceedance=exceedances(table, spec.limits), wall_s=0.0, computed=tuple(todo),
        reused=tuple(reused), folder=folder, workers=workers, threads=threads,
        scheduler=scheduler)
    result.wall_s = time.perf_counter() - started
    if folder is not None:
        result.files = write_outputs(result, folder)
        _write_marker(folder, ["study.json", *OUTPUT_FILES,
                               *(str(chunk_path(".", c).relative_to(".")) for c in
                                 range(spec.n_chunks))])
    return result


def _warm(spec: StudySpec, todo: list[int], threads: int) -> None:
    """Build (compile, or load from the disk cache) the batch Functions the chunks need, once
    here, so that worker processes only load the cached library."""
    for n in sorted({np.subtract(*reversed(spec.chunk_runs(c))) for c in todo}):
        compiled_batch(spec, int(n), threads)
