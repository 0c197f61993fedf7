"""Closed-loop MPC studies: every scenario flown with every prediction model (hybrid step,
physics RK4 of the same airframe) against the calm emulator, and their statistics.

For a preset without ``weights`` the hybrid is the shipped safe correction on the identified
airframe it was trained on, and the physics prediction is that identified airframe's RK4 step,
so "hybrid vs physics" isolates the correction (a preset whose training kept no correction
flies the identified physics alone); the plant is the emulator of the preset (the
"real aircraft" the identification and the correction were fitted to). With ``weights`` both
predictions run on the given airframe and the plant is its emulator; an airframe file without
weights flies its physics alone. ``plant`` sets the emulated aircraft apart from the prediction
model (e.g. the truth an identified model was fitted to).

Statistics follow the status policy: solve-time medians and maxima are over successful solves
only; failed solves and the fallbacks applied instead are their own columns.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe, list_presets, load_airframe
from uavdyn.emulation import Emulator
from uavdyn.integrate import DiscreteModel, physics_step
from uavdyn.learned import (
    WeightFileError,
    hybrid_step,
    load_weights,
    shipped_correction,
    shipped_identified,
)
from uavdyn.linear import TrimPoint, trim
from uavdyn.mpc.policy import Controller
from uavdyn.mpc.problem import MPCConfig
from uavdyn.mpc.rti import ITERATION_LIMIT
from uavdyn.mpc.scenarios import SCENARIO_NAMES, Scenario, run_scenario, scenario
from uavdyn.mpc.tracking import RELU_SMOOTHING, ClosedLoopResult, build_controller

MODEL_NAMES = ("hybrid", "physics")


@dataclass(frozen=True)
class PredictionModel:
    """A prediction step and the airframe, trim and command memory it runs with."""

    name: str
    model: DiscreteModel
    trim: TrimPoint
    description: str = ""

    @property
    def airframe(self) -> Airframe:
        return self.model.airframe

    def controller(self, config: MPCConfig) -> Controller:
        """A controller of ``config.mode`` predicting with this model."""
        return build_controller(self.model, self.trim.u, config,
                                speed_trim=max(self.trim.airspeed, 1.0))


@dataclass(frozen=True)
class StudySetup:
    """The plant (emulated airframe and its trim) and the prediction models of a study."""

    plant_airframe: Airframe
    plant_trim: TrimPoint
    models: dict[str, PredictionModel]
    weights: Path | None
    missing: dict[str, str] = field(default_factory=dict)  # model -> why it is not flown


def prediction_models(airframe: str, weights: str | Path | None = None,
                      mode: str = "rti", models: tuple[str, ...] = MODEL_NAMES,
                      plant: str | None = None) -> StudySetup:
    """The plant and prediction models of a study.

    Parameters
    ----------
    airframe : str
        Preset name or airframe file (the plant's airframe).
    weights : path, optional
        A weight file trained on ``airframe`` (default: the preset's shipped safe correction
        on its identified airframe).
    mode : str
        ``"rti"`` predicts with the exact (ReLU) network, the shipped correction itself;
        ``"sqp"`` smooths ReLU to softplus (:data:`uavdyn.mpc.tracking.RELU_SMOOTHING`):
        Gauss-Newton SQP zig-zags on the kinks of the exact network (measured: the line
        search fails in most speed-step solves), softplus converges.
    models : tuple of str
        Which of ``hybrid``, ``physics`` to build.
    plant : str, optional
        Preset name or airframe file the emulator flies as the real aircraft (default
        ``airframe``): an identified or corrected prediction model flown against a plant that
        differs from it.

    Returns
    -------
    StudySetup
        A preset whose shipped training kept no correction, or an airframe file given without
        weights, flies its physics alone: ``missing["hybrid"]`` says why, unless only the
        hybrid was asked for.

    Raises
    ------
    uavdyn.learned.WeightFileError
        If the hybrid is the only model asked for and no correction is available, or the
        weights do not belong to the airframe.
    """
    nominal = load_airframe(airframe)
    plant_af = load_airframe(plant) if plant is not None else nominal
    missing: dict[str, str] = {}
    net = None
    if weights is None and airframe not in list_presets():
        why = (f"no correction for the airframe file {airframe}; give --weights FILE "
               "(trained on this airframe) to fly one")
        if "physics" not in models:
            raise WeightFileError(why)
        weights, model_af = None, nominal
        if "hybrid" in models:
            missing["hybrid"] = why
    elif weights is None:
        try:
            weights, model_af = shipped_correction(nominal.name)
        except WeightFileError as exc:
            if "hybrid" in models and "physics" not in models:
                raise
            weights, model_af = None, shipped_identified(nominal.name)
            if "hybrid" in models:
                missing["hybrid"] = str(exc)
    else:
        weights, model_af = Path(weights), nominal
    if weights is not None:
        net = load_weights(weights, model_af)
    model_trim = trim(model_af)
    out: dict[str, PredictionModel] = {}
    if "hybrid" in models and net is not None:
        smoothing = RELU_SMOOTHING if mode == "sqp" else None
        step = hybrid_step(net, model_af, compile=False, relu_smoothing=smoothing)
        how = "exact ReLU" if smoothing is None else f"ReLU smoothed to softplus k={smoothing:g}"
        out["hybrid"] = PredictionModel("hybrid", step, model_trim,
                                        f"{Path(weights).name} on {model_af.name} ({how})")
    if "physics" in models:
        out["physics"] = PredictionModel("physics", physics_step(model_af), model_trim,
                                         f"RK4 of {model_af.name} (no correction)")
    if plant_af.kind != nominal.kind:
        raise ValueError(f"plant {plant} is a {plant_af.kind}, the airframe {airframe} a "
                         f"{nominal.kind}")
    return StudySetup(plant_af, trim(plant_af), out, weights, missing)


def fly_all(setup: StudySetup, config: MPCConfig,
            scenarios: tuple[str, ...] = SCENARIO_NAMES,
            progress=None) -> dict[tuple[str, str], tuple[Scenario, ClosedLoopResult]]:
    """Every scenario with every prediction model: closed-loop results keyed
    ``(scenario, model)``. One controller per model is built (and compiled) once and reset
    before each scenario; ``progress(message)`` is called before each flight."""
    emulator = Emulator(setup.plant_airframe)
    out = {}
    for name, model in setup.models.items():
        mpc = model.controller(config)
        for sc_name in scenarios:
            sc = scenario(setup.plant_airframe.kind, sc_name)
            if progress is not None:
                progress(f"{sc_name} with {name} prediction ({config.mode}, horizon "
                         f"{config.horizon})")
            out[(sc_name, name)] = (sc, run_scenario(sc, mpc, setup.plant_airframe,
                                                     setup.plant_trim, emulator=emulator))
    return out


def solve_statistics(res: ClosedLoopResult) -> dict:
    """Solve-time statistics of one flight: median, 95th percentile and max over successful
    solves only (ms), the success rate, the failures, the fallbacks applied and the full-SQP
    solves applied at the iteration limit (counted as successful)."""
    ok = res.solve_times_s[res.success] * 1e3
    counts = res.counts()
    return {
        "solves": int(len(res.success)),
        "successful_solves": int(res.success.sum()),
        "failed_solves": int((~res.success).sum()),
        "success_rate": float(res.success.mean()) if len(res.success) else 0.0,
        "fallback_shifted": counts["shifted"], "fallback_held": counts["held"],
        "iteration_limit_solves": _iteration_limited(res),
        "solve_ms_median": float(np.median(ok)) if len(ok) else None,
        "solve_ms_p95": float(np.percentile(ok, 95)) if len(ok) else None,
        "solve_ms_max": float(np.max(ok)) if len(ok) else None,
        "failed_solve_ms_max": (float(np.max(res.solve_times_s[~res.success]) * 1e3)
                                if (~res.success).any() else None),
    }


def lost_control(res: ClosedLoopResult, pitch_deg: float = 60.0) -> bool:
    """Whether a flight left any sensible envelope: departed from the physical ranges, a
    non-finite state or pitch beyond ``pitch_deg`` (no scenario commands more than 5 deg and
    the soft bound is 30 deg)."""
    return bool(res.departure is not None or not np.all(np.isfinite(res.states))
                or np.max(np.abs(res.states[:, 3])) > np.radians(pitch_deg))


def flight_outcome(res: ClosedLoopResult, sc: Scenario) -> dict:
    """Tracking RMSE of a flight that stayed finite and inside the physical ranges (else
    None), whether it stayed finite, and its departure (None when it did not depart)."""
    finite = bool(np.all(np.isfinite(res.states)))
    whole = finite and res.departure is None
    return {"tracking_rmse": res.rmse(sc.tracked, t_from=sc.start) if whole else None,
            "finite_flight": finite, "departure": res.departure}


def summarise(results: dict) -> dict:
    """Tracking RMSE and solve statistics per scenario and model (JSON-ready)."""
    out: dict = {}
    for (sc_name, model), (sc, res) in results.items():
        out.setdefault(sc_name, {})[model] = {
            "tracked": sc.tracked, "tracking_rmse_unit": sc.unit,
            **flight_outcome(res, sc),
            "max_abs_pitch_deg": float(np.degrees(np.max(np.abs(res.states[:, 3])))),
            "lost_control": lost_control(res), **solve_statistics(res)}
    return out


def _iteration_limited(res: ClosedLoopResult) -> int:
    """Full-SQP solves applied at the iteration limit (:data:`uavdyn.mpc.rti.ITERATION_LIMIT`)."""
    return 0 if res.status is None else int(np.sum(res.status == ITERATION_LIMIT))


def pooled(results: dict, model: str) -> dict:
    """Solve statistics of one model pooled over every scenario flown."""
    runs = [r for (_, m), (_, r) in results.items() if m == model]
    times = np.concatenate([r.solve_times_s for r in runs])
    ok = np.concatenate([r.success for r in runs])
    source = np.concatenate([r.source for r in runs])
    good = times[ok] * 1e3
    return {"solves": int(len(ok)), "success_rate": float(ok.mean()),
            "failed_solves": int((~ok).sum()),
            "fallback_shifted": int(np.sum(source == "shifted")),
            "fallback_held": int(np.sum(source == "held")),
            "iteration_limit_solves": sum(_iteration_limited(r) for r in runs),
            "median_ms": float(np.median(good)) if len(good) else None,
            "p95_ms": float(np.percentile(good, 95)) if len(good) else None,
            "max_ms": float(np.max(good)) if len(good) else None}


def startup_seconds(model: PredictionModel, config: MPCConfig) -> float:
    """Wall time to construct a controller (with a warm compile cache: the library is
    loaded, not built)."""
    t0 = time.perf_counter()
    model.controller(config)
    return time.perf_counter() - t0
