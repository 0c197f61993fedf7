"""A controller-in-the-loop Monte Carlo at scale: the runs of
:func:`uavdyn.montecarlo.controlled.fly_controlled_runs` cut into chunks, each chunk one task
(in this process, or as Dask tasks on a ``LocalCluster`` or a running cluster), each chunk file
written atomically as it arrives, a re-run into the same folder resuming from the finished
chunks. The same seed gives the same dispersed airframes, initial states and gusts to every
controller, so an LQR and an MPC study compare run for run.

Output folder::

    .uavdyn-output.json   marker: a 'uavdyn montecarlo' output
    study.json            the study (key, controller, scenario, seed, chunks)
    chunks/ctrl_*.npz     one per chunk (key, run range, columns, table, content digest)
    runs.csv              one row per run (controlled.OUTCOMES, then each drawn quantity)
    drivers.json          which dispersion drives the worst runs, and the summary figures
    summary.md            the same in words

Each process builds its controller once per study (a worker too): the MPC as the exported C
controller compiled into a shared library where a C compiler is found, else the Python
real-time iteration with one warning.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from uavdyn import __version__
from uavdyn.airframes import Airframe, to_toml_dict
from uavdyn.linear import trim
from uavdyn.montecarlo.controlled import OUTCOMES, ControlledRuns, describe, fly_controlled_runs
from uavdyn.montecarlo.dispersions import Dispersions
from uavdyn.montecarlo.errors import MonteCarloError
from uavdyn.montecarlo.spec import ChunkedRuns
from uavdyn.montecarlo.study import (
    _locked,
    _remove_dead_temporaries,
    _write_marker,
    prepare_folder,
)
from uavdyn.mpc import MPCConfig, Scenario
from uavdyn.outputs import atomic_file, check_output_folder, write_text_atomic
from uavdyn.safefiles import UnreadableFile, read_regular

CONTROLLERS = ("lqr", "mpc")
BACKENDS = ("auto", "c", "python")
CHUNK_FORMAT = 1
HORIZON = 20
OUTPUT_FILES = ("runs.csv", "drivers.json", "summary.md")
NO_COMPILER = ("the C controller needs a C compiler (cc, gcc or clang; or $UAVDYN_CC); "
               "--mpc-backend python flies the Python controller")


@dataclass(frozen=True, eq=False)
class ControlledSpec(ChunkedRuns):
    """Everything that decides a controller study's runs (picklable: sent to Dask workers).

    Attributes
    ----------
    airframe_source : str
        Preset name or airframe file (the worker rebuilds the prediction models from it).
    weights : str or None
        Weight file of a hybrid prediction model (MPC only); None: the physics.
    plant : Airframe
        The airframe the dispersions apply to.
    dispersions : Dispersions
    controller : str
        ``lqr`` or ``mpc``.
    scenario : Scenario
        The reference each run tracks (its duration the run's).
    runs, seed, chunk_size : int
    altitude : float
        Start altitude (m).
    airspeed : float or None
        Nominal trim airspeed before dispersion (None: the airframe's).
    backend : str
        ``auto`` (the C MPC where a compiler is found), ``c`` or ``python``.
    """

    airframe_source: str
    weights: str | None
    plant: Airframe
    dispersions: Dispersions
    controller: str
    scenario: Scenario
    runs: int
    seed: int = 0
    chunk_size: int = 50
    altitude: float = 100.0
    airspeed: float | None = None
    backend: str = "auto"
    key: str = field(init=False)

    def __post_init__(self) -> None:
        if self.controller not in CONTROLLERS:
            raise MonteCarloError(f"controller must be one of {CONTROLLERS}, got "
                                  f"{self.controller!r}")
        if self.backend not in BACKENDS:
            raise MonteCarloError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        content = to_toml_dict(self.plant)
        content["params"] = {n: repr(float(v["value"])) for n, v in content["params"].items()}
        doc = {"format": CHUNK_FORMAT, "uavdyn": __version__, "plant": content,
               "prediction": _prediction_identity(self.airframe_source, self.weights),
               "dispersions": self.dispersions.to_dict(), "controller": self.controller,
               "scenario": asdict(self.scenario), "seed": self.seed,
               "chunk_size": self.chunk_size, "altitude": self.altitude,
               "airspeed": self.airspeed, "horizon": HORIZON}
        text = json.dumps(doc, sort_keys=True, default=str)
        object.__setattr__(self, "key", hashlib.sha256(text.encode()).hexdigest())

    def columns(self) -> tuple[str, ...]:
        """The per-run table's columns."""
        return OUTCOMES + tuple(self.dispersions.column_names())

    def describe(self) -> dict:
        """JSON-friendly description (``study.json``)."""
        return {"key": self.key, "controller": self.controller, "airframe": self.plant.name,
                "source": self.airframe_source, "weights": self.weights,
                "scenario": asdict(self.scenario), "runs": self.runs, "seed": self.seed,
                "chunk_size": self.chunk_size, "horizon": HORIZON}


def _prediction_identity(source: str, weights: str | None) -> list:
    """What decides the controller's prediction model beyond the plant: a preset's name (its
    shipped identified airframe or correction) or a file's content, and the weights' content
    (not their paths, so a moved file keeps its study)."""
    def content(path: str) -> str:
        try:
            return hashlib.sha256(read_regular(Path(path), 256 * 2**20, "a file")).hexdigest()
        except UnreadableFile:
            return str(path)

    preset = not Path(source).is_file()
    return [source if preset else content(source),
            weights if weights in (None, "shipped") else content(weights)]


# ------------------------------------------------------------------------------ controllers

_CONTROLLERS: dict[tuple[str, str], object] = {}


def build_controller(spec: ControlledSpec, backend: str | None = None) -> object:
    """The controller of a study, built once per process (cached by key and backend). The
    MPC: the real-time iteration, horizon :data:`HORIZON`, predicting with the physics (or
    the hybrid of ``spec.weights``); the LQR: the stated gain of the prediction airframe at
    its trim, on the MPC's grid and limits.

    Raises
    ------
    MonteCarloError
        If ``backend`` is ``c`` and no compiler is found or the C controller does not build.
    """
    backend = backend or spec.backend
    cache = (spec.key, backend)
    if cache not in _CONTROLLERS:
        _CONTROLLERS[cache] = _build(spec, backend)
    return _CONTROLLERS[cache]


def _build(spec: ControlledSpec, backend: str) -> object:
    from uavdyn.integrate.compiler import find_compiler
    from uavdyn.montecarlo.controllers import CMPCController, LQRController
    from uavdyn.montecarlo.feedback import lqr_gain
    from uavdyn.mpc.study import prediction_models

    which = "physics" if spec.weights is None else "hybrid"
    weights = None if spec.weights == "shipped" else spec.weights  # the preset's own
    setup = prediction_models(spec.airframe_source, weights, mode="rti", models=(which,))
    if which not in setup.models:
        raise MonteCarloError(f"no {which} prediction for {spec.airframe_source}: "
                              f"{setup.missing.get(which, 'no correction')}")
    model = setup.models[which]
    python = model.controller(MPCConfig(horizon=HORIZON, mode="rti"))
    if spec.controller == "lqr":
        af = model.airframe
        gain = lqr_gain(af, trim(af))
        return LQRController(gain, python.config, python.kind, python.bounds, python.rates)
    compiler = find_compiler() if backend in ("auto", "c") else None
    if compiler is None:
        if backend == "c":
            raise MonteCarloError(NO_COMPILER)
        return python
    try:
        return CMPCController(python, setup.plant_airframe, compiler)
    except RuntimeError as exc:
        raise MonteCarloError(str(exc)) from None


def _uses_c(spec: ControlledSpec) -> bool:
    from uavdyn.integrate.compiler import find_compiler

    return spec.controller == "mpc" and spec.backend != "python" and find_compiler() is not None


def _check_backend(spec: ControlledSpec) -> None:
    """Refuse ``backend="c"`` without a compiler; warn once (here, not in every worker) when
    ``auto`` falls back to the Python controller."""
    if spec.controller != "mpc" or spec.backend == "python" or _uses_c(spec):
        return
    if spec.backend == "c":
        raise MonteCarloError(NO_COMPILER)
    warnings.warn("no C compiler found: the MPC runs as the Python controller (slower, the "
                  "same outcomes)", RuntimeWarning, stacklevel=3)


def controller_description(spec: ControlledSpec) -> str:
    """What flies the runs, in words (without building it)."""
    if spec.controller == "lqr":
        return ("LQR (Bryson's rule, the gain of the prediction airframe at its trim) on the "
                "MPC's grid, bounds and rate limits")
    model = "physics" if spec.weights is None else f"hybrid ({Path(spec.weights).name})"
    where = "C controller" if _uses_c(spec) else "Python controller"
    return f"RTI MPC, horizon {HORIZON}, {model} prediction ({where})"


# ------------------------------------------------------------------------------- chunks


@dataclass(frozen=True)
class ControlledChunk:
    """One chunk's runs: ``table`` rows for runs ``run_start..run_stop-1``."""

    index: int
    run_start: int
    run_stop: int
    table: np.ndarray
    seconds: float


def evaluate_controlled_chunk(spec: ControlledSpec, index: int) -> ControlledChunk:
    """Fly the runs of chunk ``index`` (the process's controller, built on first use)."""
    controller = build_controller(spec)
    start, stop = spec.chunk_runs(index)
    t0 = time.perf_counter()
    result = fly_controlled_runs(controller, spec.plant, spec.dispersions, spec.scenario,
                                 stop - start, spec.seed, spec.altitude, spec.airspeed,
                                 first=start)
    return ControlledChunk(index, start, stop, result.table, time.perf_counter() - t0)


def chunk_path(folder: str | Path, index: int) -> Path:
    """``<folder>/chunks/ctrl_<index>.npz``."""
    return Path(folder) / "chunks" / f"ctrl_{index:06d}.npz"


def _digest(spec: ControlledSpec, chunk: ControlledChunk) -> str:
    h = hashlib.sha256(f"{CHUNK_FORMAT}|{spec.key}|{','.join(spec.columns())}|"
                       f"{chunk.run_start}|{chunk.run_stop}|".encode())
    h.update(np.ascontiguousarray(chunk.table, dtype="<f8").tobytes())
    return h.hexdigest()


def write_controlled_chunk(folder: str | Path, spec: ControlledSpec,
                           chunk: ControlledChunk) -> Path:
    """Write a chunk file atomically (temporary sibling, then renamed)."""
    path = chunk_path(folder, chunk.index)
    arrays = {"key": np.array(spec.key), "runs": np.array([chunk.run_start, chunk.run_stop]),
              "table": chunk.table.astype("<f8"), "digest": np.array(_digest(spec, chunk)),
              "seconds": np.array([chunk.seconds])}
    with atomic_file(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def read_controlled_chunk(folder: str | Path, spec: ControlledSpec, index: int
                          ) -> ControlledChunk | None:
    """Chunk ``index`` of ``spec`` from ``folder`` if its file exists and verifies (key, run
    range, shape, content digest), else None."""
    start, stop = spec.chunk_runs(index)
    n = len(spec.columns())
    try:
        raw = read_regular(chunk_path(folder, index), 2**20 + (stop - start) * n * 16,
                           "a chunk file", follow_symlinks=False)
        with np.load(io.BytesIO(raw), allow_pickle=False) as z:
            key, runs, table = str(z["key"]), z["runs"].tolist(), z["table"]
            digest, seconds = str(z["digest"]), float(z["seconds"][0])
    except (UnreadableFile, OSError, ValueError, KeyError, EOFError, IndexError):
        return None
    chunk = ControlledChunk(index, start, stop, table, seconds)
    if (key != spec.key or runs != [start, stop] or table.dtype != np.float64
            or table.shape != (stop - start, n) or digest != _digest(spec, chunk)):
        return None
    return chunk


# ------------------------------------------------------------------------------ the study


@dataclass(frozen=True)
class ControlledStudy:
    """A finished controller study: its runs, what flew them, the time it took."""

    runs: ControlledRuns
    controller: str
    wall_s: float
    runs_computed: int
    reused: list[int]


def run_controlled_study(spec: ControlledSpec, out: str | Path, workers: int = 1,
                         scheduler: str | None = None, force: bool = False,
                         progress: Callable[[int, int], None] | None = None
                         ) -> ControlledStudy:
    """Run (or resume) a controller-in-the-loop study into ``out``.

    Parameters
    ----------
    spec : ControlledSpec
    out : path
        Output folder (a previous output of the same study resumes from its chunks; another
        study's is refused unless ``force``).
    workers : int
        1: chunks run in this process; more: a Dask ``LocalCluster`` of that many processes.
    scheduler : str, optional
        A running Dask cluster's address instead (its workers need uavdyn and the airframe
        file at the same path; the client writes the chunk files).
    force : bool
        Discard another study's chunks in ``out``.
    progress : callable, optional
        ``progress(done, total)`` after each chunk.

    Returns
    -------
    ControlledStudy

    Raises
    ------
    MonteCarloError
        On a folder of another study, a controller that cannot be built, or Dask missing.
    """
    folder = Path(out)
    check_output_folder(folder, "montecarlo", force)
    _check_backend(spec)
    folder.mkdir(parents=True, exist_ok=True)
    with _locked(folder):
        _remove_dead_temporaries(folder)
        _prepare(folder, spec, force)
        chunks = {i: c for i in range(spec.n_chunks)
                  if (c := read_controlled_chunk(folder, spec, i)) is not None}
        reused = sorted(chunks)
        todo = [i for i in range(spec.n_chunks) if i not in chunks]
        t0 = time.perf_counter()

        def store(chunk: ControlledChunk) -> None:
            write_controlled_chunk(folder, spec, chunk)
            chunks[chunk.index] = chunk
            if progress is not None:
                progress(len(chunks), spec.n_chunks)

        if todo and workers == 1 and scheduler is None:
            for index in todo:
                store(evaluate_controlled_chunk(spec, index))
        elif todo:
            _on_dask(spec, todo, workers, scheduler, store)
        description = controller_description(spec)
        wall = time.perf_counter() - t0
        table = np.vstack([chunks[i].table for i in range(spec.n_chunks)])
        runs = ControlledRuns.from_table(spec.columns(), table, spec.scenario.name)
        _write_outputs(folder, spec, runs, description)
    return ControlledStudy(runs, description, wall, sum(spec.chunk_runs(i)[1]
                                                        - spec.chunk_runs(i)[0]
                                                        for i in todo), reused)


def _prepare(folder: Path, spec: ControlledSpec, force: bool) -> None:
    prepare_folder(folder, spec.key,
                   json.dumps(spec.describe(), indent=2, default=str) + "\n", force,
                   "airframe, controller, scenario, dispersions, seed or chunk size",
                   OUTPUT_FILES)


def _on_dask(spec: ControlledSpec, todo: list[int], workers: int, scheduler: str | None,
             store: Callable[[ControlledChunk], None]) -> None:
    """Each chunk one Dask task, stored by the client as it arrives; a failed task cancels
    the rest and re-raises."""
    from uavdyn.montecarlo.scaleout import _distributed, dask_client

    distributed = _distributed()
    with dask_client(workers, scheduler) as client:
        spec_future = client.scatter(spec, broadcast=True)
        futures = [client.submit(evaluate_controlled_chunk, spec_future, i, pure=False,
                                 key=f"uavdyn-controlled-{spec.key[:12]}-{i}") for i in todo]
        try:
            for future in distributed.as_completed(futures):
                store(future.result())
        finally:
            for future in futures:
                future.cancel()


def _write_outputs(folder: Path, spec: ControlledSpec, runs: ControlledRuns,
                   description: str) -> None:
    lines = describe(runs)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(runs.columns)
    writer.writerows([[f"{v:.17g}" for v in row] for row in runs.table])
    write_text_atomic(folder / "runs.csv", buf.getvalue())
    write_text_atomic(folder / "drivers.json", json.dumps({
        **spec.describe(), "controller_description": description,
        "summary": summary_figures(runs), "worst_runs": runs.worst_runs().tolist(),
        "drivers": [vars(d) for d in runs.drivers]}, indent=2, default=float) + "\n")
    write_text_atomic(folder / "summary.md", (
        f"# {spec.controller.upper()} in the loop: {spec.scenario.name}, {spec.runs} runs x "
        f"{spec.scenario.duration:g} s\n\n{description}; plant: dispersed {spec.plant.name}, "
        f"seed {spec.seed}.\n\n" + "\n".join(f"- {line}" for line in lines) + "\n"))
    _write_marker(folder, ["study.json", *OUTPUT_FILES,
                           *(f"chunks/{chunk_path(folder, i).name}"
                             for i in range(spec.n_chunks))])


def summary_figures(runs: ControlledRuns) -> dict:
    """The study's headline figures: counts of departures, untrimmed runs, failed solves and
    fallbacks, tracking error percentiles, mean limit activity."""
    err = runs.column("tracking_rmse")
    ok = err[np.isfinite(err)]

    def pct(q):
        return float(np.percentile(ok, q)) if len(ok) else float("nan")

    return {"runs": int(len(err)), "departed": int(np.nansum(runs.column("departed"))),
            "untrimmed": int(np.sum(runs.column("trim_ok") == 0)),
            "failed_solves": int(np.nansum(runs.column("failed_solves"))),
            "runs_with_failed_solves": int(np.sum(runs.column("failed_solves") > 0)),
            "fallbacks": int(np.nansum(runs.column("fallbacks"))),
            "tracking_rmse_p50": pct(50), "tracking_rmse_p95": pct(95),
            "tracking_rmse_max": pct(100),
            "max_pitch_error_deg_p95": float(np.nanpercentile(
                runs.column("max_pitch_error_deg"), 95)),
            "bound_share_mean": float(np.nanmean(runs.column("bound_share"))),
            "rate_share_mean": float(np.nanmean(runs.column("rate_share"))),
            "median_solve_ms": float(np.nanmedian(runs.column("median_solve_ms")))}


__all__ = ["BACKENDS", "CONTROLLERS", "ControlledChunk", "ControlledSpec", "ControlledStudy",
           "build_controller", "evaluate_controlled_chunk", "read_controlled_chunk",
           "run_controlled_study", "summary_figures", "write_controlled_chunk"]
