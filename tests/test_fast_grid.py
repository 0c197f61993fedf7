"""The grid of a log whose attitude is slower than its gyro (issue 41 item 4): the rate from
the fastest body-rate topic, and the attitude between its samples from the integrated gyro,
checked against analytic angles and on the shipped ALFA flight (attitude 2.5 Hz, gyro 10 Hz).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.reallogs import alfa_folder
from uavdyn.flightdata import FlightDataError, read_alfa_flight
from uavdyn.flightdata.attitude import pitch_from_quaternion
from uavdyn.flightdata.fast_grid import fastest_grid, gyro_aided_attitude, topic_rate

PSI_DOT = 0.2   # rad/s, a steady turn rate under the oscillations


def _angles(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll with a 1.7 Hz and pitch with a 1.5 Hz component: both above the 1.25 Hz Nyquist
    frequency of a 2.5 Hz attitude topic, so a straight line between its samples misses them."""
    return (0.4 * np.sin(0.5 * t) + 0.1 * np.sin(2 * np.pi * 1.7 * t),
            0.05 + 0.08 * np.sin(2 * np.pi * 1.5 * t))


def _body_rates(t: np.ndarray, h: float = 1e-6) -> tuple[np.ndarray, ...]:
    """Exact body rates of :func:`_angles` with yaw rate PSI_DOT (inverse Euler kinematics)."""
    phi, theta = _angles(t)
    phi_dot = (_angles(t + h)[0] - _angles(t - h)[0]) / (2 * h)
    theta_dot = (_angles(t + h)[1] - _angles(t - h)[1]) / (2 * h)
    p = phi_dot - PSI_DOT * np.sin(theta)
    q = theta_dot * np.cos(phi) + PSI_DOT * np.cos(theta) * np.sin(phi)
    r = -theta_dot * np.sin(phi) + PSI_DOT * np.cos(theta) * np.cos(phi)
    return p, q, r


@pytest.mark.parametrize("gyro_hz, pitch_tol, roll_tol", [(10.0, 0.012, 0.025),
                                                          (100.0, 2e-4, 3e-4)])
def test_gyro_aided_attitude_follows_the_analytic_angles_between_slow_samples(
        gyro_hz, pitch_tol, roll_tol):
    t_att = np.arange(0.13, 30.0, 0.4)                  # 2.5 Hz attitude
    grid = np.arange(1.0, 29.0, 1 / gyro_hz)
    phi_s, theta_s = _angles(t_att)
    roll, pitch = gyro_aided_attitude(grid, t_att, phi_s, theta_s, *_body_rates(grid))
    phi, theta = _angles(grid)
    inner = (grid >= t_att[t_att >= grid[0]][0]) & (grid <= t_att[t_att <= grid[-1]][-1])
    assert np.max(np.abs(pitch - theta)[inner]) < pitch_tol
    assert np.max(np.abs(roll - phi)[inner]) < roll_tol
    line = np.interp(grid, t_att, theta_s)
    assert np.max(np.abs(line - theta)[inner]) > 0.09   # what a straight line gives
    at = np.isin(np.round(grid, 9), np.round(t_att, 9))  # exactly the samples at their times
    np.testing.assert_allclose(pitch[at], np.interp(grid[at], t_att, theta_s), atol=1e-12)


def test_a_gyro_gap_keeps_the_straight_line_in_its_interval():
    t_att = np.arange(0.0, 10.0, 0.4)
    grid = np.arange(0.0, 9.6, 0.1)
    p, q, r = _body_rates(grid)
    q[40:43] = np.nan
    _, pitch = gyro_aided_attitude(grid, t_att, *_angles(t_att), p, q, r)
    gap = (grid >= 3.6) & (grid <= 4.4)      # the attitude intervals holding the gap
    np.testing.assert_allclose(pitch[gap], np.interp(grid[gap], t_att, _angles(t_att)[1]))
    assert np.all(np.isfinite(pitch))


def test_the_grid_follows_the_fastest_body_rate_topic_only_where_it_beats_the_attitude():
    stamps = {"attitude": np.arange(0, 10, 0.4), "gyro": np.arange(0, 10, 1 / 10.06),
              "airspeed": np.arange(0, 10, 1 / 19.4)}
    choice = fastest_grid(stamps, ("gyro",), "attitude")
    assert choice.rate_hz == 10.0 and choice.topic == "gyro" and choice.gyro_aided
    assert "10 Hz from gyro (10.06 Hz)" in choice.reason and "attitude 2.5 Hz" in choice.reason
    given = fastest_grid(stamps, ("gyro",), "attitude", rate_hz=5.0)
    assert given.rate_hz == 5.0 and given.gyro_aided
    # an attitude as fast as the gyro keeps the reader's own attitude-rate grid
    fast = {"attitude": np.arange(0, 10, 0.01), "gyro": np.arange(0, 10, 0.01)}
    same = fastest_grid(fast, ("gyro",), "attitude", attitude_rate_hz=100.0)
    assert (same.rate_hz, same.topic, same.gyro_aided) == (100.0, "attitude", False)
    # a 1 kHz gyro over a 20 Hz attitude: the grid is capped at 100 Hz, and says so
    capped = fastest_grid({"attitude": np.arange(0, 2, 0.05), "gyro": np.arange(0, 2, 1e-3)},
                          ("gyro",), "attitude")
    assert capped.rate_hz == 100.0 and "capped at 100 Hz" in capped.reason
    assert topic_rate(np.arange(0, 1, 0.02)) == pytest.approx(50.0)
    with pytest.raises(FlightDataError, match="no body-rate topic"):
        fastest_grid(stamps, ("imu",), "attitude")


def test_alfa_grid_from_the_raw_gyro_and_its_attitude_through_every_sample():
    flight = read_alfa_flight(alfa_folder())
    assert flight.dt == pytest.approx(0.1)
    grid = flight.meta["grid"]
    assert grid.startswith("10 Hz from mavros-imu-data_raw (10.06")
    assert "mavros-imu-data 2.47" in grid and "from the integrated gyro" in grid
    rates = flight.meta["topic_rates_hz"]
    assert rates["mavros-imu-data_raw"] > 4 * rates["mavros-imu-data"]
    # the attitude samples, each at its own time, are kept: the grid pitch interpolated at
    # the sample times is within the change of one 0.1 s grid step of the sample
    import csv

    path = next(alfa_folder().glob("*-mavros-imu-data.csv"))
    rows = list(csv.DictReader(path.open()))
    quats = np.array([[float(r[f"field.orientation.{c}"]) for c in "wxyz"] for r in rows])
    t = (np.array([int(r["%time"]) for r in rows]) * 1e-9
         - float(flight.meta["start_time_s"]))
    inside = (t > 0.2) & (t < flight.time[-1] - 0.2)
    at = np.interp(t[inside], flight.time, flight.channels["pitch"])
    step = np.nanmax(np.abs(np.diff(flight.channels["pitch"])))
    assert np.nanmax(np.abs(at - (-pitch_from_quaternion(quats))[inside])) < step


def test_px4_log_with_a_slow_attitude_gets_the_gyro_grid_and_the_analytic_pitch(tmp_path):
    """A synthetic ULog (tests/ulog_writer.py) with vehicle_attitude at 5 Hz and
    vehicle_angular_velocity at 100 Hz, banked 0.3 rad and turning: the grid is 100 Hz and
    the pitch between the attitude samples is the analytic one."""
    from tests.test_ulog_synthetic import (
        RATE_HZ,
        actuator_controls,
        control_stamps,
        seconds,
        stamps,
        state_topics,
        theta_true,
        write_log,
    )
    from uavdyn.flightdata.ulog_flight import read_ulog_flight

    fast = state_topics(stamps(401, RATE_HZ), yaw_rate=0.2, roll=0.3)
    slow = state_topics(stamps(21, 5.0), yaw_rate=0.2, roll=0.3)
    topics = {**fast, "vehicle_attitude": slow["vehicle_attitude"],
              **actuator_controls(control_stamps())}
    flight = read_ulog_flight(write_log(tmp_path / "slow_att.ulg", topics))
    assert flight.dt == pytest.approx(0.01)
    assert flight.meta["grid"].startswith("100 Hz from vehicle_angular_velocity")
    t = flight.time + seconds(stamps(1, RATE_HZ))[0]
    t_att = seconds(slow["vehicle_attitude"]["timestamp"])
    inner = (t >= t_att[1]) & (t <= t_att[-2])
    truth = theta_true(t)
    assert np.max(np.abs(flight.channels["pitch"] - truth)[inner]) < 2e-3
    line = np.interp(t, t_att, theta_true(t_att))
    assert np.max(np.abs(line - truth)[inner]) > 0.01     # what the old grid would give
    np.testing.assert_allclose(flight.channels["roll"][inner], 0.3, atol=2e-3)
