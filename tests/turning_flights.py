"""Synthetic turning-flight campaigns for issue 41 item 2: flights whose pitch-plane dynamics
feel the turns, written as the generic six-degree-of-freedom CSV
(:mod:`uavdyn.flightdata.sixdof_csv`).

How a flight is made (the difference from :mod:`tests.campaign_flights`, whose turns are laid
over a pitch-plane flight by kinematics only):

* the truth airframe is :func:`tests.campaign_flights.truth_airframe` of the example trainer
  (``examples/trainer.toml``, not a preset, with its ``Jx, Jz, Jxz``), flown by the project's
  emulator (:class:`uavdyn.emulation.Emulator`: actuator lags and rate limits, filtered
  alpha-dot and stall dynamics, survey autopilot with speed and altitude changes, open-loop
  3-2-1-1 elevator inputs in the level legs, Dryden turbulence, sensor noise);
* the lateral motion is **prescribed**, a coordinated-turn schedule, and fed to the emulator's
  truth as inputs (``Emulator.fly(lateral=...)``), whose longitudinal equations then carry the
  bank and turn-rate terms of :mod:`uavdyn.model.equations`::

      phi(t)   trapezoids of 20-45 deg, rolled in and out at ROLL_RATE_DEG_S
      psi_dot = g tan(phi) / V_ref           (level coordinated turn at the speed reference)
      p = phi_dot,  r = psi_dot cos(phi),  beta = 0

  (the exact kinematics of a level turn are ``p = phi_dot - psi_dot sin(theta)``,
  ``r = psi_dot cos(theta) cos(phi)``; the schedule drops the ``theta`` terms, which only
  changes which turn is flown: the truth's pitch rate ``q`` and attitude follow from its own
  dynamics, ``theta_dot = q cos(phi) - r sin(phi)``, and the heading logged is the integral of
  ``(q sin(phi) + r cos(phi)) / cos(theta)``, so every CSV column is kinematically
  consistent);
* a steady horizontal wind (NED) is added to the air-relative velocity rotated to NED, so the
  CSV carries ground velocities and the wind columns, as :mod:`tests.campaign_flights` does.

What it is not: a full 6-DoF simulator. The lateral motion does not respond to the
longitudinal one (no roll/yaw dynamics, no sideslip aerodynamics), and truth and model share
the decoupled structure of the turning-flight equations (the truth adds its own actuator,
unsteady-aerodynamic and turbulence effects the model lacks). A real aircraft would also couple
back; these flights test that the model uses the turns correctly, not that the decoupling holds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tests.campaign_flights import (
    COLUMNS,
    RATE_NOISE,
    ROLL_NOISE,
    ROLL_RATE_DEG_S,
    TRAINER,
    G,
    _inputs,
    _roll,
    _turn_plan,
    truth_airframe,
)
from uavdyn.airframes import Airframe, load_airframe
from uavdyn.emulation.emulator import Emulator
from uavdyn.emulation.missions import REF, survey
from uavdyn.emulation.turbulence import dryden_gusts, gust_span
from uavdyn.flightdata.attitude import body_from_euler

SIDE_NOISE = 0.05  # m/s, the side velocity's noise (like the emulator's u and w noise)


@dataclass
class TurningFlight:
    """One synthetic turning flight: its CSV columns, the turns flown, the true lateral
    inputs fed to the truth (``N x 4``, phi p r beta) and the log rate."""

    columns: dict[str, np.ndarray]
    turns: list[tuple[float, float, float]]      # (start_s, end_s, bank_deg)
    lateral: np.ndarray
    rate_hz: float

    @property
    def duration(self) -> float:
        return float(self.columns["time"][-1] - self.columns["time"][0])

    def bank_time(self, limit_deg: float) -> float:
        """Seconds with the true ``|bank|`` above ``limit_deg``."""
        t = self.columns["time"]
        return float(np.sum(np.abs(np.degrees(self.lateral[:, 0])) > limit_deg)
                     * (t[1] - t[0]))

    def write(self, path: Path) -> Path:
        """The generic six-degree-of-freedom CSV of this flight."""
        data = np.column_stack([self.columns[c] for c in COLUMNS])
        rows = [",".join(COLUMNS)] + [",".join(f"{v:.9g}" for v in row) for row in data]
        path.write_text("\n".join(rows) + "\n")
        return path


def turn_schedule(t: np.ndarray, turns: list[tuple[float, float, float]],
                  speed_ref: np.ndarray) -> np.ndarray:
    """The prescribed ``[phi, p, r, beta]`` (``N x 4``) of the coordinated turns (module
    docstring)."""
    phi = _roll(t, turns)
    psi_dot = G * np.tan(phi) / np.maximum(speed_ref, 1.0)
    p = np.gradient(phi, t)
    return np.column_stack([phi, p, psi_dot * np.cos(phi), np.zeros_like(t)])


def turning_flight(seed: int, duration_s: float = 360.0, rate_hz: float = 50.0,
                   wind_ned: tuple[float, float] = (3.0, -2.0), turbulence: float = 1.0,
                   nominal: Airframe | None = None, noise_scale: float = 1.0
                   ) -> TurningFlight:
    """One synthetic turning flight (module docstring).

    Parameters
    ----------
    seed : int
        Seeds the legs, turns, inputs, turbulence and noise.
    duration_s, rate_hz : float
        Length and log rate (the truth runs ten RK4 steps per log interval).
    wind_ned : tuple of float
        Steady horizontal wind (north, east), m/s.
    turbulence : float
        Dryden intensity multiplier (0: calm).
    nominal : Airframe, optional
        Default the example trainer; the truth is its ``truth_airframe``.
    noise_scale : float
        Sensor noise multiplier (0: noise-free logs).
    """
    rng = np.random.default_rng([412, seed])
    nominal = nominal or load_airframe(str(TRAINER))
    truth = truth_airframe(nominal)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    turns = _turn_plan(rng, duration_s)
    plan = survey(truth, t, rng)
    ref = _inputs(plan.references, t, rng, turns)
    lateral = turn_schedule(t, turns, ref[:, REF["speed_ref"]])
    emulator = Emulator(truth, sample_rate_hz=rate_hz, internal_dt=1.0 / (10 * rate_hz),
                        compiled=False)
    speed = float(np.mean(ref[:, REF["speed_ref"]]))
    gusts = dryden_gusts(rng, n, 1.0 / rate_hz, speed, turbulence, gust_span(truth))
    flown = emulator.fly(emulator.initial_state(plan.x0, plan.u0, plan.altitude), ref, gusts,
                         rng, noise_scale, lateral=lateral)
    u, w, q, theta = flown.measured_states.T
    q_true, theta_true = flown.true_states[:, 2], flown.true_states[:, 3]
    phi, p, r = lateral[:, 0], lateral[:, 1], lateral[:, 2]
    va = np.hypot(flown.true_states[:, 0], flown.true_states[:, 1])
    psi_dot = (q_true * np.sin(phi) + r * np.cos(phi)) / np.cos(theta_true)
    psi = np.concatenate([[0.3], 0.3 + np.cumsum(0.5 * (psi_dot[1:] + psi_dot[:-1])) / rate_hz])
    v = rng.normal(0.0, SIDE_NOISE * noise_scale, n)
    air_ned = np.einsum("nji,nj->ni", body_from_euler(phi, theta, psi),
                        np.column_stack([u, v, w]))
    wind = np.column_stack([np.full(n, wind_ned[0]), np.full(n, wind_ned[1]), np.zeros(n)])
    ground = air_ned + wind
    columns = {"time": t, "roll": phi + rng.normal(0, ROLL_NOISE * noise_scale, n),
               "pitch": theta, "yaw": (psi + np.pi) % (2 * np.pi) - np.pi,
               "p": p + rng.normal(0, RATE_NOISE * noise_scale, n), "q": q,
               "r": r + rng.normal(0, RATE_NOISE * noise_scale, n),
               "vn": ground[:, 0], "ve": ground[:, 1], "vd": ground[:, 2],
               "wind_n": wind[:, 0], "wind_e": wind[:, 1], "wind_d": wind[:, 2],
               "airspeed": va, "altitude_m": flown.aux["h"], "airborne": np.ones(n),
               "elevator": flown.controls[:, 0], "throttle": flown.controls[:, 1]}
    return TurningFlight(columns, turns, lateral, rate_hz)


__all__ = ["ROLL_RATE_DEG_S", "TurningFlight", "turn_schedule", "turning_flight"]
