"""What a Monte-Carlo study is: airframe, step (physics or hybrid), dispersions, command input,
grid and seed gathered in one picklable :class:`StudySpec` with a content key. The command
deviations are :mod:`uavdyn.montecarlo.commands`', the closed loop's gain
:mod:`uavdyn.montecarlo.feedback`'s.

The key hashes everything that decides a run's numbers (but not the number of runs, so a study
can be extended); chunk files carry it, and a resumed study reuses only chunks made with it.

"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import casadi as ca
import numpy as np

from uavdyn import __version__
from uavdyn.airframes import Airframe, to_toml_dict
from uavdyn.integrate import DiscreteModel, physics_step
from uavdyn.integrate.inputs import PROFILES
from uavdyn.integrate.lanes import vector_math_unavailable
from uavdyn.learned import CorrectionNet, hybrid_step, load_weights, shipped_weights
from uavdyn.learned.hybrid import correction_structure
from uavdyn.linear import TrimError, stall_speed, trim
from uavdyn.model import ModelStructure, structure_of
from uavdyn.montecarlo.batch import gust_step
from uavdyn.montecarlo.commands import command_deviations, emulator_missions
from uavdyn.montecarlo.dispersions import LIMIT_KEYS, Dispersions
from uavdyn.montecarlo.errors import MonteCarloError
from uavdyn.montecarlo.feedback import lqr_gain
from uavdyn.safefiles import UnreadableFile, read_regular

SPEC_FORMAT = 3  # 2: the whole airframe and the step Function; 3: departures end a run
DEFAULT_HISTORY_DT = 0.1      # s between two envelope samples
MAX_STEPS = 10_000_000        # per run
DEFAULT_PITCH_LIMIT_DEG = 30.0
DEFAULT_LOAD_LIMIT = {"fixed_wing": 2.5, "multirotor": 2.0}


class ChunkedRuns:
    """Runs ``0..runs`` cut in chunks of ``chunk_size`` (a study's unit of work and resume);
    mixed into a spec with those two fields."""

    runs: int
    chunk_size: int

    @property
    def n_chunks(self) -> int:
        """Chunks of :attr:`chunk_size` runs (the last one may be shorter)."""
        return -(-self.runs // self.chunk_size)

    def chunk_runs(self, index: int) -> tuple[int, int]:
        """``(start, stop)`` run numbers of chunk ``index``."""
        start = index * self.chunk_size
        return start, min(start + self.chunk_size, self.runs)


@dataclass(frozen=True, eq=False)
class StudySpec(ChunkedRuns):
    """Everything a chunk of runs needs (picklable: it is sent to Dask workers).

    Attributes
    ----------
    airframe : Airframe
        Nominal airframe.
    dispersions : Dispersions
        Parsed dispersion file.
    net : CorrectionNet or None
        The correction of a hybrid study (None: physics).
    model : str
        ``physics`` or a description of the hybrid weights.
    runs : int
        Number of runs.
    dt : float
        Step size (s).
    n_steps : int
        Steps per run (duration / dt).
    stride : int
        Steps between two envelope samples.
    seed : int
        Study seed.
    chunk_size : int
        Runs per chunk (the unit of work, of resume and of a Dask task).
    airspeed : float
        Nominal trim airspeed (m/s) before dispersion.
    input_name : str
        Mission, profile or CSV the command deviations come from.
    deviations : numpy.ndarray
        ``n_steps x nu`` command deviations added to each run's trim command.
    limits : tuple of float
        Resolved thresholds ``(pitch rad, alpha rad, airspeed m/s, load factor)``; inf where a
        limit is off.
    weights_digest : str
        SHA-256 of the weight file, or of the given model's Function ('' for the airframe's
        own physics).
    given : DiscreteModel or None
        A model the caller built (``build_spec(..., model=)``); None: the airframe's physics
        or the hybrid step of ``net``.
    feedback : numpy.ndarray or None
        Closed loop: the state-feedback gain (``nu x 4``, :func:`lqr_gain`) on the body states
        about each run's trim; None: the commands are flown open loop.
    vector_math : bool
        The chunk loop's maths functions through glibc's vector library (faster; each run
        equal to the scalar code to round-off instead of to the last bit).
    """

    airframe: Airframe
    dispersions: Dispersions
    net: CorrectionNet | None
    model: str
    runs: int
    dt: float
    n_steps: int
    stride: int
    seed: int
    chunk_size: int
    airspeed: float
    input_name: str
    deviations: np.ndarray
    limits: tuple[float, float, float, float]
    weights_digest: str = ""
    given: DiscreteModel | None = None
    feedback: np.ndarray | None = None
    vector_math: bool = False
    key: str = field(default="", init=False)
    model_key: str = field(default="", init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "key", _digest(self.key_content()))
        object.__setattr__(self, "model_key", _digest({
            "airframe": self.airframe.param_hash(), "kind": self.airframe.kind,
            "structure": repr(self.structure), "weights": self.weights_digest,
            "n_steps": self.n_steps, "stride": self.stride, "gusts": self.gusts,
            "bounds": self.airframe.control_bounds(), "casadi": ca.__version__,
            "feedback": None if self.feedback is None else np.asarray(self.feedback).tolist()}))

    @property
    def duration(self) -> float:
        return self.n_steps * self.dt

    @property
    def gusts(self) -> bool:
        return self.dispersions.has_gusts

    @property
    def gust_stride(self) -> int:
        """Steps over which one gust sample is held (``[gust] sample_dt / dt``, at least 1)."""
        sample_dt = self.dispersions.gust_sample_dt
        return 1 if sample_dt is None else max(1, int(round(sample_dt / self.dt)))

    @property
    def fitting(self) -> tuple[str, ...]:
        """Dispersed parameters: their terms stay in the graph even at a nominal value of 0."""
        return tuple(sorted(self.dispersions.params))

    @property
    def structure(self) -> ModelStructure:
        """The physics structure the runs are integrated with."""
        if self.given is not None:
            return self.given.structure
        if self.net is None:
            return structure_of(self.airframe, self.fitting)
        return correction_structure(self.airframe, self.net.kind, self.net.formulation)

    def discrete_model(self) -> DiscreteModel:
        """The (uncompiled) model the runs fly, without gusts: its state layout starts each
        run."""
        if self.given is not None:
            return self.given
        if self.net is None:
            return replace(physics_step(self.structure), airframe=self.airframe)
        return hybrid_step(self.net, self.airframe, compile=False)

    @property
    def history_time(self) -> np.ndarray:
        """Times (s) of the envelope samples."""
        stride = min(self.stride, self.n_steps)
        return np.arange(self.n_steps // stride + 1) * stride * self.dt

    def step(self) -> ca.Function:
        """The (uncompiled) step Function the runs use: ``(x, u, p, dt)``, ``u`` with gusts
        appended when the study has turbulence."""
        if not self.gusts:
            return self.discrete_model().function
        if self.net is None:
            return gust_step(self.structure)
        return gust_step(self.structure, self.net, "hybrid_gust_step")

    def key_content(self) -> dict:
        """What the study key hashes: everything but the number of runs, by construction the
        whole airframe as its file would hold it (parameters, limits, rate limits, delays,
        atmosphere, tables) and the serialised step Function the runs integrate (its
        structure: actuator lags, delay buffers, gusts, the correction), not a hand-picked
        list of fields."""
        content = to_toml_dict(self.airframe)
        content["params"] = {n: repr(float(v["value"])) for n, v in content["params"].items()}
        for label in ("name", "description"):
            content.pop(label, None)
        step = hashlib.sha256(self.step().serialize().encode()).hexdigest()
        return {
            "format": SPEC_FORMAT, "uavdyn": __version__, "casadi": ca.__version__,
            "airframe": {"kind": self.airframe.kind, "param_hash": self.airframe.param_hash(),
                         "content": content},
            "step_sha256": step,
            "model": self.model, "weights_sha256": self.weights_digest,
            "dispersions": self.dispersions.to_dict(), "seed": self.seed, "dt": self.dt,
            "n_steps": self.n_steps, "stride": self.stride, "chunk_size": self.chunk_size,
            "airspeed": self.airspeed, "input": self.input_name,
            "deviations_sha256": hashlib.sha256(
                np.ascontiguousarray(self.deviations, dtype="<f8").tobytes()).hexdigest(),
            "limits": [repr(float(v)) for v in self.limits],
            "feedback": (None if self.feedback is None
                         else [[repr(float(v)) for v in row] for row in self.feedback]),
            **({"vector_math": True} if self.vector_math else {}),
        }

    def describe(self) -> dict:
        """JSON-friendly description (``study.json``)."""
        return {"key": self.key, "airframe_name": self.airframe.name, "runs": self.runs,
                "duration_s": self.duration,
                "dispersion_file": self.dispersions.origin,
                "dispersions": self.dispersions.describe(),
                "limits": dict(zip(("pitch_deg", "alpha_deg", "airspeed_min_mps",
                                    "load_factor_max"), _limits_shown(self.limits))),
                **{k: v for k, v in self.key_content().items() if k != "limits"}}


def _limits_shown(limits) -> list:
    pitch, alpha, speed, load = limits
    return [None if math.isinf(pitch) else math.degrees(pitch),
            None if math.isinf(alpha) else math.degrees(alpha),
            None if speed == -math.inf else speed, None if math.isinf(load) else load]


def _digest(doc: dict) -> str:
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def resolve_limits(dispersions: Dispersions, airframe: Airframe
                   ) -> tuple[float, float, float, float]:
    """The thresholds in SI units: the file's ``[limits]`` where set (None: off), else the
    defaults (pitch 30 deg; fixed wing: alpha at the nominal stall angle, airspeed at the
    nominal stall speed, load factor 2.5; multirotor: no alpha and airspeed limits, load factor
    2.0). Off is +inf (-inf for the airspeed minimum)."""
    given = dispersions.limits
    defaults: dict[str, float | None] = {
        "pitch_deg": DEFAULT_PITCH_LIMIT_DEG, "alpha_deg": None, "airspeed_min_mps": None,
        "load_factor_max": DEFAULT_LOAD_LIMIT[airframe.kind]}
    if airframe.kind == "fixed_wing" and not ("alpha_deg" in given
                                              and "airspeed_min_mps" in given):
        v_stall, alpha_stall, _ = stall_speed(airframe)
        defaults.update(alpha_deg=math.degrees(alpha_stall), airspeed_min_mps=v_stall)
    values = {k: given[k] if k in given else defaults[k] for k in LIMIT_KEYS}
    return (math.radians(values["pitch_deg"]) if values["pitch_deg"] is not None else math.inf,
            math.radians(values["alpha_deg"]) if values["alpha_deg"] is not None else math.inf,
            float(values["airspeed_min_mps"]) if values["airspeed_min_mps"] is not None
            else -math.inf,
            float(values["load_factor_max"]) if values["load_factor_max"] is not None
            else math.inf)


def _weights(weights: str | Path | None, airframe: Airframe
             ) -> tuple[CorrectionNet | None, str, str]:
    if weights is None:
        return None, "physics", ""
    path = shipped_weights(airframe.name) if str(weights) == "shipped" else Path(weights)
    net = load_weights(path, airframe)
    try:
        digest = hashlib.sha256(read_regular(path, 64 * 2**20, "a weight file")).hexdigest()
    except UnreadableFile as exc:  # pragma: no cover - load_weights read it just now
        raise MonteCarloError(f"{path}: {exc.reason}") from None
    return net, f"hybrid ({Path(path).name}: {net.describe()})", digest


def _given_model(model: DiscreteModel, weights, dispersions: Dispersions, airframe: Airframe
                 ) -> tuple[str, str]:
    """The label and content digest of a model handed to :func:`build_spec`."""
    if not isinstance(model, DiscreteModel):
        raise MonteCarloError(f"model must be a DiscreteModel (uavdyn.physics_step, "
                              f"uavdyn.hybrid_step), got {type(model).__name__}")
    if weights is not None:
        raise MonteCarloError("give either weights or model, not both")
    if dispersions.has_gusts:
        raise MonteCarloError("a study with gusts rebuilds the physics around the correction: "
                              "give weights (or no model) instead of a model object")
    if model.kind != airframe.kind or model.layout.with_position:
        raise MonteCarloError(f"model '{model.name}' is a {model.kind} step"
                              + (" with position states" if model.layout.with_position else "")
                              + f"; the airframe '{airframe.name}' is a {airframe.kind}")
    if model.function.is_a("External"):
        raise MonteCarloError(f"model '{model.name}' is compiled; give the uncompiled model "
                              "(compile=False): the study compiles its own batch")
    digest = hashlib.sha256(model.function.serialize().encode()).hexdigest()
    return model.description or model.name, digest


def build_spec(airframe: Airframe, dispersions: Dispersions, runs: int, duration: float,
               dt: float = 0.01, mission: str = "doublet", weights: str | Path | None = None,
               seed: int | None = None, chunk_size: int = 200,
               history_dt: float = DEFAULT_HISTORY_DT, airspeed: float | None = None,
               model: DiscreteModel | None = None, closed_loop: bool = False,
               vector_math: bool = False) -> StudySpec:
    """Check a study's settings and gather them in a :class:`StudySpec`.

    Parameters
    ----------
    airframe : Airframe
        Nominal airframe.
    dispersions : Dispersions
        From :func:`uavdyn.montecarlo.load_dispersions`.
    runs : int
        Number of runs (>= 1).
    duration, dt : float
        Seconds per run and step size (s).
    mission : str
        Command input (see :func:`command_deviations`).
    weights : path, "shipped" or None
        Weight file of a hybrid study (None: the physics step).
    seed : int, optional
        Study seed (default: the dispersion file's, else 0).
    chunk_size : int
        Runs per chunk.
    history_dt : float
        Interval of the envelope samples (s, rounded to whole steps).
    airspeed : float, optional
        Nominal trim airspeed (default: the airframe's).
    closed_loop : bool
        Fly each run with the state feedback of :func:`lqr_gain` at the nominal trim about
        the run's own trim (an open-loop unstable airframe, any multirotor, departs open
        loop).
    model : DiscreteModel, optional
        Fly this model (e.g. ``uavdyn.physics_step(af)`` or ``uavdyn.hybrid_step(w, af)``)
        instead of building one from ``weights``; it must be built for ``airframe``'s
        structure, and a study with gusts needs ``weights`` instead (the gust step rebuilds
        the physics around the network).
    vector_math : bool
        Evaluate the maths functions of four runs in one call of glibc's vector library
        (``libmvec``; x86-64 with AVX2, glibc 2.35+): about 1.5x faster chunks, each run equal
        to the scalar code's to round-off (a few units in the last place per function) instead
        of bit for bit.

    Raises
    ------
    MonteCarloError
        For settings out of range, a nominal airframe that does not trim, or a hybrid step
        that cannot be used for the study.
    """
    for name, value in (("duration", duration), ("dt", dt), ("history_dt", history_dt)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise MonteCarloError(f"{name} must be a positive number of seconds, got {value}")
    if not (isinstance(runs, int) and runs >= 1):
        raise MonteCarloError(f"runs must be an integer >= 1, got {runs}")
    if not (isinstance(chunk_size, int) and chunk_size >= 1):
        raise MonteCarloError(f"chunk size must be an integer >= 1, got {chunk_size}")
    n_steps = int(round(duration / dt))
    if n_steps < 1 or n_steps > MAX_STEPS:
        raise MonteCarloError(f"duration {duration:g} s at dt {dt:g} s is {n_steps} steps; "
                              f"between 1 and {MAX_STEPS} are allowed")
    unavailable = vector_math_unavailable() if vector_math else None
    if unavailable:
        raise MonteCarloError(f"vector math is not available here: {unavailable}; leave out "
                              "--vector-math")
    seed = dispersions.seed if seed is None and dispersions.seed is not None else (seed or 0)
    if not (isinstance(seed, int) and 0 <= seed < 2**63):
        raise MonteCarloError(f"seed must be an integer >= 0, got {seed}")
    speed = airframe.nominal_airspeed if airspeed is None else float(airspeed)
    try:
        point = trim(airframe, speed)
    except TrimError as exc:
        raise MonteCarloError(f"the nominal airframe does not trim: {exc}") from None
    feedback = lqr_gain(airframe, point) if closed_loop else None
    if model is not None:
        label, digest = _given_model(model, weights, dispersions, airframe)
        net = None
    else:
        net, label, digest = _weights(weights, airframe)
    if net is not None or model is not None:
        step = model if model is not None else hybrid_step(net, airframe, compile=False)
        if step.takes_time:
            raise MonteCarloError(f"{label}: this correction takes time t as an input; use "
                                  "weights of the 'improved' formulation")
        step.check_use(dt, 0.0, n_steps * dt)
        needed = structure_of(airframe, tuple(sorted(dispersions.params)))
        if needed != step.structure:
            raise MonteCarloError(
                f"dispersing {', '.join(sorted(dispersions.params))} adds model terms (alpha-"
                "dot, actuator lag) the model's physics does not carry at the nominal "
                "values; disperse them with the airframe's own physics step")
    sample_dt = dispersions.gust_sample_dt
    if sample_dt is not None and abs(sample_dt / dt - round(sample_dt / dt)) > 1e-6 * (
            sample_dt / dt) or (sample_dt is not None and sample_dt < dt * (1 - 1e-9)):
        raise MonteCarloError(f"{dispersions.origin}: key 'gust.sample_dt' = {sample_dt:g} s "
                              f"must be a whole multiple of the step {dt:g} s")
    deviations = command_deviations(mission, airframe, n_steps, dt, seed)
    stride = max(1, int(round(history_dt / dt)))
    # a CSV is known by its name (its content is in the key through the deviations)
    known = mission in PROFILES or mission in emulator_missions()
    name = mission if known else f"csv:{Path(mission).name}"
    return StudySpec(airframe=airframe, dispersions=dispersions, net=net, model=label,
                     runs=runs, dt=float(dt), n_steps=n_steps, stride=min(stride, n_steps),
                     seed=int(seed), chunk_size=chunk_size, airspeed=speed,
                     input_name=name, deviations=np.ascontiguousarray(deviations, float),
                     limits=resolve_limits(dispersions, airframe), weights_digest=digest,
                     given=model, feedback=feedback, vector_math=bool(vector_math))
