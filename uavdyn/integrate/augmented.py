"""The discrete step of a model with actuator dynamics: first-order lags and integer transport
delays carried as augmented states, written once against ``ops`` (CasADi, NumPy, torch).

One call advances one sample: the delayed command is read from the buffer (or is the command
itself), each lagged channel follows it exactly (``a(s) = c + (a0 - c) exp(-s/tau)``, stable and
exact for any step, however fast the actuator; a rate-limited one by the exact solution of
its slewing lag, :func:`slew_toward`), and the rigid body is integrated by the RK
tableau with the actuator value taken at each stage's time (a clock rides along as an extra RK
state). A delay of ``k`` samples means a command acts ``k`` calls later: the delay counts calls
of the step, so use the step at the sample period the delays were identified at.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.integrate.tableau import RK4, ButcherTableau, explicit_rk_step
from uavdyn.model import (
    CASADI_OPS,
    NUMPY_OPS,
    ModelStructure,
    build_model,
    make_rhs,
    structure_of,
)

STEP_INPUTS = ["x", "u", "p", "dt"]
TAU_FLOOR = 1e-300  # s; a time constant of 0 is an instant jump, never 0/0 at a stage time 0
SLEW_FLOOR = 1e-12  # s per unit; a slew time of 0 (no rate limit) is the plain lag to round-off
# s; inside a rate-limited lag a time constant below this is this: at TAU_FLOOR the pure rate
# limiter's derivatives were inf * 0 = NaN (identify could not fit a slew time with the lag
# kept at 0); 1 us is far below any log interval
SLEW_TAU_FLOOR = 1e-6
LOG_2 = math.log(2.0)


def _rows(z, start: int, stop: int):
    """Feature rows ``start:stop`` of a feature-first array (an empty list if none)."""
    return [z[i] for i in range(start, stop)]


def _shift_buffers(structure: ModelStructure, buffers: list, u) -> tuple[list, list]:
    """The command each control acts on this call (the oldest buffered one, or ``u`` itself
    without a delay) and the buffers after the call (``u`` in front, the oldest dropped)."""
    delayed, new_buffers, offset = [], [], 0
    for c, d in enumerate(structure.delay_samples):
        if d:
            delayed.append(buffers[offset + d - 1])
            new_buffers += [u[c], *buffers[offset:offset + d - 1]]
            offset += d
        else:
            delayed.append(u[c])
    return delayed, new_buffers


def lag_toward(value, command, decay):
    """The exact first-order lag over an interval with the command held: ``value`` moves to
    ``command`` by the factor ``decay = exp(-interval / tau)`` (any ``ops`` type). The one
    formula of every lag: actuators, command memory, identification's pre-roll."""
    return command + (value - command) * decay


def slew_toward(value, command, elapsed, tau, slew, ops):
    """The actuator ``elapsed`` seconds on, following ``command`` held, by the exact solution of
    the rate-limited lag ``a' = tanh(slew (command - a) / tau) / slew`` (slope ``1/tau`` for a
    small error, the rate limit ``1/slew`` for a large one; the emulator's actuator model):
    with ``y = slew (command - a) / tau``, ``sinh(y(t)) = sinh(y(0)) exp(-t/tau)``.

    Odd and smooth in the error (its derivative at zero error is the lag's ``exp(-t/tau)``, so
    trims linearise as with the plain lag); a slew of 0 is the plain lag (:data:`SLEW_FLOOR`); a
    time constant of 0 is a pure rate limiter (to :data:`SLEW_TAU_FLOOR`). Large ``|y|`` are
    computed in the log domain (no overflow), and each ``if_else`` branch stays finite for
    every input (no NaN in derivatives)."""
    tau = ops.fmax(tau, SLEW_TAU_FLOOR)
    slew = ops.fmax(slew, SLEW_FLOOR)
    y0 = slew * (command - value) / tau
    log_decay = -elapsed / tau
    small = ops.asinh(ops.sinh(ops.fmin(ops.fmax(y0, -1.0), 1.0)) * ops.exp(log_decay))
    m = ops.fmax(ops.fabs(y0), 1.0)  # |y0| >= 1: log(sinh(m) exp(-t/tau)) without overflow
    log_sinh = m + ops.log1p(-ops.exp(-2.0 * m)) - LOG_2 + log_decay
    below, above = ops.fmin(log_sinh, 0.0), ops.fmax(log_sinh, 0.0)
    large = ops.sign(y0) * ops.if_else(
        log_sinh < 0, ops.asinh(ops.exp(below)),
        above + ops.log1p(ops.sqrt(1.0 + ops.exp(-2.0 * above))))
    y = ops.if_else(ops.fabs(y0) < 1.0, small, large)
    return command - tau / slew * y


def actuators_after(structure: ModelStructure, a0: list, commands: list, p, elapsed, ops
                    ) -> list:
    """Each actuator ``elapsed`` seconds on from ``a0``, following its (delayed) command held:
    the exact lag, or the exact rate-limited lag of a slewed control (:func:`slew_toward`); a
    time constant at 0 (a lag about to be fitted) jumps: ``exp(-s/0+) = 0``."""
    out = []
    for a, c, i, k in zip(a0, structure.lag_indices, structure.tau_indices,
                          structure.slew_indices):
        if k is None:
            out.append(lag_toward(a, commands[c], ops.exp(-elapsed / ops.fmax(p[i], TAU_FLOOR))))
        else:
            out.append(slew_toward(a, commands[c], elapsed, p[i], p[k], ops))
    return out


def effective_controls(structure: ModelStructure, z, u, ops=CASADI_OPS):
    """The actuator-side controls at the start of a step of the augmented state ``z``: each
    lagged control's actuator state, else the command acting this call (the oldest buffered
    one under a delay, or ``u`` itself)."""
    buffer_start = 4 + structure.n_actuator
    delayed, _ = _shift_buffers(structure, _rows(z, buffer_start,
                                                 buffer_start + structure.n_buffer), u)
    out = list(delayed)
    for j, c in enumerate(structure.lag_indices):
        out[c] = z[4 + j]
    return ops.stack(*out)


def augmented_rk_step(structure: ModelStructure, body_rhs: Callable, z, u, p, dt,
                      tableau: ButcherTableau = RK4, ops=CASADI_OPS,
                      with_position: bool = False, substeps: int = 1):
    """``z_next`` of the augmented state ``z`` (layout: :mod:`uavdyn.model.structure`) under the
    command ``u`` held over the step ``dt`` (``substeps`` RK steps of ``dt/substeps`` for the
    body; the lag is exact over the whole step).

    ``body_rhs(x, u_effective, p)`` is the rigid body's right-hand side (e.g. the physics plus a
    learned residual)."""
    nb = 6 if with_position else 4
    buffer_start = nb + structure.n_actuator
    delayed, new_buffer = _shift_buffers(
        structure, _rows(z, buffer_start, buffer_start + structure.n_buffer), u)
    a0 = _rows(z, nb, buffer_start)

    def actuator(s):
        return actuators_after(structure, a0, delayed, p, s, ops)

    def effective(values):
        out = list(delayed)
        for c, v in zip(structure.lag_indices, values):
            out[c] = v
        return ops.stack(*out)

    x = _rows(z, 0, nb)
    if not structure.n_actuator:
        u_eff = effective([])
        x_next = ops.stack(*x)
        h = dt / substeps
        for _ in range(substeps):
            x_next = explicit_rk_step(tableau, lambda xx: body_rhs(xx, u_eff, p), x_next, h)
        return ops.concat(x_next, ops.stack(*new_buffer)) if new_buffer else x_next
    h = dt / substeps
    y = ops.stack(*x, x[0] * 0.0)  # the body state and the clock (time since the step start)
    one = x[0] * 0.0 + 1.0

    def rhs(yy):
        rates = body_rhs(ops.stack(*_rows(yy, 0, nb)), effective(actuator(yy[nb])), p)
        return ops.concat(rates, ops.stack(one))

    for _ in range(substeps):
        y = explicit_rk_step(tableau, rhs, y, h)
    blocks = [ops.stack(*_rows(y, 0, nb)), ops.stack(*actuator(dt))]
    if new_buffer:
        blocks.append(ops.stack(*new_buffer))
    return ops.concat(*blocks)


def physics_function(airframe: Airframe | ModelStructure, tableau: ButcherTableau = RK4,
                     with_position: bool = False, substeps: int = 1, fitting=(),
                     name: str | None = None) -> ca.Function:
    """The bare SX Function ``(x, u, p, dt) -> x_next`` of :func:`uavdyn.physics_step` (for
    code that builds on the Function itself, e.g. the identification); ``x`` is the augmented
    state when the airframe has actuator lags or delays (state names:
    ``structure.state_names()``), else the body state and the plain RK step. The parameters
    are those of :func:`uavdyn.integrate.physics_step`."""
    structure = (airframe if isinstance(airframe, ModelStructure)
                 else structure_of(airframe, fitting))
    if not structure.augmented and substeps == 1:
        from uavdyn.integrate.steps import rk_step
        return rk_step(build_model(structure, with_position).f, tableau,
                       name or f"{tableau.name}_step")
    nz = structure.nx(with_position)
    z, u = ca.SX.sym("x", nz), ca.SX.sym("u", structure.nu)
    p, dt = ca.SX.sym("p", structure.np), ca.SX.sym("dt")
    z_next = augmented_rk_step(structure, make_rhs(structure, with_position), z, u, p, dt,
                               tableau, CASADI_OPS, with_position, substeps)
    return ca.Function(name or f"{tableau.name}_step", [z, u, p, dt], [z_next], STEP_INPUTS,
                       ["x_next"])


def memory_state_names(control_names: tuple[str, ...], taus: tuple[float, ...]
                       ) -> tuple[str, ...]:
    """Names of the command-memory states, in state order (time constant, then command)."""
    return tuple(f"{c}_memory_{tau:g}s" for tau in taus for c in control_names)


def memory_update(memory: list, u, taus: tuple[float, ...], dt, ops) -> list:
    """Exact update over ``dt`` of each command's low-pass memory (command held): one state per
    time constant and command, ``m + (u - m)(1 - exp(-dt/tau))``."""
    out = []
    nu = len(memory) // max(1, len(taus)) if taus else 0
    for j, tau in enumerate(taus):
        decay = math.exp(-dt / tau) if isinstance(dt, (int, float)) else ops.exp(-dt / tau)
        out += [lag_toward(memory[j * nu + c], u[c], decay) for c in range(nu)]
    return out


def actuator_rest(structure: ModelStructure, u) -> np.ndarray:
    """The actuator and delay-buffer states at rest on the command ``u``: every actuator at
    its command, every buffer full of it (layout: ``structure.state_names()`` after the body)."""
    u = np.asarray(u, float).ravel()
    return np.array([u[c] for c in structure.lag_indices]
                    + [u[c] for c, d in enumerate(structure.delay_samples) for _ in range(d)],
                    dtype=float)


def advance_actuators_ops(structure: ModelStructure, states: list, u, p, dt, ops) -> list:
    """The actuator and delay-buffer states (a list of rows) one call of the step later, the
    command ``u`` given over it (what the step does to them: they do not depend on the
    body), in any ``ops``."""
    n_act = structure.n_actuator
    delayed, new_buffers = _shift_buffers(structure, states[n_act:], u)
    return [*actuators_after(structure, states[:n_act], delayed, p, dt, ops), *new_buffers]


def advance_actuators(structure: ModelStructure, states, u, p, dt: float) -> np.ndarray:
    """:func:`advance_actuators_ops` in NumPy on an array of states."""
    states = list(np.asarray(states, float).ravel())
    u = np.asarray(u, float).ravel()
    return np.array(advance_actuators_ops(structure, states, u, p, dt, NUMPY_OPS), dtype=float)

