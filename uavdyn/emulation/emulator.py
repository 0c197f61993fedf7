"""Flight-data emulator: a "truth" model flown by an autopilot and logged like a flight log.

The "truth" model is deliberately richer than the baseline model; a simple autopilot flies it
and it is logged like a real flight log (noise-free true states kept beside measured).

The baseline model (:mod:`uavdyn.model`) is reused, not copied: the emulator evaluates the
baseline force functions at the *air-relative* state and with the *actual* actuator positions,
and adds what the baseline lacks. Exactly what differs from the baseline:

Both kinds
    * Wind: a mean wind ``[W_x, W_z]`` in the inertial frame (x forward/north, z down; a head
      wind has ``W_x < 0``, an updraft ``W_z < 0``), held over each log interval and rotated
      into body axes with the *current* pitch angle inside the dynamics
      (:func:`wind_in_body`), plus Dryden turbulence ``[u_g, w_g, q_g]`` in body axes as the
      MIL spec defines it (MIL-F-8785C forms with Beard & McLain's low-altitude scales,
      intensity multiplier settable, 0 = calm; the pitch-rate gust filtered with the airframe's
      span, :func:`dryden_gusts`). Both enter through the air-relative velocity
      ``u - u_w - u_g, w - w_w - w_g, q - q_g`` at which the aerodynamics, the propulsion and
      the autopilot's pitot tube are evaluated; the kinematics use the inertial velocities.
    * Actuator dynamics: each commanded input passes a smooth position limit, then a
      first-order lag whose rate is smoothly limited (``rate * tanh(error / (tau * rate))``).
      The lags and rates are the airframe file's own where it sets them (``tau_elevator``,
      ``tau_throttle``, ``tau_rotor``, ``[limits]`` ``<control>_rate``:
      :func:`airframe_truth`), the defaults below otherwise; ``Emulator.truth_sources`` says
      which.
    * Commands: the autopilot saturates each command at the travel of the file's ``[limits]``
      (else the kind's physical range), smoothly, and at its ``[limits]`` rate (a hard limit
      per log interval; none where the file sets none), so the logged commands never leave
      them.
    * Sensor noise: Gaussian white noise on every logged state and a constant gyro bias per
      sortie; the logged controls are the commands (exact, zero-order hold per log interval).
    * What is logged (``true_states`` and ``measured_states``, the interchange format's
      ``u, w, q, theta``): the **air-relative** body velocities ``u, w`` (inertial minus wind
      minus gust, what the aerodynamics see; SPEC section 3) and the **inertial** pitch rate and
      attitude ``q, theta`` (gyro, attitude), so ``d theta/dt = q`` holds in the log. The
      inertial (ground-relative) velocities stay in ``aux["emulator_states"][:, :2]``. In calm
      air the two coincide bit for bit.
    * Logging at ``sample_rate_hz`` (100 Hz default); integration by RK4 at ``internal_dt``
      (1 ms default) inside one compiled ``mapaccum`` rollout.

Fixed wing (extra states: elevator, throttle, alpha filter, separation)
    * Elevator servo lag 0.04 s, rate limit 3 rad/s; throttle (engine/propeller spool) lag
      0.25 s, rate limit 2 /s (defaults; the file's lags and rates replace them).
    * Unsteady aerodynamics: ``C_L_alphadot`` and ``C_m_alphadot`` terms, with alpha-dot taken
      from a first-order filtered derivative of the air-relative alpha (filter state). They add
      to the airframe's own optional ``C_L_alpha_dot``/``C_m_alpha_dot`` (0 in the presets),
      which the emulator applies with the same filtered air-relative alpha-dot (gusts included)
      instead of the baseline's gust-blind closed form.
    * Dynamic stall: the baseline's static stall blend ``sigma(alpha)`` becomes a lagged flow-
      separation state (Goman-Khrabrov form) ``tau1 sigma_dot = sigma_static(alpha - tau2
      alpha_dot) - sigma`` (stall hysteresis), and a nose-down pitch break ``C_m_stall sigma``.
      In steady attached flow all extra terms vanish, so baseline trim points are also trim
      points of the calm emulator.

Multirotor (extra states: front and rear rotor speeds, in throttle units)
    * Mixer saturation: each rotor pair's throttle ``collective +- pitch_mix * pitch_cmd`` is
      limited to [0, 1] (the baseline does not limit the mix).
    * Motor spin-up: first-order lag 0.04 s up / 0.08 s down (no active braking), rate
      limited (a file's ``tau_rotor`` replaces the spin-up lag, spin-down keeps the ratio).
    * Airspeed-dependent rotors: axial-inflow thrust change (less thrust in climb), effective
      translational lift in forward flight, rotor drag proportional to rotor speed (replacing
      the baseline's constant ``drag_linear``), and a blade-flapping pitch moment
      proportional to rotor speed times forward airspeed.

All extra numbers are engineering estimates (marked as such in :data:`TRUTH_DEFAULTS`); they
are chosen to be plausible for the preset airframe classes, not identified from data.

Where the parts live: the truth dynamics in :mod:`uavdyn.emulation.truth`, the autopilot in
:mod:`uavdyn.emulation.autopilot`, the Dryden turbulence in :mod:`uavdyn.emulation.turbulence`;
this module flies sorties (:class:`Emulator`) and re-exports their names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cache

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.emulation.autopilot import (
    COMMAND_LIMIT_NAMES,
    REFERENCE_NAMES,
    autopilot,
    command_limits,
    open_loop_references,
    rate_limit,
)
from uavdyn.emulation.truth import (
    AUX_NAMES,
    BODY_STATE_NAMES,
    EXTRA_STATE_NAMES,
    GUST_NAMES,
    SATURATION_SHARPNESS,
    TRUTH_DEFAULTS,
    WIND_NAMES,
    air_relative,
    airframe_truth,
    emulator_aux,
    emulator_rhs,
    rate_limited_lag,
    soft_clip,
    truth_param_names,
    wind_in_body,
)
from uavdyn.emulation.truth import _emulator_expressions as _emulator_expressions
from uavdyn.emulation.truth import _fixed_wing_rates as _fixed_wing_rates
from uavdyn.emulation.truth import _multirotor_rates as _multirotor_rates
from uavdyn.emulation.truth import _with_param as _with_param
from uavdyn.emulation.turbulence import (
    MULTIROTOR_PROP_DIAMETER_M,
    dryden_filter,
    dryden_gusts,
    gust_span,
)
from uavdyn.integrate import compile_function, rk4_step
from uavdyn.model import NUMPY_OPS, stall_blend

__all__ = ["AUX_NAMES", "BODY_STATE_NAMES", "COMMAND_LIMIT_NAMES", "EXTRA_STATE_NAMES",
           "GUST_NAMES", "MULTIROTOR_PROP_DIAMETER_M", "REFERENCE_NAMES",
           "SATURATION_SHARPNESS", "TRUTH_DEFAULTS", "WIND_NAMES", "EmulatedFlight", "Emulator",
           "SensorNoise", "air_relative", "airframe_truth", "autopilot", "command_limits",
           "dryden_filter", "dryden_gusts", "emulator_aux", "emulator_rhs", "emulator_rollout",
           "gust_span", "log_interval_step", "open_loop_references", "rate_limit",
           "rate_limited_lag", "soft_clip", "truth_param_names", "wind_in_body"]


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the white measurement noise and of the per-sortie gyro bias."""

    u: float = 0.05       # m/s (EKF velocity estimate)
    w: float = 0.05       # m/s
    q: float = 0.005      # rad/s (filtered gyro)
    theta: float = 0.002  # rad (~0.1 deg)
    gyro_bias: float = 0.002  # rad/s

    def scaled(self, factor: float) -> SensorNoise:
        """All standard deviations times ``factor`` (0 gives noise-free logs)."""
        return SensorNoise(self.u * factor, self.w * factor, self.q * factor,
                           self.theta * factor, self.gyro_bias * factor)


@cache
def log_interval_step(kind: str, substeps: int, lateral: bool = False) -> ca.Function:
    """One log interval: autopilot command (held), then ``substeps`` RK4 steps of the emulator.
    Signature ``(z=[x; pe; dt_log; limits; cmd_prev], r=[ref; gust; wind]) -> (z_next, cmd,
    aux)`` for ``mapaccum``: the command is saturated at the travel and rate ``limits``
    (:data:`COMMAND_LIMIT_NAMES`) from the previous command ``cmd_prev`` (which ``z_next``
    carries on); gust and inertial wind are held over the interval, the wind's body
    components follow the pitch inside every RK4 stage. ``lateral``: ``r`` ends with the
    prescribed ``[phi, p, r, beta]`` held over the interval, and ``pe`` with ``[Jx, Jz, Jxz]``
    (turning flight, :func:`uavdyn.emulation.truth.emulator_rhs`)."""
    f = emulator_rhs(kind, with_wind=True, lateral=lateral)
    step = rk4_step(f, "emulator_rk4")
    nx, n_pe, n_lim = f.size1_in(0), f.size1_in(2), len(COMMAND_LIMIT_NAMES)
    n_d = len(GUST_NAMES) + len(WIND_NAMES)
    z = ca.SX.sym("z", nx + n_pe + 1 + n_lim + 2)
    r = ca.SX.sym("r", len(REFERENCE_NAMES) + n_d + (4 if lateral else 0))
    x, pe, dt_log = z[:nx], z[nx:nx + n_pe], z[nx + n_pe]
    limits, previous = z[nx + n_pe + 1:nx + n_pe + 1 + n_lim], z[nx + n_pe + 1 + n_lim:]
    disturbance = r[len(REFERENCE_NAMES):len(REFERENCE_NAMES) + n_d]
    cmd = autopilot(kind, x, r[:len(REFERENCE_NAMES)], disturbance, limits)
    cmd = rate_limit(cmd, previous, limits[4:], dt_log)
    v = ca.vertcat(cmd, r[len(REFERENCE_NAMES):])
    aux = emulator_aux(kind, with_wind=True, lateral=lateral)(x, v, pe)
    h = dt_log / substeps
    xk = x
    for _ in range(substeps):
        xk = step(xk, v, pe, h)
    return ca.Function("emulator_interval", [z, r],
                       [ca.vertcat(xk, pe, dt_log, limits, cmd), cmd, aux],
                       ["z", "r"], ["z_next", "cmd", "aux"])


@cache
def emulator_rollout(kind: str, n_intervals: int, substeps: int, compiled: bool = True,
                     lateral: bool = False) -> ca.Function:
    """ONE Function for a whole sortie: ``(x0, pe, dt_log, R[15 x N], limits[6], cmd0[2]) ->
    (X[nx x N+1], CMD[2 x N], AUX[4 x N])`` built with ``mapaccum`` (a loop in the generated
    C) and compiled (cached on disk by content hash). ``limits`` are the autopilot's command
    limits (:data:`COMMAND_LIMIT_NAMES`), ``cmd0`` the command before the first interval
    (where the rate limit starts from)."""
    body = log_interval_step(kind, substeps, lateral)
    nx = 6 + len(EXTRA_STATE_NAMES[kind])
    n_lim = len(COMMAND_LIMIT_NAMES)
    n_pe = body.size1_in(0) - nx - 1 - n_lim - 2
    acc = body.mapaccum("emulator_acc", n_intervals)
    x0, pe, dt = ca.MX.sym("x0", nx), ca.MX.sym("pe", n_pe), ca.MX.sym("dt")
    limits, cmd0 = ca.MX.sym("limits", n_lim), ca.MX.sym("cmd0", 2)
    R = ca.MX.sym("R", body.size1_in(1), n_intervals)
    Z, CMD, AUX = acc(ca.vertcat(x0, pe, dt, limits, cmd0), R)
    X = ca.horzcat(x0, Z[:nx, :])
    func = ca.Function(f"emulator_{kind}_{n_intervals}_{substeps}"
                       + ("_lateral" if lateral else ""),
                       [x0, pe, dt, R, limits, cmd0], [X, CMD, AUX],
                       ["x0", "pe", "dt", "R", "limits", "cmd0"], ["X", "cmd", "aux"])
    return compile_function(func) if compiled else func


@dataclass
class EmulatedFlight:
    """What one emulated sortie produced: true and measured states at the log rate, commanded
    controls (held over each interval), the disturbances, and auxiliary truth (air-relative
    alpha, airspeed, actuator positions, position, the full inertial emulator state).

    ``true_states`` and ``measured_states`` are ``[u, w, q, theta]`` with **air-relative**
    ``u, w`` (inertial minus wind minus gust, body axes) and **inertial** ``q, theta``; the
    inertial body velocities are ``aux["emulator_states"][:, :2]``. ``gusts`` (``N x 3``, body
    axes) and ``wind`` (``N x 2``, inertial ``[W_x, W_z]``) are the values held over each log
    interval."""

    time: np.ndarray
    true_states: np.ndarray
    measured_states: np.ndarray
    controls: np.ndarray
    gusts: np.ndarray
    aux: dict = field(default_factory=dict)
    wind: np.ndarray | None = None

    @property
    def alpha_air(self) -> np.ndarray:
        """Air-relative angle of attack (rad) at each log time (what the wing sees)."""
        return self.aux["alpha_air"]


class Emulator:
    """The truth model of one airframe. Build once, fly many sorties (the compiled rollout is
    cached per sortie length)."""

    def __init__(self, airframe: Airframe, truth: dict[str, float] | None = None,
                 sample_rate_hz: float = 100.0, internal_dt: float = 1e-3,
                 noise: SensorNoise | None = None, compiled: bool = True) -> None:
        if not (sample_rate_hz > 0) or not (internal_dt > 0):
            raise ValueError("sample_rate_hz and internal_dt must be positive")
        substeps = round(1.0 / (sample_rate_hz * internal_dt))
        if substeps < 1 or abs(substeps * internal_dt * sample_rate_hz - 1) > 1e-9:
            raise ValueError(f"internal_dt {internal_dt} s must divide the log interval "
                             f"{1 / sample_rate_hz} s")
        if airframe.kind == "multirotor" and airframe.params.pitch_mix <= 0:
            raise ValueError("the multirotor emulator needs pitch_mix > 0")
        values = dict(TRUTH_DEFAULTS[airframe.kind])
        unknown = set(truth or {}) - set(values)
        if unknown:
            raise ValueError(f"unknown truth parameter(s) {sorted(unknown)} for "
                             f"{airframe.kind}; expected {sorted(values)}")
        own = airframe_truth(airframe)
        values.update(own)
        values.update({k: float(v) for k, v in (truth or {}).items()})
        self.airframe = airframe
        self.kind = airframe.kind
        self.truth = values
        # where each truth value comes from: given here, the airframe file, or the default
        self.truth_sources = {k: "given" if k in (truth or {}) else "airframe file"
                              if k in own else "emulator default" for k in values}
        # the autopilot's command saturation: the file's [limits] travel and rates
        self.command_limits = command_limits(airframe)
        self.sample_rate_hz = float(sample_rate_hz)
        self.internal_dt = float(internal_dt)
        self.substeps = int(substeps)
        self.noise = noise if noise is not None else SensorNoise()
        self.compiled = compiled

    @property
    def dt_log(self) -> float:
        """Log interval (s): the autopilot's and the log's sample time."""
        return 1.0 / self.sample_rate_hz

    @property
    def pe(self) -> np.ndarray:
        """Baseline parameters followed by the truth extras (the emulator's ``p``)."""
        return np.concatenate([self.airframe.p, [self.truth[k] for k in
                                                 truth_param_names(self.kind)]])

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the emulator's full state (body states, position, extra states)."""
        return BODY_STATE_NAMES + EXTRA_STATE_NAMES[self.kind]

    def initial_state(self, x: np.ndarray, u: np.ndarray, altitude: float,
                      wind: np.ndarray | None = None) -> np.ndarray:
        """Full emulator state from a baseline state ``[u, w, q, theta]`` and controls (e.g. a
        trim point): actuators at the controls, filters at their steady values.

        Without ``wind`` the velocities of ``x`` become the inertial ones (calm air: the same).
        With an inertial ``wind = [W_x, W_z]`` they are taken as air-relative: the state starts
        in equilibrium with the moving air mass (e.g. a trim point flown in a steady wind), its
        inertial velocity being ``x[:2]`` plus the wind rotated into body axes."""
        x = np.asarray(x, float)
        body = x[:4].copy()
        if wind is not None:
            wind = np.asarray(wind, float).reshape(-1)
            if wind.shape != (len(WIND_NAMES),) or not np.all(np.isfinite(wind)):
                raise ValueError(f"wind must be finite [W_x, W_z], got {wind}")
            u_w, w_w = wind_in_body(x[3], wind[0], wind[1], NUMPY_OPS)
            body[0], body[1] = x[0] + u_w, x[1] + w_w
        if self.kind == "fixed_wing":
            P = self.airframe.params
            alpha = math.atan2(x[1], x[0])
            sigma = float(stall_blend(alpha, P.M_blend, P.alpha0))
            extra = [u[0], u[1], alpha, sigma]
        else:
            mix = self.airframe.params.pitch_mix
            extra = [u[0] + mix * u[1], u[0] - mix * u[1]]
        return np.concatenate([body, [0.0, altitude], extra])

    def actuator_command(self, x0: np.ndarray) -> np.ndarray:
        """The command that holds the actuators of the full emulator state ``x0`` where they
        are (the previous command the autopilot's rate limit starts from)."""
        extra = np.asarray(x0, float)[6:8]
        if self.kind == "fixed_wing":
            return extra.copy()
        mix = self.airframe.params.pitch_mix
        return np.array([0.5 * (extra[0] + extra[1]), (extra[0] - extra[1]) / (2 * mix)])

    def fly(self, x0: np.ndarray, references: np.ndarray, gusts: np.ndarray | None = None,
            rng: np.random.Generator | None = None, noise_scale: float = 1.0, *,
            wind: np.ndarray | None = None, lateral: np.ndarray | None = None
            ) -> EmulatedFlight:
        """Fly one sortie. ``references`` is ``N x 10`` (:data:`REFERENCE_NAMES`, row k held over
        log interval k); ``gusts`` ``N x 3`` body-axis turbulence or None (none); ``wind`` the
        inertial mean wind ``[W_x, W_z]`` (m/s, x forward/north, z down: a head wind of 5 m/s
        is ``[-5, 0]``), constant or ``N x 2`` (row k held over interval k), or None (calm).
        ``x0`` is the full inertial emulator state (:meth:`initial_state`). Logged: N rows at
        t_k = k dt_log, states at t_k (``u, w`` air-relative, ``q, theta`` inertial) and the
        command held over [t_k, t_k+1). Noise needs ``rng``.

        ``lateral`` (``N x 4``, row k held over interval k): the prescribed bank angle, roll
        and yaw rates and sideslip ``[phi, p, r, beta]`` of turning flight, which the truth's
        longitudinal equations then feel (the bank/turn-rate terms of
        :mod:`uavdyn.model.equations`, with the airframe's ``Jx, Jz, Jxz``); the lateral motion
        itself is given, not simulated (no coupling back: not a full 6-DoF simulator)."""
        references = np.atleast_2d(np.asarray(references, float))
        n = references.shape[0]
        if references.shape[1] != len(REFERENCE_NAMES):
            raise ValueError(f"references must be N x {len(REFERENCE_NAMES)}, got "
                             f"{references.shape}")
        gusts = np.zeros((n, 3)) if gusts is None else np.asarray(gusts, float)
        if gusts.shape != (n, 3):
            raise ValueError(f"gusts must be {n} x 3, got {gusts.shape}")
        if wind is None:
            wind = np.zeros((n, len(WIND_NAMES)))
        else:
            wind = np.asarray(wind, float)
            if wind.shape == (len(WIND_NAMES),):
                wind = np.tile(wind, (n, 1))
            if wind.shape != (n, len(WIND_NAMES)):
                raise ValueError(f"wind must be [W_x, W_z] or {n} x 2, got {wind.shape}")
        if not (np.all(np.isfinite(gusts)) and np.all(np.isfinite(wind))):
            raise ValueError("gusts and wind must be finite")
        pe, blocks = self.pe, [references, gusts, wind]
        if lateral is not None:
            lateral = np.asarray(lateral, float)
            if lateral.shape != (n, 4) or not np.all(np.isfinite(lateral)):
                raise ValueError(f"lateral must be finite {n} x 4 [phi, p, r, beta], got "
                                 f"{lateral.shape}")
            P = self.airframe.params
            pe = np.concatenate([pe, [P.Jx, P.Jz, P.Jxz]])
            blocks.append(lateral)
        func = emulator_rollout(self.kind, n, self.substeps, self.compiled,
                                lateral is not None)
        R = np.hstack(blocks).T
        x0 = np.asarray(x0, float)
        X, CMD, AUX = func(x0, pe, self.dt_log, R, self.command_limits,
                           self.actuator_command(x0))
        X, CMD, AUX = np.asarray(X).T[:n], np.asarray(CMD).T, np.asarray(AUX).T
        # Logged velocities are air-relative (what the aerodynamics see), at the same instant
        # and with the same held gust and wind as the interval's aerodynamics.
        u_w, w_w = wind_in_body(X[:, 3], wind[:, 0], wind[:, 1], NUMPY_OPS)
        true = X[:, :4].copy()
        true[:, 0] = X[:, 0] - u_w - gusts[:, 0]
        true[:, 1] = X[:, 1] - w_w - gusts[:, 1]
        measured = true.copy()
        if noise_scale > 0 and rng is not None:
            ns = self.noise.scaled(noise_scale)
            sig = np.array([ns.u, ns.w, ns.q, ns.theta])
            measured = true + rng.standard_normal(true.shape) * sig
            measured[:, 2] += ns.gyro_bias * rng.standard_normal()
        time = np.arange(n) * self.dt_log
        aux = {name: AUX[:, i] for i, name in enumerate(AUX_NAMES)}
        aux["x_n"], aux["h"] = X[:, 4], X[:, 5]
        aux["emulator_states"] = X
        return EmulatedFlight(time=time, true_states=true, measured_states=measured,
                              controls=CMD, gusts=gusts, aux=aux, wind=wind)
