"""How the network enters the step, one small object per formulation, written once against
``ops`` so the CasADi hybrid step and the torch training step are the same code.

``improved`` (default)
    inputs ``[x_k, u_k]``, output a residual acceleration ``[du_dot, dw_dot, dq_dot]`` (SI units)
    added to the physics right-hand side in every RK stage and held over the step (grey-box /
    UDE style): ``theta_dot = q`` stays exact and one network serves every ``dt``.
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

from uavdyn.integrate.tableau import RK4, explicit_rk_step

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

    def step(self, rhs: Callable, x, u, p, dt, net: Callable, ops, t=None):
        """``x_next`` of the hybrid step; ``rhs(x, u, p)`` is the physics, ``net(inp)`` the
        network on a feature-first block (both evaluated with ``ops``)."""
        if self.name == "improved":
            accel = net(ops.concat(x, u))
            extra = ops.concat(accel, ops.zeros(STATE_DIM - self.n_out, accel))
            return explicit_rk_step(RK4, lambda xx: rhs(xx, u, p) + extra, x, dt)
        base = explicit_rk_step(RK4, lambda xx: rhs(xx, u, p), x, dt)
        if self.name == "paper":
            if t is None:
                raise ValueError("the 'paper' formulation needs the time input t")
            return base + net(ops.concat(t, base))
        return base + dt**HYPERSOLVER_ORDER * net(ops.concat(x, u))


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
