"""The emulator's autopilot: attitude, speed and altitude loops with scheduled gains."""

from __future__ import annotations

import casadi as ca
import numpy as np

from uavdyn.emulation.truth import air_relative, soft_clip
from uavdyn.model import CONTROL_BOUNDS

# Per-interval reference/gain rows fed to the autopilot (see :func:`autopilot`).
REFERENCE_NAMES = ("ff0", "ff1", "theta_ref", "speed_ref", "h_ref",
                   "K_theta", "K_q", "K_speed", "K_h", "K_hdot")
# The command limits the autopilot saturates at: travel of each control, then its rate
# (per second; 0 = no rate limit). From the airframe's [limits] (:func:`command_limits`).
COMMAND_LIMIT_NAMES = ("low0", "high0", "low1", "high1", "rate0", "rate1")


def command_limits(airframe) -> np.ndarray:
    """``[low0, high0, low1, high1, rate0, rate1]`` of an airframe: the travel of its file's
    ``[limits]`` (else the kind's physical range) and the command rates (0: none set)."""
    bounds = airframe.control_bounds()
    rates = airframe.rate_limits() or (None, None)
    return np.array([bounds[0][0], bounds[0][1], bounds[1][0], bounds[1][1],
                     rates[0] or 0.0, rates[1] or 0.0], float)


def rate_limit(cmd, previous, rates, dt):
    """The command moved at most ``rate * dt`` from the previous one, per channel; a rate of
    0 passes the command unchanged (exactly)."""
    out = []
    for i in range(2):
        step = rates[i] * dt
        limited = previous[i] + ca.fmin(ca.fmax(cmd[i] - previous[i], -step), step)
        out.append(ca.if_else(rates[i] > 0, limited, cmd[i]))
    return ca.vertcat(*out)


def autopilot(kind: str, x, ref, gust, limits=None):
    """Discrete autopilot evaluated once per log interval (the command is then held): pitch
    attitude PD with an outer speed loop and an altitude loop; gains come with the references,
    so a mission can schedule them (all zero = open-loop feed-forward ``ff0, ff1``).
    ``gust`` is ``[u_g, w_g, q_g, W_x, W_z]``: the fixed wing's speed loop uses the pitot
    (air-relative) airspeed, the multirotor's the ground speed (inertial). Each command is
    saturated (smoothly) at the travel in ``limits`` (:data:`COMMAND_LIMIT_NAMES`; None: the
    kind's physical range); the rates are applied by :func:`rate_limit`."""
    u, w, q, theta, h = x[0], x[1], x[2], x[3], x[5]
    ff0, ff1, theta_ref, speed_ref, h_ref, k_th, k_q, k_sp, k_h, k_hd = (
        ref[i] for i in range(len(REFERENCE_NAMES)))
    h_dot = u * ca.sin(theta) - w * ca.cos(theta)
    if kind == "fixed_wing":
        x_air = air_relative(x, gust)
        airspeed = ca.sqrt(x_air[0] ** 2 + x_air[1] ** 2)  # what a pitot tube sees
        theta_cmd = soft_clip(theta_ref + k_h * (h_ref - h) - k_hd * h_dot, -0.6, 1.2, 50.0)
        elevator = ff0 - k_th * (theta_cmd - theta) + k_q * q
        throttle = ff1 + k_sp * (speed_ref - airspeed)
        cmd = ca.vertcat(elevator, throttle)
    else:
        ground_speed = u * ca.cos(theta) + w * ca.sin(theta)
        theta_cmd = soft_clip(theta_ref - k_sp * (speed_ref - ground_speed), -0.6, 0.6, 50.0)
        pitch_cmd = ff1 + k_th * (theta_cmd - theta) - k_q * q
        collective = ff0 + k_h * (h_ref - h) - k_hd * h_dot
        cmd = ca.vertcat(collective, pitch_cmd)
    if limits is None:
        lo = [b[0] for b in CONTROL_BOUNDS[kind]]
        hi = [b[1] for b in CONTROL_BOUNDS[kind]]
    else:
        lo, hi = [limits[0], limits[2]], [limits[1], limits[3]]
    return ca.vertcat(*(soft_clip(cmd[i], lo[i], hi[i]) for i in range(2)))


def open_loop_references(controls: np.ndarray) -> np.ndarray:
    """References that make the autopilot pass ``controls`` (``N x 2``) straight through (all
    gains zero): for comparing the emulator with the baseline model on the same inputs."""
    controls = np.atleast_2d(np.asarray(controls, float))
    ref = np.zeros((controls.shape[0], len(REFERENCE_NAMES)))
    ref[:, :2] = controls
    return ref
