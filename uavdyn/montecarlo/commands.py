"""The command input every Monte-Carlo run adds to its own trim command: an input profile, an
emulator mission flown once, or the controls of a recorded interchange CSV, zero-order held on
the run grid.

The emulator and the flight-data reader are imported only where a mission or a CSV is turned
into command deviations: a Dask worker that unpickles a spec does not pay for them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.integrate.inputs import PROFILES, control_sequence
from uavdyn.model import CONTROL_NAMES
from uavdyn.montecarlo.errors import MonteCarloError

MISSION_LOG_RATE_HZ = 100.0   # the emulator flies a mission at this log rate
# input profiles (uavdyn.integrate.inputs): the channel and amplitude they act on
PROFILE_INPUT = {"fixed_wing": (0, math.radians(2.0)), "multirotor": (1, 0.05)}


def input_names(kind: str) -> list[str]:
    """Names ``--mission`` accepts for an airframe kind (a CSV path is accepted too)."""
    return list(PROFILES) + [n for n, (_, kinds) in emulator_missions().items() if kind in kinds]


def emulator_missions() -> dict:
    from uavdyn.emulation import MISSIONS

    return MISSIONS


def command_deviations(source: str, airframe: Airframe, n_steps: int, dt: float,
                       seed: int = 0) -> np.ndarray:
    """``n_steps x nu`` command deviations, zero-order held over each step, that every run adds
    to its own trim command.

    Parameters
    ----------
    source : str
        An input profile (``step``, ``doublet``, ``3211``, ``chirp``, ``none``: 2 deg of
        elevator, or 0.05 of pitch command for a multirotor, from 1 s), an emulator mission
        (:data:`uavdyn.emulation.MISSIONS`: the commands its autopilot gave flying it once in
        calm air with the nominal airframe, seeded with ``seed``, at 100 Hz), or the path of a
        recorded interchange CSV (its controls). Missions and CSVs count from their first
        command.
    airframe : Airframe
        The nominal airframe.
    n_steps, dt : int, float
        The run grid.
    seed : int
        Seed of the mission draw.

    Raises
    ------
    MonteCarloError
        For an unknown name or an input shorter than the runs.
    """
    t = np.arange(n_steps) * dt
    nu = len(CONTROL_NAMES[airframe.kind])
    if source in PROFILES:
        channel, amplitude = PROFILE_INPUT[airframe.kind]
        return control_sequence(source, t, np.zeros(nu), amplitude, channel=channel)
    if source in emulator_missions():
        from uavdyn.emulation import Emulator, plan_mission

        plan = plan_mission(source, airframe, n_steps * dt, MISSION_LOG_RATE_HZ,
                            np.random.default_rng(seed))
        emulator = Emulator(airframe, sample_rate_hz=MISSION_LOG_RATE_HZ)
        flight = emulator.fly(emulator.initial_state(plan.x0, plan.u0, plan.altitude),
                              plan.references)
        return _resample(flight.time, flight.controls, t, source)
    path = Path(source)
    if path.suffix.lower() == ".csv" or path.exists():
        from uavdyn.flightdata import read_csv

        sortie = read_csv(path, kind=airframe.kind)
        return _resample(sortie.time - sortie.time[0], sortie.controls, t, str(path))
    raise MonteCarloError(f"unknown input '{source}': expected a mission or profile "
                          f"({', '.join(input_names(airframe.kind))}) or a control CSV path")


def _resample(time: np.ndarray, controls: np.ndarray, t: np.ndarray, what: str) -> np.ndarray:
    """Zero-order hold of ``controls`` (row i from ``time[i]``) at the times ``t``, minus the
    first command."""
    interval = float(np.median(np.diff(time))) if len(time) > 1 else 0.0
    if len(time) < 2 or time[-1] + interval < t[-1] - 1e-9:
        raise MonteCarloError(f"{what}: its commands cover {time[-1] + interval:.3f} s, less "
                              f"than the {t[-1]:.3f} s the runs need")
    idx = np.clip(np.searchsorted(time, t + 1e-9, side="right") - 1, 0, len(time) - 1)
    return controls[idx] - controls[0]


__all__ = ["MISSION_LOG_RATE_HZ", "PROFILE_INPUT", "command_deviations", "input_names"]
