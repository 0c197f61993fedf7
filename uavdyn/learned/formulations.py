"""How the network enters the step, one small object per formulation, written once against
``ops`` so the CasADi hybrid step and the torch training step are the same code.

``improved`` (default)
    inputs: the step's whole state (body state, the physics' actuator and delay-buffer states,
    and a command memory: each command low-passed at a few time constants, exact exponential
    filters carried as augmented states) and the command ``u_k``: causal and state-complete,
    no absolute time. Output: a residual acceleration ``[du_dot, dw_dot, dq_dot]`` (SI units),
    bounded and multiplied by the envelope gate (the guard of :mod:`uavdyn.learned.envelope`:
    1 inside the training data, exactly 0 outside), added to
    the physics right-hand side in every RK stage and held over the step (grey-box / UDE
    style): ``theta_dot = q`` stays exact, far from the data the step IS the physics step.
``paper``
    inputs ``[t, x_base]`` (time since the start of the sortie and the RK4 state), output ``dx``:
    ``x_next = x_base + y`` as the paper states it; valid only at its trained ``dt`` and inside
    its trained time range.
``hypersolver``
    inputs ``[x_k, u_k]``, output ``g``: ``x_next = RK4(x_k, u_k, dt) + dt**5 g`` (Poli et al.
    2020); right for pure integration error, wrong for unmodelled physics.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from uavdyn.integrate.augmented import (
    augmented_rk_step,
    effective_controls,
    memory_state_names,
    memory_update,
)
from uavdyn.integrate.tableau import RK4, explicit_rk_step
from uavdyn.learned.envelope import DEFAULT_GUARD, GUARDS, bounded
from uavdyn.model import (
    NUMPY_OPS,
    ModelStructure,
    body_forces,
    symbolic_params,
    translational_accelerations,
)

HYPERSOLVER_ORDER = 5  # dt**(p+1) with p = 4 for RK4
STATE_DIM = 4
# What the ``improved`` network sees in place of the body states (the rest of the step's
# state and the command follow): ``state`` the body states themselves; ``physical`` the
# variables aerodynamics depend on, computed inside the step from the physics at the step's
# start (:func:`correction_inputs`).
INPUT_DESIGNS = ("state", "physical")
# the inputs that are rates (zero in steady flight, whatever the condition): the steady box of
# the gate does not hold them (uavdyn.learned.envelope.SteadyBox); a pitch rate among them
# measures how steady the flight is
DYNAMIC_INPUTS = ("q_hat", "alpha_dot_hat", "q")
PHYSICAL_INPUTS = {"fixed_wing": ("alpha", "V", "q_hat", "alpha_dot_hat", "C_thrust"),
                   "multirotor": ("u", "w", "q", "thrust_per_weight", "omega_u", "omega_w",
                                  "omega_diff_u", "omega_diff_w")}
# What its output is: ``acceleration`` [du_dot, dw_dot, dq_dot] (m/s^2, rad/s^2), or
# ``coefficient`` [dC_X, dC_Z, dC_m] (body-axis force and moment coefficients, a fixed wing
# only: times qbar S / m and qbar S c / Jy inside the step, so the residual grows with dynamic
# pressure as aerodynamic forces do).
OUTPUT_DESIGNS = ("acceleration", "coefficient")


@dataclass(frozen=True)
class Formulation:
    """One way of combining physics step and network.

    Attributes
    ----------
    name : str
        ``improved``, ``paper`` or ``hypersolver``.
    input_names : tuple of str
        Network input features, in order.
    n_out : int
        Network output size.
    takes_time : bool
        Whether the step has the named input ``t`` (time since the start of the sortie).
    dt_bound : bool
        Whether the network is only valid at the step size it was trained at.
    """

    name: str
    input_names: tuple[str, ...]
    n_out: int
    takes_time: bool
    dt_bound: bool

    @property
    def n_in(self) -> int:
        return len(self.input_names)

    def step(self, rhs: Callable, x, u, p, dt, net: Callable, ops, t=None,
             layout: CorrectionLayout | None = None):
        """``x_next`` of the hybrid step; ``rhs(x, u, p)`` is the physics, ``net(inp)`` the
        network on a feature-first block (both evaluated with ``ops``). ``improved`` works on
        the augmented state of ``layout`` (default: the body state alone, as in format 2)."""
        if self.name == "improved":
            return improved_step(layout or CorrectionLayout(), rhs, x, u, p, dt, net, ops)
        base = explicit_rk_step(RK4, lambda xx: rhs(xx, u, p), x, dt)
        if self.name == "paper":
            if t is None:
                raise ValueError("the 'paper' formulation needs the time input t")
            return base + net(ops.concat(t, base))
        return base + dt**HYPERSOLVER_ORDER * net(ops.concat(x, u))


def design_problem(inputs: str, output: str, kind: str | None) -> str | None:
    """What is wrong with an ``improved`` network's design (None: nothing): an unknown input or
    output design, or a coefficient output on a multirotor."""
    if inputs not in INPUT_DESIGNS:
        return f"key 'inputs' is {inputs!r}; expected one of {INPUT_DESIGNS}"
    if output not in OUTPUT_DESIGNS:
        return f"key 'output' is {output!r}; expected one of {OUTPUT_DESIGNS}"
    if output == "coefficient" and kind not in (None, "fixed_wing"):
        return ("key 'output' is 'coefficient', which needs a fixed wing: a hovering "
                "multirotor has no dynamic pressure to scale it by")
    return None


@dataclass(frozen=True)
class CorrectionLayout:
    """The state the ``improved`` correction steps: the physics ``structure``'s augmented state
    (None: the 4 body states) followed by one memory state per command and time constant in
    ``memory_tau`` (s); the network's gate (``gate(inp, ops)``, None: 1) and output bound
    (per-output array, None: unbounded), applied in the form of ``guard`` (a name of
    :data:`uavdyn.learned.envelope.GUARDS`; its gate form is the caller's to bind)."""

    structure: ModelStructure | None = None
    memory_tau: tuple[float, ...] = ()
    gate: Callable | None = None
    bound: object = None
    guard: str = DEFAULT_GUARD
    inputs: str = "state"
    output: str = "acceleration"

    def __post_init__(self) -> None:
        kind = self.structure.kind if self.structure is not None else None
        problem = design_problem(self.inputs, self.output, kind)
        if problem:
            raise ValueError(problem)
        if (self.inputs != "state" or self.output != "acceleration") and kind is None:
            raise ValueError("physical inputs and coefficient outputs need the physics "
                             "structure of the step")

    @property
    def n_physics(self) -> int:
        return self.structure.nx() if self.structure is not None else STATE_DIM

    @property
    def nu(self) -> int:
        return self.structure.nu if self.structure is not None else 2

    @property
    def n_state(self) -> int:
        return self.n_physics + self.nu * len(self.memory_tau)

    def state_names(self, control_names: tuple[str, ...] = ("u1", "u2")) -> tuple[str, ...]:
        physics = (self.structure.state_names() if self.structure is not None
                   else ("u", "w", "q", "theta"))
        names = self.structure.control_names if self.structure is not None else control_names
        return physics + memory_state_names(names, self.memory_tau)

    def input_names(self) -> tuple[str, ...]:
        """The network's inputs, in order (:func:`correction_inputs`)."""
        names = self.structure.control_names if self.structure is not None else ("u1", "u2")
        states = self.state_names()
        if self.inputs == "physical":
            states = PHYSICAL_INPUTS[self.structure.kind] + states[STATE_DIM:]
        return states + tuple(names)

    @property
    def n_inputs(self) -> int:
        return len(self.input_names())


def rate_inputs(layout: CorrectionLayout) -> tuple[int, ...]:
    """Which of ``layout``'s network inputs are rates (:data:`DYNAMIC_INPUTS`)."""
    return tuple(i for i, name in enumerate(layout.input_names()) if name in DYNAMIC_INPUTS)


def airspeed_input(kind: str, inputs: str) -> int | None:
    """Which network input is the airspeed itself (``V`` among a design's physical inputs,
    :data:`PHYSICAL_INPUTS`), None where the network sees no airspeed and its first two inputs
    are the body velocities ``u``, ``w`` (the gate's trim sweep,
    :func:`uavdyn.learned.stability.envelope_speeds`)."""
    names = PHYSICAL_INPUTS.get(kind, ()) if inputs == "physical" else ()
    return names.index("V") if "V" in names else None


def correction_inputs(layout: CorrectionLayout, z, u, p, ops):
    """The network's inputs and the gain of each output, at the step's state ``z`` and
    command ``u`` (feature-first, any ``ops``).

    ``physical`` inputs replace the body states by what the forces depend on, from the physics
    at the start of the step with the actuator-side controls: a fixed wing's angle of attack,
    airspeed, ``q c/2V``, ``alpha_dot c/2V`` (alpha_dot from the physics' own accelerations:
    causal, no filter) and thrust coefficient ``T / (qbar S)``; a multirotor's body velocities,
    pitch rate, thrust per weight and its mean rotor speed (over the slope ``C_R``, about the
    full-throttle speed) times ``u`` and ``w`` (rotor drag, blade flapping and inflow scale
    with both) and the front-rear difference of rotor speed times ``u`` and ``w`` (the pitch
    moments of translational lift and of the thrust each pair loses to axial inflow). Pitch
    attitude only enters through gravity, which the physics has exactly. The gains turn a
    ``coefficient`` output into accelerations (1 for an ``acceleration`` output)."""
    one = z[0] * 0.0 + 1.0
    if layout.inputs == "state" and layout.output == "acceleration":
        return ops.concat(z, u), (one, one, one)
    structure = layout.structure
    body = ops.stack(*[z[i] for i in range(STATE_DIM)])
    u_eff = effective_controls(structure, z, u, ops)
    X, Z, _, alpha, V, thrust = body_forces(structure, body, u_eff, p, ops)
    P = symbolic_params(structure.kind, p)
    qbar_s = 0.5 * P.rho * V**2 * P.S_wing if structure.kind == "fixed_wing" else None
    if layout.inputs == "state":
        head = body
    elif structure.kind == "fixed_wing":
        u_dot, w_dot = translational_accelerations(body, X, Z, P.mass, P.gravity, ops)
        c_2v = P.c / (2.0 * V)
        alpha_dot = (z[0] * w_dot - z[1] * u_dot) / V**2
        head = ops.stack(alpha, V, z[2] * c_2v, alpha_dot * c_2v, thrust / qbar_s)
    else:  # rotor drag, flapping and inflow scale with rotor speed times airspeed
        front, rear = (ops.fmax(P.C_R * (u_eff[0] + sign * P.pitch_mix * u_eff[1]) + P.omega_b,
                                0) / (2.0 * P.C_R) for sign in (1.0, -1.0))
        omega, omega_diff = front + rear, front - rear
        head = ops.stack(z[0], z[1], z[2], thrust / (P.mass * P.gravity), omega * z[0],
                         omega * z[1], omega_diff * z[0], omega_diff * z[1])
    rest = [z[i] for i in range(STATE_DIM, layout.n_state)]
    inp = ops.concat(head, ops.stack(*rest), u) if rest else ops.concat(head, u)
    if layout.output == "acceleration":
        return inp, (one, one, one)
    force = qbar_s / P.mass
    return inp, (force, force, qbar_s * P.c / P.Jy)


def network_inputs(layout: CorrectionLayout, z: np.ndarray, controls: np.ndarray,
                   p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The network's inputs ``(N, n_in)`` and output gains ``(N, 3)`` at the states ``z``
    ``(N, nz)`` under ``controls`` ``(N, nu)`` (the step's own :func:`correction_inputs`)."""
    inp, gains = correction_inputs(layout, z.T, controls.T, np.asarray(p, float), NUMPY_OPS)
    n = len(z)
    return (np.asarray(inp, float).reshape(-1, n).T,
            np.column_stack([np.broadcast_to(np.asarray(g, float), (n,)) for g in gains]))


def improved_step(layout: CorrectionLayout, rhs: Callable, z, u, p, dt, net: Callable, ops):
    """The ``improved`` hybrid step on the layout's state ``z`` (see the module docstring)."""
    inp, gains = correction_inputs(layout, z, u, p, ops)
    accel = net(inp)
    if layout.bound is not None:
        accel = bounded(accel, layout.bound, ops, GUARDS[layout.guard][1])
    if layout.gate is not None:
        accel = accel * layout.gate(inp, ops)
    if layout.output != "acceleration":
        accel = ops.stack(*[accel[i] * gains[i] for i in range(3)])
    extra = ops.concat(accel, ops.zeros(STATE_DIM - accel.shape[0], accel))
    n_phys = layout.n_physics
    z_phys = ops.stack(*[z[i] for i in range(n_phys)]) if layout.memory_tau else z

    def body(x, u_eff, pp):
        return rhs(x, u_eff, pp) + extra

    if layout.structure is None:
        z_next = explicit_rk_step(RK4, lambda xx: body(xx, u, p), z_phys, dt)
    else:
        z_next = augmented_rk_step(layout.structure, body, z_phys, u, p, dt, RK4, ops)
    if not layout.memory_tau:
        return z_next
    memory = [z[i] for i in range(n_phys, layout.n_state)]
    return ops.concat(z_next, ops.stack(*memory_update(memory, u, layout.memory_tau, dt, ops)))


FORMULATIONS: dict[str, Formulation] = {
    "improved": Formulation("improved", ("u", "w", "q", "theta", "u1", "u2"), 3, False, False),
    "paper": Formulation("paper", ("t", "u_base", "w_base", "q_base", "theta_base"), 4, True,
                         True),
    "hypersolver": Formulation("hypersolver", ("u", "w", "q", "theta", "u1", "u2"), 4, False,
                               True),
}
DEFAULT_FORMULATION = "improved"


def formulation(name: str) -> Formulation:
    """The formulation called ``name``; ``ValueError`` naming the choices otherwise."""
    try:
        return FORMULATIONS[name]
    except KeyError:
        raise ValueError(f"unknown formulation '{name}'; expected one of "
                         f"{tuple(FORMULATIONS)}") from None
