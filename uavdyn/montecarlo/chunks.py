"""One chunk of Monte-Carlo runs: draw each run from ``(seed, run)``, trim it, fly the chunk in
one call of the compiled batch Function, and store it as a compressed ``.npz`` written
atomically and verified (content digest) before a resumed study reuses it.

:func:`evaluate_chunk` is a pure function of the spec and the chunk index: the same numbers
whether it runs in this process, on another thread count, or as a Dask task on another worker.
:func:`evaluate_and_write` also writes the chunk file where the chunk was computed, so that the
compression and the write run in parallel on the workers instead of one after the other in the
client.

Chunk file (format 2; an ``.npz`` that ``numpy.load`` reads): ``format``, ``key``, ``index``,
``runs`` (start, stop), ``columns``, ``table`` (float64), ``history_planes`` and
``history_shape`` (the float32 history as its four little-endian byte planes, one after the
other: for 200 runs x 60 s deflated in 28 ms instead of 48 ms for the plain array, into 29 %
fewer bytes; see :func:`history_from_planes`), ``digest`` (SHA-256 of the format, key, run
range, columns and the arrays' bytes) and ``seconds`` (wall and CPU time of the computation).
A file of another format does not verify: its chunk is computed again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import os
import threading
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn.airframes import AirframeError
from uavdyn.integrate import StateLayout
from uavdyn.integrate.lanes import vector_math_unavailable
from uavdyn.linear import TrimError, point_params, trim, trim_many
from uavdyn.montecarlo.batch import (
    N_GUST,
    SIGNALS,
    STAT_NAMES,
    RunPieces,
    batch_function,
    pieces_run,
    run_pieces,
)
from uavdyn.montecarlo.dispersions import STATE_KEYS
from uavdyn.montecarlo.native import NativeBatch, native_batch
from uavdyn.montecarlo.spec import MonteCarloError, StudySpec
from uavdyn.outputs import atomic_file
from uavdyn.safefiles import UnreadableFile, read_regular

CHUNK_FORMAT = 2  # 1 stored the history as a plain float32 array
COMPRESS_LEVEL = 1
GUST_SPEED_FLOOR = 5.0  # m/s: frozen-turbulence convection speed of a hovering airframe
RESULT_COLUMNS = ("run", "trim_ok", "diverged", "t_diverged_s", "max_abs_pitch_deg",
                  "max_alpha_deg", "min_airspeed_mps", "max_load_factor", "min_load_factor",
                  "time_pitch_over_s", "time_alpha_over_s", "time_airspeed_under_s",
                  "time_load_over_s", "trim_airspeed_mps")
_STAT_INDEX = {name: i for i, name in enumerate(STAT_NAMES)}
# per-process cache of built chunk loops and batch Functions
_COMPILED: dict[tuple, NativeBatch | ca.Function | None] = {}
_COMPILED_MAX = 8  # oldest dropped beyond this (a notebook may run many studies)
# CasADi graph construction and the trim are not thread-safe: one chunk at a time per process
# (a Dask worker with several threads runs its chunks one after the other; a chunk's own
# CasADi threads are unaffected)
_CHUNK_LOCK = threading.Lock()


def table_columns(spec: StudySpec) -> tuple[str, ...]:
    """Columns of the per-run table: outcomes, then every drawn quantity."""
    return RESULT_COLUMNS + tuple(spec.dispersions.column_names())


@dataclass(frozen=True)
class ChunkResult:
    """The runs ``run_start..run_stop-1`` of a study.

    Attributes
    ----------
    index : int
        Chunk number.
    run_start, run_stop : int
        Run range.
    table : numpy.ndarray
        ``n x len(table_columns(spec))`` per-run rows (float64).
    history : numpy.ndarray
        ``n x len(SIGNALS) x len(spec.history_time)`` envelope samples (float32, SI units;
        NaN for a run that did not trim and from its divergence on).
    seconds : float
        Wall time spent computing it.
    cpu_seconds : float
        CPU time of the process computing it (all its threads).
    file : str or None
        Its chunk file, once written (by :func:`evaluate_and_write` where it was computed, or
        read back by :func:`read_chunk`); None while it is held in memory only.
    """

    index: int
    run_start: int
    run_stop: int
    table: np.ndarray
    history: np.ndarray
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    file: str | None = None


def compiled_batch(spec: StudySpec, n_runs: int, threads: int) -> NativeBatch | ca.Function:
    """The compiled chunk of ``n_runs`` runs on ``threads`` threads: the chunk loop of
    :func:`uavdyn.montecarlo.native.native_batch`, one library for every chunk of the study
    (up to ``spec.chunk_size`` runs, any thread count); else CasADi's map of the run (built once
    per process and study model; compiled libraries are cached on disk)."""
    capacity = max(n_runs, spec.chunk_size)
    native = _cached(("native", spec.model_key, capacity, spec.vector_math),
                     lambda: _native(spec, capacity))
    if native is not None:
        return native.on_threads(threads)
    return _cached(("mapped", spec.model_key, n_runs, threads),
                   lambda: batch_function(_run(spec), n_runs, threads))


def _cached(key: tuple, build):
    """``_COMPILED[key]``, built once (the oldest dropped beyond :data:`_COMPILED_MAX`)."""
    if key not in _COMPILED:
        while len(_COMPILED) >= _COMPILED_MAX:
            _COMPILED.pop(next(iter(_COMPILED)))
        _COMPILED[key] = build()
    return _COMPILED[key]


def _pieces(spec: StudySpec) -> RunPieces:
    return run_pieces(spec.step(), spec.airframe, spec.structure, spec.gusts,
                      f"mc_{spec.model_key[:10]}", spec.feedback)


def _run(spec: StudySpec, pieces: RunPieces | None = None) -> ca.Function:
    return pieces_run(pieces or _pieces(spec), spec.n_steps, spec.stride, spec.gusts,
                      f"mc_{spec.model_key[:10]}", spec.feedback is not None)


def _native(spec: StudySpec, capacity: int) -> NativeBatch | None:
    """The chunk loop of the study (its run's pieces built once for the loop and its check).

    Raises
    ------
    MonteCarloError
        For a vector-math study on a machine without it (a Dask worker unlike the client)."""
    unavailable = vector_math_unavailable() if spec.vector_math else None
    if unavailable:
        raise MonteCarloError(f"vector math is not available on this worker ({unavailable}); "
                              "run the study without --vector-math")
    pieces = _pieces(spec)
    return native_batch(pieces, batch_function(_run(spec, pieces), capacity, 1, False),
                        spec.n_steps, spec.stride, spec.gusts, spec.feedback is not None,
                        spec.vector_math)


def _initial(spec: StudySpec, layout: StateLayout, point, p: np.ndarray, offsets: dict
             ) -> np.ndarray:
    """The step's state at the start of a run: trim plus the initial-state offsets, with the
    actuator, delay and command-memory states at rest on the trim command."""
    body = np.asarray(point.x, float)[:4].copy()
    for name, dist in spec.dispersions.initial.items():
        i = STATE_KEYS.index(name)
        body[i] = dist.apply(body[i], offsets[f"initial.{name}"])
    return layout.states(body, point.u, p, spec.dt)[0]


def evaluate_chunk(spec: StudySpec, index: int, threads: int = 1) -> ChunkResult:
    """Fly the runs of chunk ``index`` (see the module docstring).

    Parameters
    ----------
    spec : StudySpec
        The study.
    index : int
        Chunk number.
    threads : int
        Threads of the batch call.

    Returns
    -------
    ChunkResult

    Raises
    ------
    MonteCarloError
        If a run draws a physically impossible airframe (an unbounded normal dispersion).
    """
    with _CHUNK_LOCK:
        return _evaluate_chunk(spec, index, threads)


def _evaluate_chunk(spec: StudySpec, index: int, threads: int) -> ChunkResult:
    start_time, start_cpu = time.perf_counter(), time.process_time()
    start, stop = spec.chunk_runs(index)
    n = stop - start
    if n < 1:
        raise MonteCarloError(f"chunk {index} holds no runs of a {spec.runs}-run study")
    nominal = spec.airframe
    nom_point = trim(nominal, spec.airspeed)
    nom_p = point_params(nominal, nom_point)
    layout = spec.discrete_model().layout  # built once per chunk, not once per run
    x0 = np.tile(_initial(spec, layout, nom_point, nom_p, _zero_offsets(spec))[:, None],
                 (1, n))
    u0 = np.tile(np.asarray(nom_point.u, float)[:, None], (1, n))
    x_ref = np.tile(np.asarray(nom_point.x, float)[:4, None], (1, n))  # closed loop: trims
    P = np.tile(nom_p[:, None], (1, n))
    G = np.zeros((N_GUST, spec.n_steps * n)) if spec.gusts else None
    columns = table_columns(spec)
    table = np.full((n, len(columns)), np.nan)
    airframes, speeds, draws = _draw_runs(spec, start, stop, table)
    trimmed = np.zeros(n, bool)
    for j, (run, point) in enumerate(zip(range(start, stop), trim_many(airframes, speeds))):
        if isinstance(point, TrimError):
            table[j, columns.index("trim_ok")] = 0.0
            continue
        trimmed[j] = True
        table[j, columns.index("trim_ok")] = 1.0
        p = point_params(airframes[j], point)
        x0[:, j] = _initial(spec, layout, point, p, draws[j].offsets)
        u0[:, j] = point.u
        x_ref[:, j] = point.x[:4]
        P[:, j] = p
        if spec.gusts and draws[j].gust_intensity > 0:
            G[:, j * spec.n_steps:(j + 1) * spec.n_steps] = _gusts(spec, run, speeds[j],
                                                                  draws[j], airframes[j])
    batch = compiled_batch(spec, n, threads)
    args = [x0, u0, P, spec.deviations.T] + ([G] if spec.gusts else []) + \
        [spec.dt, np.asarray(spec.limits, float)] + ([x_ref] if spec.feedback is not None
                                                      else [])
    with np.errstate(all="ignore"):
        stats, hist = (np.asarray(a) for a in batch(*args))
    n_hist = len(spec.history_time)
    history = hist.reshape(len(SIGNALS), n, n_hist).transpose(1, 0, 2).copy()
    t_div = stats[_STAT_INDEX["t_diverged"]]
    diverged = trimmed & (t_div >= 0)
    out = {"diverged": diverged.astype(float),
           "t_diverged_s": np.where(diverged, t_div, np.nan),
           "max_abs_pitch_deg": np.degrees(stats[_STAT_INDEX["max_abs_pitch"]]),
           "max_alpha_deg": np.degrees(stats[_STAT_INDEX["max_alpha"]]),
           "min_airspeed_mps": stats[_STAT_INDEX["min_airspeed"]],
           "max_load_factor": stats[_STAT_INDEX["max_load_factor"]],
           "min_load_factor": stats[_STAT_INDEX["min_load_factor"]],
           "time_pitch_over_s": stats[_STAT_INDEX["time_pitch_over"]],
           "time_alpha_over_s": stats[_STAT_INDEX["time_alpha_over"]],
           "time_airspeed_under_s": stats[_STAT_INDEX["time_airspeed_under"]],
           "time_load_over_s": stats[_STAT_INDEX["time_load_over"]]}
    for name, values in out.items():
        table[:, columns.index(name)] = np.where(trimmed, values, np.nan)
    table[~trimmed, columns.index("diverged")] = 0.0
    history[~trimmed] = np.nan
    times = spec.history_time
    for j in np.flatnonzero(diverged):
        history[j, :, times >= t_div[j] - 1e-9 * spec.dt] = np.nan
    return ChunkResult(index, start, stop, table, history.astype(np.float32),
                       time.perf_counter() - start_time, time.process_time() - start_cpu)


def _draw_runs(spec: StudySpec, start: int, stop: int, table: np.ndarray
               ) -> tuple[list, list[float], list]:
    """Each run's draw, dispersed airframe and trim airspeed, its identity and drawn values
    written into its row of ``table``."""
    columns = table_columns(spec)
    draw_columns = [columns.index(c) for c in spec.dispersions.column_names()]
    nominal = spec.airframe
    airframes, speeds, draws = [], [], []
    for j, run in enumerate(range(start, stop)):
        draw = spec.dispersions.sample(spec.seed, run)
        try:
            airframe = nominal.replace(**draw.params(spec.dispersions, nominal)) \
                if spec.dispersions.params else nominal
        except AirframeError as exc:
            raise MonteCarloError(f"run {run} drew an impossible airframe ({exc}); bound that "
                                  "dispersion (uniform or truncnormal)") from None
        values = dict(draw.offsets)  # parameters are shown by their dispersed value
        drawn_p = dict(zip(airframe.param_names, airframe.p))
        values.update({f"params.{name}": float(drawn_p[name]) for name in spec.dispersions.params})
        speed = spec.airspeed
        if "airspeed" in spec.dispersions.trim:
            speed = spec.dispersions.trim["airspeed"].apply(speed, draw.offsets["trim.airspeed"])
        table[j, columns.index("run")] = run
        table[j, columns.index("trim_airspeed_mps")] = speed
        table[j, draw_columns] = [values[c] for c in spec.dispersions.column_names()]
        airframes.append(airframe)
        speeds.append(speed)
        draws.append(draw)
    return airframes, speeds, draws


def _gusts(spec: StudySpec, run: int, speed: float, draw, airframe) -> np.ndarray:
    """A run's Dryden gusts (``3 x n_steps``), drawn from ``(seed, run)``."""
    from uavdyn.emulation import dryden_gusts, gust_span  # only for gusty studies

    rng = np.random.default_rng([spec.seed, run, 1])
    m = spec.gust_stride
    gusts = dryden_gusts(rng, -(-spec.n_steps // m), m * spec.dt,
                         max(speed, GUST_SPEED_FLOOR), draw.gust_intensity,
                         wingspan=gust_span(airframe), **spec.dispersions.gust_scales)
    return np.repeat(gusts, m, 0)[:spec.n_steps].T


def _zero_offsets(spec: StudySpec) -> dict:
    return {c: 0.0 for c in spec.dispersions.column_names()}


def evaluate_and_write(spec: StudySpec, index: int, threads: int = 1,
                       folder: str | Path | None = None) -> ChunkResult:
    """:func:`evaluate_chunk`, then, with ``folder``, :func:`write_chunk` right where the chunk
    was computed (a Dask worker that sees the output folder, or this process).

    Returns
    -------
    ChunkResult
        With ``file`` set to the chunk file when it was written.
    """
    result = evaluate_chunk(spec, index, threads)
    if folder is None:
        return result
    return dataclasses.replace(result, file=str(write_chunk(folder, spec, result)))


# ----------------------------------------------------------------------------- chunk files


def chunk_path(folder: str | Path, index: int) -> Path:
    """``<folder>/chunks/chunk_<index>.npz``."""
    return Path(folder) / "chunks" / f"chunk_{index:06d}.npz"


def _content_digest(key: str, columns: tuple[str, ...], run_start: int, run_stop: int,
                    table: np.ndarray, history: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(f"{CHUNK_FORMAT}|{key}|{','.join(columns)}|{run_start}|{run_stop}|".encode())
    h.update(np.ascontiguousarray(table, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(history, dtype="<f4").tobytes())
    return h.hexdigest()


def history_planes(history: np.ndarray) -> np.ndarray:
    """The four byte planes of a float32 history (``4 x history.size`` uint8, little-endian
    byte order): a float's sign and exponent bytes lie side by side, which deflate well."""
    raw = np.ascontiguousarray(history, dtype="<f4").reshape(-1).view(np.uint8)
    return np.ascontiguousarray(raw.reshape(-1, 4).T)


def history_from_planes(planes: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`history_planes`: the float32 array of ``shape``."""
    raw = np.ascontiguousarray(np.asarray(planes, np.uint8).T).reshape(-1)
    return raw.view("<f4").astype(np.float32, copy=False).reshape(shape)


def write_chunk(folder: str | Path, spec: StudySpec, result: ChunkResult) -> Path:
    """Write a chunk file atomically (temporary sibling, flushed to disk, then renamed)."""
    path = chunk_path(folder, result.index)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = table_columns(spec)
    digest = _content_digest(spec.key, columns, result.run_start, result.run_stop,
                             result.table, result.history)
    arrays = {"format": np.array([CHUNK_FORMAT]), "key": np.array(spec.key),
              "index": np.array([result.index]),
              "runs": np.array([result.run_start, result.run_stop]),
              "columns": np.array(columns), "table": result.table.astype("<f8"),
              "history_planes": history_planes(result.history),
              "history_shape": np.array(result.history.shape, np.int64),
              "digest": np.array(digest),
              "seconds": np.array([result.seconds, result.cpu_seconds])}
    with atomic_file(path) as tmp, open(tmp, "wb") as fh:
        # an .npz (numpy.load reads it) deflated at level 1: the byte planes compress better
        # than at numpy's default level of the plain array, several times faster
        with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED,
                             compresslevel=COMPRESS_LEVEL) as zf:
            for name, array in arrays.items():
                with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, array, allow_pickle=False)
        fh.flush()
        os.fsync(fh.fileno())
    return path


def read_chunk(folder: str | Path, spec: StudySpec, index: int) -> ChunkResult | None:
    """The chunk ``index`` of ``spec`` from ``folder`` if its file exists and verifies (study
    key, run range, columns, shapes and content digest), else None."""
    path = chunk_path(folder, index)
    start, stop = spec.chunk_runs(index)
    n, columns = stop - start, table_columns(spec)
    n_hist = len(spec.history_time)
    limit = 4096 + n * (len(columns) * 8 + len(SIGNALS) * n_hist * 4) * 2 + 2**20
    shape = (n, len(SIGNALS), n_hist)
    try:
        raw = read_regular(path, limit, "a chunk file", follow_symlinks=False)
        with np.load(io.BytesIO(raw), allow_pickle=False) as z:
            if z["format"].tolist() != [CHUNK_FORMAT]:
                return None
            content = {k: z[k] for k in ("key", "index", "runs", "columns", "table",
                                         "history_shape", "history_planes", "digest",
                                         "seconds")}
    except (UnreadableFile, OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    table, planes = content["table"], content["history_planes"]
    if (content["history_shape"].tolist() != list(shape) or planes.dtype != np.uint8
            or planes.shape != (4, n * len(SIGNALS) * n_hist)):
        return None
    history = history_from_planes(planes, shape)
    if (str(content["key"]) != spec.key
            or content["index"].tolist() != [index] or content["runs"].tolist() != [start, stop]
            or tuple(content["columns"].tolist()) != columns
            or table.dtype != np.float64 or table.shape != (n, len(columns))):
        return None
    if str(content["digest"]) != _content_digest(spec.key, columns, start, stop, table,
                                                 history):
        return None
    times = content["seconds"]
    seconds, cpu = (float(times[0]), float(times[1])) if times.shape == (2,) else (0.0, 0.0)
    return ChunkResult(index, start, stop, table, history, seconds, cpu, str(path))
