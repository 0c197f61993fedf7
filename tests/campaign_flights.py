"""Synthetic flight-test campaigns for the tests: six-degree-of-freedom flights with coordinated
turns, climbs, a steady wind, turbulence and sensor noise, written as the generic CSV
(:mod:`uavdyn.flightdata.sixdof_csv`), with the truly wings-level intervals known exactly.

How a flight is made:

* the pitch plane is flown by the project's emulator (:class:`uavdyn.emulation.Emulator`) on a
  "truth" airframe: the example trainer (``examples/trainer.toml``, not a preset) with its
  pitch-moment and lift derivatives changed (:data:`TRUTH_CHANGES`), through survey legs
  (speed and altitude changes: climbs and descents) with open-loop 3-2-1-1 elevator inputs,
  Dryden turbulence and the emulator's sensor noise;
* coordinated turns of 20-45 deg bank are laid over it: roll ramps in and out at
  :data:`ROLL_RATE_DEG_S`, heading rate ``g tan(phi) / V``, and the body rates and Euler
  angles follow the exact kinematics (``theta_dot = q cos(phi) - r sin(phi)`` equals the
  emulator's pitch rate, ``psi_dot = (q sin(phi) + r cos(phi)) / cos(theta)`` the turn rate);
* a steady horizontal wind (NED) is added to the air-relative velocity rotated to NED, so the
  CSV carries ground velocities ``vn, ve, vd`` and the wind columns, as a logger with a wind
  estimate would; the importer recovers the air-relative ``u, v, w``.

What it is not: the longitudinal motion does not feel the bank (no extra lift demand or
pitch-rate coupling in the turns). The turns are therefore right for testing where an
importer cuts and what it keeps, and wrong for fitting through turns (issue 41 item 2 needs
a generator with the full six-degree-of-freedom equations).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uavdyn.airframes import Airframe, load_airframe
from uavdyn.emulation.emulator import Emulator
from uavdyn.emulation.missions import REF, survey
from uavdyn.emulation.turbulence import dryden_gusts, gust_span
from uavdyn.flightdata.attitude import body_from_euler
from uavdyn.integrate.inputs import multistep_3211

G = 9.80665
TRAINER = Path(__file__).resolve().parents[1] / "examples" / "trainer.toml"
TRUTH_CHANGES = {"C_m_alpha": 1.3, "C_m_q": 0.7, "C_L_alpha": 0.9, "C_m_0": 1.5}
"""The truth airframe's parameters as multiples of the trainer file's (what identify should
find; the emulator adds the effects the model lacks)."""
ROLL_RATE_DEG_S = 30.0
COLUMNS = ["time", "roll", "pitch", "yaw", "p", "q", "r", "vn", "ve", "vd", "wind_n",
           "wind_e", "wind_d", "airspeed", "altitude_m", "airborne", "elevator", "throttle"]
ROLL_NOISE = 0.003        # rad, like the emulator's pitch noise
RATE_NOISE = 0.005        # rad/s, like the emulator's pitch-rate noise


@dataclass
class CampaignFlight:
    """One synthetic flight: its CSV columns, the turns flown, and the truly wings-level
    intervals (bank exactly zero) in the flight's own time."""

    columns: dict[str, np.ndarray]
    turns: list[tuple[float, float, float]]      # (start_s, end_s, bank_deg)
    level: list[tuple[float, float]]
    rate_hz: float

    @property
    def duration(self) -> float:
        return float(self.columns["time"][-1] - self.columns["time"][0])

    def within_bank(self, limit_deg: float) -> list[tuple[float, float]]:
        """The intervals where the true bank is at most ``limit_deg`` (the turns shrunk by
        the roll ramp's time to ``limit_deg``): where a ``|roll| <= limit_deg`` rule must
        cut, exactly."""
        shrink = limit_deg / ROLL_RATE_DEG_S
        edges = [0.0] + [x for s, e, _ in self.turns for x in (s + shrink, e - shrink)]
        edges.append(self.duration)
        return list(zip(edges[::2], edges[1::2]))

    def write(self, path: Path) -> Path:
        """The generic six-degree-of-freedom CSV of this flight."""
        data = np.column_stack([self.columns[c] for c in COLUMNS])
        rows = [",".join(COLUMNS)] + [",".join(f"{v:.9g}" for v in row) for row in data]
        path.write_text("\n".join(rows) + "\n")
        return path


def truth_airframe(nominal: Airframe) -> Airframe:
    """The trainer with :data:`TRUTH_CHANGES` applied."""
    values = dict(zip(nominal.param_names, nominal.p))
    return nominal.replace(**{k: values[k] * f for k, f in TRUTH_CHANGES.items()})


def _turn_plan(rng: np.random.Generator, duration: float) -> list[tuple[float, float, float]]:
    """Alternating wings-level legs (20-40 s) and turns (8-20 s at 20-45 deg, either way)."""
    turns, t = [], float(rng.uniform(15.0, 25.0))
    while t + 25.0 < duration:
        length = float(rng.uniform(8.0, 20.0))
        bank = float(rng.uniform(20.0, 45.0)) * float(rng.choice([-1.0, 1.0]))
        turns.append((t, t + length, bank))
        t += length + float(rng.uniform(20.0, 40.0))
    return turns


def _roll(t: np.ndarray, turns: list[tuple[float, float, float]]) -> np.ndarray:
    """Bank angle (rad): trapezoids ramping at ROLL_RATE_DEG_S inside each turn window."""
    phi = np.zeros_like(t)
    for start, end, bank in turns:
        ramp = abs(bank) / ROLL_RATE_DEG_S
        shape = np.clip(np.minimum(t - start, end - t) / ramp, 0.0, 1.0)
        phi += np.radians(bank) * shape
    return phi


def _inputs(plan_ref: np.ndarray, t: np.ndarray, rng: np.random.Generator,
            turns: list[tuple[float, float, float]]) -> np.ndarray:
    """The survey references with an open-loop 3-2-1-1 in the middle of each level leg."""
    ref = plan_ref.copy()
    edges = [0.0] + [x for s, e, _ in turns for x in (s, e)] + [float(t[-1])]
    for lo, hi in zip(edges[::2], edges[1::2]):
        if hi - lo < 14.0:
            continue
        unit = float(rng.uniform(0.3, 0.5))
        start = 0.5 * (lo + hi) - 3.5 * unit
        amp = float(rng.choice([-1.0, 1.0])) * float(rng.uniform(0.03, 0.05))
        ref[:, REF["ff0"]] += multistep_3211(t, amp, start, unit)
        window = (t >= start) & (t < start + 7 * unit + 3.0)
        ref[window, REF["K_theta"]:] = 0.0
    return ref


def campaign_flight(seed: int, duration_s: float = 360.0, rate_hz: float = 50.0,
                    wind_ned: tuple[float, float] = (3.0, -2.0), turbulence: float = 1.0,
                    nominal: Airframe | None = None) -> CampaignFlight:
    """One synthetic six-degree-of-freedom flight (see the module docstring).

    Parameters
    ----------
    seed : int
        Seeds the legs, turns, inputs, turbulence and noise.
    duration_s, rate_hz : float
        Length and log rate.
    wind_ned : tuple of float
        Steady horizontal wind (north, east), m/s.
    turbulence : float
        Dryden intensity multiplier (0: calm).
    nominal : Airframe, optional
        Default the example trainer; the truth is :func:`truth_airframe` of it.
    """
    rng = np.random.default_rng([41, seed])
    nominal = nominal or load_airframe(str(TRAINER))
    truth = truth_airframe(nominal)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    turns = _turn_plan(rng, duration_s)
    plan = survey(truth, t, rng)
    ref = _inputs(plan.references, t, rng, turns)
    emulator = Emulator(truth, sample_rate_hz=rate_hz, internal_dt=1.0 / (10 * rate_hz),
                        compiled=False)
    speed = float(np.mean(ref[:, REF["speed_ref"]]))
    gusts = dryden_gusts(rng, n, 1.0 / rate_hz, speed, turbulence, gust_span(truth))
    flown = emulator.fly(emulator.initial_state(plan.x0, plan.u0, plan.altitude), ref, gusts,
                         rng)
    u, w, q_long, theta = flown.measured_states.T
    va = np.hypot(flown.true_states[:, 0], flown.true_states[:, 1])
    phi = _roll(t, turns)
    psi_dot = G * np.tan(phi) / va
    psi = np.concatenate([[0.3], 0.3 + np.cumsum(0.5 * (psi_dot[1:] + psi_dot[:-1])) / rate_hz])
    p = np.gradient(phi, t) - psi_dot * np.sin(theta)
    q = q_long * np.cos(phi) + psi_dot * np.cos(theta) * np.sin(phi)
    r = -q_long * np.sin(phi) + psi_dot * np.cos(theta) * np.cos(phi)
    v = rng.normal(0.0, 0.05, n)
    air_ned = np.einsum("nji,nj->ni", body_from_euler(phi, theta, psi),
                        np.column_stack([u, v, w]))
    wind = np.column_stack([np.full(n, wind_ned[0]), np.full(n, wind_ned[1]), np.zeros(n)])
    ground = air_ned + wind
    noisy = {"roll": phi + rng.normal(0, ROLL_NOISE, n),
             "p": p + rng.normal(0, RATE_NOISE, n), "r": r + rng.normal(0, RATE_NOISE, n)}
    columns = {"time": t, "roll": noisy["roll"], "pitch": theta,
               "yaw": (psi + np.pi) % (2 * np.pi) - np.pi, "p": noisy["p"], "q": q,
               "r": noisy["r"], "vn": ground[:, 0], "ve": ground[:, 1], "vd": ground[:, 2],
               "wind_n": wind[:, 0], "wind_e": wind[:, 1], "wind_d": wind[:, 2],
               "airspeed": va, "altitude_m": flown.aux["h"], "airborne": np.ones(n),
               "elevator": flown.controls[:, 0], "throttle": flown.controls[:, 1]}
    edges = [0.0] + [x for s, e, _ in turns for x in (s, e)] + [float(t[-1])]
    level = [(lo, hi) for lo, hi in zip(edges[::2], edges[1::2])]
    return CampaignFlight(columns, turns, level, rate_hz)


def write_campaign(folder: Path, flights: list, stem: str = "flight") -> list[Path]:
    """Each flight (a :class:`CampaignFlight` or a ``tests.turning_flights.TurningFlight``:
    anything with ``write(path)`` and ``rate_hz``) as ``<stem><k>_<rate>hz.csv`` in
    ``folder`` (k from 1, flight order)."""
    folder.mkdir(parents=True, exist_ok=True)
    return [f.write(folder / f"{stem}{k}_{f.rate_hz:g}hz.csv")
            for k, f in enumerate(flights, start=1)]
