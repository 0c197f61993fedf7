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

from uavdyn.integrate.augmented import augmented_rk_step, memory_state_names, memory_update
from uavdyn.integrate.tableau import RK4, explicit_rk_step
from uavdyn.learned.envelope import DEFAULT_GUARD, GUARDS, bounded
from uavdyn.model import ModelStructure

HYPERSOLVER_ORDER = 5  # dt**(p+1) with p = 4 for RK4
STATE_DIM = 4


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
        names = self.structure.control_names if self.structure is not None else ("u1", "u2")
        return self.state_names() + tuple(names)


def improved_step(layout: CorrectionLayout, rhs: Callable, z, u, p, dt, net: Callable, ops):
    """The ``improved`` hybrid step on the layout's state ``z`` (see the module docstring)."""
    inp = ops.concat(z, u)
    accel = net(inp)
    if layout.bound is not None:
        accel = bounded(accel, layout.bound, ops, GUARDS[layout.guard][1])
    if layout.gate is not None:
        accel = accel * layout.gate(inp, ops)
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
