"""The grid of a log whose attitude is logged slower than its gyro (issue 41 item 4).

Some logs record the attitude slowly and the raw gyro faster (ALFA: attitude 2.5 Hz, raw
gyro 10 Hz). Two rules:

* **the grid follows the fastest usable body-rate topic** where it is faster than the
  attitude (:func:`fastest_grid`): the pitch rate is the fastest state of the pitch plane, so
  the grid runs at its topic's rate (a rate within 2 % of a whole number of Hz is taken as
  that number), up to 100 Hz or the attitude's own rate if that is higher; slower topics
  are interpolated (states) or held (commands) onto it, as before. A log whose attitude is
  as fast as its gyro keeps its reader's attitude-rate grid;
* **the attitude between its own samples comes from the gyro** (:func:`gyro_aided_attitude`):
  the Euler-angle rates from the gyro (``phi_dot = p + (q sin phi + r cos phi) tan theta``,
  ``theta_dot = q cos phi - r sin phi``) are integrated from each attitude sample to the next,
  and the small closure error is spread linearly over the interval, so the result passes
  exactly through every logged attitude and between them moves as the gyro says, instead of
  along a straight line that hides everything faster than half the attitude rate.

Where the gyro has a gap inside an attitude interval, that interval keeps the straight line;
where the attitude has a gap, the angles stay NaN (the segmenter cuts there).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uavdyn.flightdata.errors import FlightDataError

WHOLE_HZ_TOLERANCE = 0.02     # a rate within 2 % of a whole number of Hz is that number
PASSES = 3                    # Euler rates re-evaluated at the previous pass's attitude
AUTO_GRID_CAP_HZ = 100.0      # a gyro faster than the attitude sets the grid up to this


@dataclass(frozen=True)
class GridChoice:
    """The grid rate of a log and which topic set it (for the summary and the manifest)."""

    rate_hz: float
    topic: str
    topic_rates_hz: dict[str, float] = field(default_factory=dict)
    reason: str = ""
    gyro_aided: bool = False


def topic_rate(t: np.ndarray) -> float:
    """A topic's rate (Hz): one over its median sample interval (robust to a few gaps)."""
    steps = np.diff(np.asarray(t, float))
    steps = steps[steps > 0]
    return float(1.0 / np.median(steps)) if len(steps) else float("nan")


def _whole(rate: float) -> float:
    """``rate`` as a whole number of Hz when within :data:`WHOLE_HZ_TOLERANCE`."""
    near = round(rate)
    return float(near) if near >= 1 and abs(rate - near) <= WHOLE_HZ_TOLERANCE * rate else \
        float(f"{rate:.4g}")


def fastest_grid(stamps: dict[str, np.ndarray], body_rate_topics: tuple[str, ...],
                 attitude_topic: str, attitude_rate_hz: float | None = None,
                 rate_hz: float | None = None) -> GridChoice:
    """The grid rate: ``rate_hz`` if given; else, where a body-rate topic is faster than the
    attitude topic, the rate of the fastest one (at most ``max(attitude rate,``
    :data:`AUTO_GRID_CAP_HZ` ``)``); else the attitude topic's rate.

    Parameters
    ----------
    stamps : dict of str to ndarray
        Each topic's sample times (s), by the name the summary should show.
    body_rate_topics : tuple of str
        The keys of ``stamps`` that carry body rates (the gyro topics the reader can use).
    attitude_topic : str
        The key of ``stamps`` that carries the attitude.
    attitude_rate_hz : float, optional
        The reader's own rate for a grid that follows the attitude topic (default the
        attitude topic's median rate, a whole number of Hz when within 2 %).
    rate_hz : float, optional
        A stated rate.

    Returns
    -------
    GridChoice
        ``gyro_aided`` says whether the attitude is slower than the grid (the reader then
        fills it with :func:`gyro_aided_attitude`).

    Raises
    ------
    FlightDataError
        If no body-rate topic has two samples.
    """
    rates = {k: round(topic_rate(t), 3) for k, t in stamps.items()}
    usable = [k for k in body_rate_topics if np.isfinite(rates.get(k, np.nan))]
    if not usable:
        raise FlightDataError(f"no body-rate topic with two samples among "
                              f"{', '.join(body_rate_topics)}")
    best = max(usable, key=lambda k: rates[k])
    listed = ", ".join(f"{k} {rates[k]:g} Hz" for k in stamps)
    att = rates[attitude_topic]
    own = float(attitude_rate_hz) if attitude_rate_hz is not None else _whole(att)
    cap = max(att, AUTO_GRID_CAP_HZ)
    faster = min(rates[best], cap)
    if rate_hz is not None:
        rate, topic, why = float(rate_hz), "given", f"{float(rate_hz):g} Hz given"
    elif faster <= att * (1 + WHOLE_HZ_TOLERANCE):
        rate, topic = own, attitude_topic
        why = (f"{own:g} Hz from {attitude_topic}, the attitude ("
               + ("no body-rate topic is faster)" if rates[best] <= att * (1 + WHOLE_HZ_TOLERANCE)
                  else f"already above {AUTO_GRID_CAP_HZ:g} Hz)"))
    else:
        rate, topic = _whole(faster), best
        why = (f"{rate:g} Hz from {best} ({rates[best]:g} Hz), the fastest body-rate topic"
               + (f", capped at {cap:g} Hz (--rate chooses)" if rates[best] > cap else ""))
    aided = rate > att * (1 + WHOLE_HZ_TOLERANCE)
    if aided:
        why += (f"; roll and pitch between the attitude samples ({att:g} Hz) from the "
                "integrated gyro")
    return GridChoice(rate, topic, rates, f"{why} (topics: {listed})", aided)


def euler_rates(roll: np.ndarray, pitch: np.ndarray, p: np.ndarray, q: np.ndarray,
                r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``phi_dot, theta_dot`` from the body rates (the Euler kinematics)."""
    phi_dot = p + (q * np.sin(roll) + r * np.cos(roll)) * np.tan(pitch)
    theta_dot = q * np.cos(roll) - r * np.sin(roll)
    return phi_dot, theta_dot


def _fill(grid: np.ndarray, t_att: np.ndarray, angle: np.ndarray, rate: np.ndarray
          ) -> np.ndarray:
    """``angle`` (sampled at ``t_att``) on the grid: its samples joined by the integral of
    ``rate`` (on the grid), the closure error spread linearly over each interval."""
    ok = np.isfinite(rate)
    step = np.diff(grid)
    increments = 0.5 * (np.where(ok, rate, 0.0)[1:] + np.where(ok, rate, 0.0)[:-1]) * step
    integral = np.concatenate([[0.0], np.cumsum(increments)])
    line = np.interp(grid, t_att, angle)
    k = np.clip(np.searchsorted(t_att, grid, side="right") - 1, 0, len(t_att) - 2)
    a, b = t_att[k], t_att[k + 1]
    at_a, at_b = np.interp(a, grid, integral), np.interp(b, grid, integral)
    share = np.clip((grid - a) / (b - a), 0.0, 1.0)
    out = line + (integral - at_a) - share * (at_b - at_a)
    inside = (grid >= t_att[0]) & (grid <= t_att[-1])
    gyro_gap = np.zeros(len(t_att), bool)   # an attitude interval a gyro gap touches
    bad = ~(ok[1:] & ok[:-1])                # a grid step whose integral lacks a rate
    np.logical_or.at(gyro_gap, k[:-1], bad)
    np.logical_or.at(gyro_gap, k[1:], bad)
    # an interval the grid does not cover whole (at its ends) has no integral to close it
    keep_line = ~inside | gyro_gap[k] | (a < grid[0]) | (b > grid[-1])
    out[keep_line] = line[keep_line]
    return out


def gyro_aided_attitude(grid: np.ndarray, t_att: np.ndarray, roll: np.ndarray,
                        pitch: np.ndarray, p: np.ndarray, q: np.ndarray, r: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch on ``grid`` from slow attitude samples and a faster gyro.

    Parameters
    ----------
    grid : ndarray
        The uniform grid (s).
    t_att : ndarray
        The attitude samples' times (s), increasing, at least two.
    roll, pitch : ndarray
        The attitude samples (rad).
    p, q, r : ndarray
        Body rates on the grid (rad/s; NaN in a gyro gap).

    Returns
    -------
    roll, pitch : ndarray
        On the grid: equal to the samples at their times, moving with the integrated Euler
        rates between them; the straight line where the gyro has a gap in an interval.
        Outside the attitude samples' span, the (held) end values; the caller marks the
        attitude topic's gaps NaN.
    """
    t_att = np.asarray(t_att, float)
    if len(t_att) < 2:
        raise FlightDataError("the attitude topic needs at least two samples")
    roll_u = np.unwrap(np.asarray(roll, float))
    new_roll = np.interp(grid, t_att, roll_u)
    new_pitch = np.interp(grid, t_att, pitch)
    for _ in range(PASSES):   # the Euler rates at the better attitude of the previous pass
        phi_dot, theta_dot = euler_rates(new_roll, new_pitch, p, q, r)
        new_roll = _fill(grid, t_att, roll_u, phi_dot)
        new_pitch = _fill(grid, t_att, np.asarray(pitch, float), theta_dot)
    return (new_roll + np.pi) % (2 * np.pi) - np.pi, new_pitch
