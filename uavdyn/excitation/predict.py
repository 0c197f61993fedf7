"""Fly a designed input on the flight-data emulator and predict the standard errors it gives.

The emulator (:mod:`uavdyn.emulation`) flies the schedule as a pilot would (the fixed wing's
inputs hands-off, the multirotor's injected at the mixer with its attitude loop on), with the
truth model's actuator lags and rate limits, Dryden turbulence and mean wind on a share of the
sorties and the emulator's sensor noise, exactly as ``uavdyn generate-data`` flies its
missions. The predicted standard errors are the Cramer-Rao bound of the output-error fit on
those flights (:func:`uavdyn.identify.prediction.predict_standard_errors`) with the emulator's
white sensor noise: a lower bound, since turbulence and model error colour the residuals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.emulation.datagen import SPLITS
from uavdyn.emulation.emulator import (
    REFERENCE_NAMES,
    Emulator,
    SensorNoise,
    dryden_gusts,
    gust_span,
)
from uavdyn.emulation.missions import DEFAULT_ALTITUDE, GAINS, FlightPlan, trim_schedule
from uavdyn.excitation.design import ExcitationDesign
from uavdyn.flightdata import Sortie, csv_columns, write_csv, write_manifest
from uavdyn.identify.excitation import unexcited
from uavdyn.identify.prediction import (
    DEFAULT_MAX_WINDOWS,
    PredictedErrors,
    predict_standard_errors,
)
from uavdyn.linear import trim

MISSION = "designed_input"
TURBULENCE = (0.5, 2.0)   # x light turbulence, as the emulator's recipes
MEAN_WIND = (0.0, 6.0)    # m/s inertial head wind on turbulent sorties


def schedule_plan(airframe: Airframe, t: np.ndarray, speed: float, increments: np.ndarray,
                  hands_off: np.ndarray) -> FlightPlan:
    """The emulator's flight plan for a schedule: level flight at ``speed`` at the missions'
    default altitude with the autopilot's trim feed-forward (as every mission flies), the
    ``increments`` (``N x 2``) added to it, and the autopilot's gains zero where
    ``hands_off`` (a multirotor's loops stay on: its inputs are injected at the mixer)."""
    ref = np.zeros((len(t), len(REFERENCE_NAMES)))
    col = {name: i for i, name in enumerate(REFERENCE_NAMES)}
    theta, ctrl = trim_schedule(airframe, np.full_like(t, speed))
    h0 = DEFAULT_ALTITUDE[airframe.kind]
    ref[:, col["ff0"]:col["ff1"] + 1] = ctrl + np.asarray(increments, float)
    ref[:, col["theta_ref"]], ref[:, col["speed_ref"]], ref[:, col["h_ref"]] = theta, speed, h0
    ref[:, col["K_theta"]:] = GAINS[airframe.kind]
    ref[np.asarray(hands_off, bool), col["K_theta"]:] = 0.0
    return FlightPlan(mission=MISSION, kind=airframe.kind, x0=trim(airframe, speed).x.copy(),
                      u0=ctrl[0], altitude=h0, references=ref,
                      params={"speed_mps": round(float(speed), 3)})


def emulate_design(design: ExcitationDesign, airframe: Airframe, sorties: int, seed: int = 0,
                   turbulent_fraction: float = 0.5, noise_scale: float = 1.0
                   ) -> list[Sortie]:
    """Fly ``sorties`` repetitions of ``design`` on the emulator (every other one reversed in
    sign, ``turbulent_fraction`` of them in turbulence and mean wind), seeded per sortie.

    Returns
    -------
    list of Sortie
        Measured states (sensor noise), ``true_states`` noise-free, ``meta`` with the
        condition, turbulence intensity and wind.
    """
    emulator = Emulator(airframe, sample_rate_hz=design.sample_rate_hz)
    t = design.time
    n_turb = int(round(turbulent_fraction * sorties))
    out = []
    for i in range(sorties):
        rng = np.random.default_rng([seed, 2, i])
        sign = 1.0 if i % 2 == 0 else -1.0
        plan = schedule_plan(airframe, t, design.speed, sign * design.increments,
                             design.hands_off)
        turbulent = (i * n_turb) // sorties != ((i + 1) * n_turb) // sorties
        x0 = emulator.initial_state(plan.x0, plan.u0, plan.altitude)
        gusts = wind = None
        intensity = speed_wind = 0.0
        if turbulent:
            intensity = float(rng.uniform(*TURBULENCE))
            speed_wind = float(rng.uniform(*MEAN_WIND))
            wind = np.array([-speed_wind, 0.0])
            airspeed = abs(design.speed) + (speed_wind if airframe.kind == "multirotor" else 0)
            gusts = dryden_gusts(rng, len(t), 1.0 / design.sample_rate_hz,
                                 max(airspeed, 5.0), intensity, gust_span(airframe))
            if airframe.kind == "fixed_wing":
                x0 = emulator.initial_state(plan.x0, plan.u0, plan.altitude, wind=wind)
        flight = emulator.fly(x0, plan.references, gusts, rng, noise_scale, wind=wind)
        out.append(Sortie(f"sortie_{i:03d}", airframe.kind, flight.time,
                          flight.measured_states, flight.controls, MISSION,
                          {"condition": "turbulent" if turbulent else "calm",
                           "turbulence_intensity": round(intensity, 6),
                           "wind_inertial_mps": [-round(speed_wind, 6) + 0.0, 0.0],
                           "seed": [seed, 2, i], "sign": int(sign)},
                          flight.true_states))
    return out


def calm_screen(sorties: list[Sortie], names: list[str]) -> list[str]:
    """What ``uavdyn identify``'s excitation screen (:func:`uavdyn.identify.excitation.unexcited`)
    would refuse on the calm ones of the emulated ``sorties`` (all of them if none is calm):
    turbulence must not be what excites a parameter."""
    calm = [s for s in sorties if s.meta.get("condition") == "calm"] or sorties
    return unexcited(list(names), calm)


def sensor_noise(noise_scale: float = 1.0) -> np.ndarray:
    """The emulator's white sensor-noise standard deviations ``[u, w, q, theta]``."""
    s = SensorNoise().scaled(noise_scale)
    return np.array([s.u, s.w, s.q, s.theta])


def predict_errors(airframe: Airframe, sorties: list[Sortie], names: list[str],
                   noise_scale: float = 1.0, window_s: float = 1.0,
                   max_windows: int | None = DEFAULT_MAX_WINDOWS) -> PredictedErrors:
    """The Cramer-Rao standard errors of ``names`` on the emulated ``sorties`` (their
    noise-free states, the emulator's sensor noise): see the module docstring."""
    return predict_standard_errors(airframe, sorties, names, sensor_noise(noise_scale),
                                   window_s, max_windows)


def split_of(index: int, count: int) -> str:
    """Every fifth sortie (the 5th, 10th, ...) validation, the others train."""
    return SPLITS[1] if count >= 5 and index % 5 == 4 else SPLITS[0]


def write_emulated(sorties: list[Sortie], design: ExcitationDesign, folder: Path,
                   recipe: dict) -> Path:
    """Write the emulated flights as a dataset (interchange format, ``*_true.csv`` beside
    each sortie, a train/validation split) into ``folder``; returns the manifest path."""
    entries = []
    for i, s in enumerate(sorties):
        write_csv(s, folder / f"{s.name}.csv")
        true = Sortie(s.name + "_true", s.kind, s.time, s.true_states, s.controls, s.mission)
        write_csv(true, folder / f"{s.name}_true.csv")
        entries.append({"file": f"{s.name}.csv", "true_file": f"{s.name}_true.csv",
                        "mission": s.mission, "duration_s": float(s.time[-1] - s.time[0]),
                        "rows": len(s.time), "split": split_of(i, len(sorties)), **s.meta})
    splits = {k: [e["file"] for e in entries if e["split"] == k] for k in SPLITS}
    return write_manifest(
        folder, airframe=design.airframe, kind=design.kind,
        sample_rate_hz=design.sample_rate_hz,
        source="uavdyn design-input: the designed schedule flown on the flight-data emulator",
        sorties=entries, columns=list(csv_columns(design.kind)), splits=splits,
        true_states="each sortie's true_file holds the noise-free states, same header",
        controls="commanded inputs, held over each log interval (zero-order hold)",
        recipe=recipe)
