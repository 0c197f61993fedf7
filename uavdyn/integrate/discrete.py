"""The discrete model object: a step Function together with everything a caller must know to
use it right (step-size policy, time range, state/control/parameter layout, how to start it
from logged data), so evaluation, MPC, Monte Carlo, modes and C export take one object.

The state of a discrete step is laid out as::

    [body (u, w, q, theta[, x_n, h]) | actuator states | delay buffers | command memory]

The actuator and delay-buffer states come from the physics structure
(:mod:`uavdyn.model.structure`); the command memory (each command low-passed at a few time
constants) is what a learned correction carries. None of the extra states depend on the body,
so they can be rebuilt from a recorded command history alone: :meth:`StateLayout.history` is
the one loop that does it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from functools import lru_cache

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.integrate.augmented import (
    actuator_rest,
    advance_actuators,
    advance_actuators_ops,
    memory_state_names,
    memory_update,
    physics_function,
)
from uavdyn.integrate.codegen import compile_function
from uavdyn.integrate.tableau import RK4, ButcherTableau
from uavdyn.model import CASADI_OPS, NUMPY_OPS, ModelStructure, structure_of


class StepUseError(ValueError):
    """A discrete model was asked for a step size or time it was not made for."""


class StepUseWarning(UserWarning):
    """As :class:`StepUseError`, downgraded on request (``strict=False``)."""


@dataclass(frozen=True)
class StateLayout:
    """The state vector of a discrete step (see the module docstring).

    Parameters
    ----------
    structure : ModelStructure
        The physics structure (kind, actuator lags, delays).
    memory_tau : tuple of float
        Time constants (s) of the command memory, one memory state per command and constant.
    with_position : bool
        Whether the body carries the ``[x_n, h]`` position states.
    """

    structure: ModelStructure
    memory_tau: tuple[float, ...] = ()
    with_position: bool = False

    @property
    def n_body(self) -> int:
        return len(self.structure.body_state_names(self.with_position))

    @property
    def n_physics(self) -> int:
        """Body, actuator and delay-buffer states (what the physics step carries)."""
        return self.structure.nx(self.with_position)

    @property
    def n_extra(self) -> int:
        """Actuator, delay-buffer and memory states (everything after the body)."""
        return self.n_state - self.n_body

    @property
    def n_state(self) -> int:
        return self.n_physics + self.structure.nu * len(self.memory_tau)

    @property
    def state_names(self) -> tuple[str, ...]:
        return (self.structure.state_names(self.with_position)
                + memory_state_names(self.structure.control_names, self.memory_tau))

    def rest(self, u) -> np.ndarray:
        """The extra states at rest on the command ``u``: every actuator at it, every buffer
        full of it, every memory equal to it."""
        u = np.asarray(u, float).ravel()
        return np.concatenate([actuator_rest(self.structure, u),
                               np.tile(u, len(self.memory_tau))])

    def advance(self, extra, u, p, dt: float) -> np.ndarray:
        """The extra states one call of the step later, the command ``u`` held over ``dt``
        (NumPy; exactly what the step does to them)."""
        extra = np.asarray(extra, float).ravel()
        u = np.asarray(u, float).ravel()
        n_act = self.n_physics - self.n_body
        act = advance_actuators(self.structure, extra[:n_act], u, p, dt)
        memory = memory_update(list(extra[n_act:]), u, self.memory_tau, dt, NUMPY_OPS)
        return np.concatenate([act, np.asarray(memory, float)])

    def history(self, controls, p, sample_dt: float) -> np.ndarray:
        """The extra states at every sample of a recorded command history (``N x nu``, row k
        held over sample k), at rest on the first command: row ``k`` is what the step carries
        at sample ``k``. One CasADi loop (``mapaccum``) over the step's own update of the
        extra states: a 60 s log at 100 Hz in milliseconds."""
        controls = np.atleast_2d(np.asarray(controls, float))
        out = np.empty((controls.shape[0], self.n_extra))
        if not len(controls):
            return out
        out[0] = self.rest(controls[0])
        if len(controls) > 1 and self.n_extra:
            loop = _extra_loop(self.structure, self.memory_tau, len(controls) - 1)
            out[1:] = np.array(loop(out[0], controls[:-1].T, np.asarray(p, float),
                                    float(sample_dt))).T
        return out

    def states(self, body, controls, p, sample_dt: float) -> np.ndarray:
        """Recorded body states (``N x n_body``) with the extra states of :meth:`history`
        appended: the step's state at every recorded sample."""
        body = np.atleast_2d(np.asarray(body, float))
        if not self.n_extra:
            return body
        return np.hstack([body, self.history(controls, p, sample_dt)])


@lru_cache(maxsize=64)
def extra_step_function(structure: ModelStructure, memory_tau: tuple[float, ...] = ()
                        ) -> ca.Function:
    """``(e, u, p, dt) -> e_next``: the step's update of its extra states (actuators, delay
    buffers, command memory; they do not depend on the body) as an SX Function, what
    :meth:`StateLayout.advance` computes in NumPy (the C export of the MPC carries them
    with it)."""
    layout = StateLayout(structure, memory_tau)
    n_act = layout.n_physics - layout.n_body
    e, u = ca.SX.sym("e", layout.n_extra), ca.SX.sym("u", structure.nu)
    p, dt = ca.SX.sym("p", structure.np), ca.SX.sym("dt")
    rows = [e[i] for i in range(layout.n_extra)]
    act = advance_actuators_ops(structure, rows[:n_act], u, p, dt, CASADI_OPS)
    memory = memory_update(rows[n_act:], u, memory_tau, dt, CASADI_OPS)
    return ca.Function("extra_step", [e, u, p, dt], [ca.vertcat(*act, *memory)],
                       ["e", "u", "p", "dt"], ["e_next"])


@lru_cache(maxsize=64)
def _extra_loop(structure: ModelStructure, memory_tau: tuple[float, ...], n: int
                ) -> ca.Function:
    """``(extra0, U[nu x n], p, dt) -> extra after each of the n calls``: the step's update of
    its extra states (they do not depend on the body), looped with ``mapaccum``."""
    layout = StateLayout(structure, memory_tau)
    e, u = ca.SX.sym("e", layout.n_extra), ca.SX.sym("u", structure.nu)
    p, dt = ca.SX.sym("p", structure.np), ca.SX.sym("dt")
    step = extra_step_function(structure, memory_tau)
    acc = ca.Function("extra_acc", [ca.vertcat(e, p, dt), u],
                      [ca.vertcat(step(e, u, p, dt), p, dt)])
    E0, U = ca.MX.sym("e0", layout.n_extra), ca.MX.sym("U", structure.nu, n)
    P, DT = ca.MX.sym("p", structure.np), ca.MX.sym("dt")
    out = acc.mapaccum("extra_loop", n)(ca.vertcat(E0, P, DT), U)
    return ca.Function("extra_history", [E0, U, P, DT], [out[:layout.n_extra, :]])


@dataclass(frozen=True, eq=False)
class DiscreteModel:
    """A discrete step ``x_next = F(x, u, p, dt[, t])`` and how to use it right.

    Build one with :func:`uavdyn.physics_step` or :func:`uavdyn.hybrid_step`; call it like the
    Function (``model(x, u, p, dt)``), or hand it to :func:`uavdyn.free_run`, the MPC, Monte
    Carlo, the modes and the C export.

    Attributes
    ----------
    function : casadi.Function
        ``(x, u, p, dt[, t]) -> x_next`` (SX, or its compiled twin: :meth:`compiled`).
    layout : StateLayout
        Order and meaning of the entries of ``x``.
    dt : float or None
        The step size the model must be used at (a correction trained at one step, delays
        counted in calls), or None for any step size.
    t_range : tuple of float or None
        For a formulation that takes time ``t`` (s since the sortie start): the times it was
        trained on.
    strict : bool
        Whether a use outside ``dt``/``t_range`` raises (default) or only warns.
    airframe : Airframe or None
        The airframe the model was built for (its parameters, limits and trim speed).
    description : str
        One line for reports (e.g. ``"physics RK4"``, ``"physics + safe correction"``).
    """

    function: ca.Function
    layout: StateLayout
    dt: float | None = None
    t_range: tuple[float, float] | None = None
    strict: bool = True
    airframe: Airframe | None = None
    description: str = ""
    _compiled: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.function.size1_in(0) != self.layout.n_state:
            raise ValueError(f"step '{self.function.name()}' has {self.function.size1_in(0)} "
                             f"states but the layout names {self.layout.n_state}: "
                             f"{self.layout.state_names}")

    # ---- what a caller must know ------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.function.name()

    @property
    def kind(self) -> str:
        return self.layout.structure.kind

    @property
    def structure(self) -> ModelStructure:
        return self.layout.structure

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.layout.state_names

    @property
    def body_state_names(self) -> tuple[str, ...]:
        return self.structure.body_state_names(self.layout.with_position)

    @property
    def control_names(self) -> tuple[str, ...]:
        return self.structure.control_names

    @property
    def param_names(self) -> tuple[str, ...]:
        return self.structure.param_names

    @property
    def nx(self) -> int:
        return self.layout.n_state

    @property
    def nu(self) -> int:
        return self.structure.nu

    @property
    def n_body(self) -> int:
        return self.layout.n_body

    @property
    def takes_time(self) -> bool:
        """Whether the step has the named time input ``t``."""
        return "t" in self.function.name_in()

    @property
    def p(self) -> np.ndarray:
        """The airframe's parameter vector (``ValueError`` for a model built without one)."""
        if self.airframe is None:
            raise ValueError(f"model '{self.name}' was built without an airframe: give p")
        return self.airframe.p

    def __call__(self, *args):
        return self.function(*args)

    def step_rows(self, z: np.ndarray, controls: np.ndarray, p: np.ndarray,
                  dt: float) -> np.ndarray:
        """One step from every row of ``z`` (``(N, nx)``) with the matching row of
        ``controls`` and the parameters ``p``, as ``(N, nx)``: one mapped call, not N.

        Raises
        ------
        ValueError
            For a formulation that takes time (each row would need its own ``t``).
        """
        if self.takes_time:
            raise ValueError(f"model '{self.name}' takes time t: step_rows steps without it")
        z = np.asarray(z, float)
        params = np.tile(np.asarray(p, float).reshape(-1, 1), (1, len(z)))
        return np.asarray(self.function.map(len(z))(z.T, np.asarray(controls, float).T,
                                                    params, dt)).T

    def jacobians(self) -> ca.Function:
        """``(x, u, p, dt[, t]) -> (x_next, A = dx_next/dx, B = dx_next/du)`` by exact
        algorithmic differentiation of the step (built once per model)."""
        if "jacobians" not in self._compiled:
            self._compiled["jacobians"] = step_jacobians(self.function)
        return self._compiled["jacobians"]

    # ---- derived models ---------------------------------------------------------------------
    def compiled(self) -> DiscreteModel:
        """The same model with its Function compiled to C (cached on disk by content; the
        CasADi VM with one warning where no compiler exists)."""
        if self.function.is_a("External"):
            return self
        if "model" not in self._compiled:
            self._compiled["model"] = replace(self, function=compile_function(self.function),
                                              _compiled={})
        return self._compiled["model"]

    def with_function(self, function: ca.Function) -> DiscreteModel:
        """The same policy and layout around another Function of the same signature (e.g. a
        smoothed or renamed build)."""
        return replace(self, function=function, _compiled={})

    # ---- use --------------------------------------------------------------------------------
    def check_use(self, dt: float, t_start: float = 0.0, t_end: float = 0.0) -> None:
        """Refuse (or warn, for a non-strict model) a use at step size ``dt`` over the times
        ``[t_start, t_end]`` (s since the sortie start) outside what the model was made for.

        Raises
        ------
        StepUseError
            Naming the step, the requested and the allowed values.
        """
        problems = []
        if self.dt is not None and abs(dt - self.dt) > 1e-9 * self.dt:
            problems.append(f"step size {dt:g} s but it is made for {self.dt:g} s")
        if self.t_range is not None and (t_start < self.t_range[0] - 1e-9
                                         or t_end > self.t_range[1] + 1e-9):
            problems.append(f"times {t_start:g}..{t_end:g} s but it was trained on "
                            f"{self.t_range[0]:g}..{self.t_range[1]:g} s since the sortie start")
        if problems:
            message = f"step '{self.name}' used at {' and '.join(problems)}"
            if self.strict:
                raise StepUseError(message + " (build it with strict=False to only warn)")
            warnings.warn(message, StepUseWarning, stacklevel=3)

    def initial_state(self, body, controls=None, p=None, sample_dt: float | None = None
                      ) -> np.ndarray:
        """The step's state from logged body states and the commands that led there.

        Parameters
        ----------
        body : array_like, shape (n_body,) or (N, n_body)
            Logged body states (one sample, or a whole record).
        controls : array_like, shape (nu,) or (N, nu), optional
            The commands at those samples (row k held over sample k); the extra states start
            at rest on the first one. Needed when the model has extra states.
        p : array_like, optional
            Parameter vector (the lags' time constants); default the airframe's.
        sample_dt : float, optional
            Interval between the samples; default the model's ``dt``.

        Returns
        -------
        ndarray, shape (nx,) or (N, nx)
            One row per given body state.

        Raises
        ------
        ValueError
            If the body states have the wrong width, or the model has extra states and the
            commands (or an interval) are missing.
        """
        body = np.asarray(body, float)
        single = body.ndim == 1
        body = np.atleast_2d(body)
        if body.shape[1] != self.n_body:
            raise ValueError(f"model '{self.name}' starts from {self.n_body} body states "
                             f"{self.body_state_names}, got {body.shape[1]}")
        if not self.layout.n_extra:
            return body[0] if single else body
        if controls is None:
            raise ValueError(f"model '{self.name}' carries {self.layout.n_extra} actuator/"
                             "buffer/memory state(s): give the commands that led to the state")
        controls = np.atleast_2d(np.asarray(controls, float))
        step_dt = sample_dt if sample_dt is not None else self.dt
        if step_dt is None and len(controls) > 1:
            raise ValueError(f"model '{self.name}': give sample_dt, the interval of the log")
        z = self.layout.states(body, controls[:len(body)], self.p if p is None else p,
                               float(step_dt or 0.0))
        return z[0] if single else z


def step_jacobians(step: ca.Function, name: str = "step_jacobians") -> ca.Function:
    """``(x, u, p, dt[, t]) -> (x_next, A, B)`` of a step Function: its value and its exact
    Jacobians with respect to the state and the control (the map Jacobian ``A`` gives the
    discrete modes and the stability rule; ``A, B`` linearise an MPC)."""
    args = [ca.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(step.n_in())]
    x_next = step(*args)
    return ca.Function(name, args, [x_next, ca.jacobian(x_next, args[0]),
                                    ca.jacobian(x_next, args[1])],
                       [step.name_in(i) for i in range(step.n_in())], ["x_next", "A", "B"])


def model_function(step: DiscreteModel | ca.Function) -> ca.Function:
    """The Function of a discrete model (a bare Function is returned as it is)."""
    return step.function if isinstance(step, DiscreteModel) else step


def body_model(function: ca.Function, kind: str, airframe: Airframe | None = None,
               description: str = "") -> DiscreteModel:
    """A model on the 4 body states around a bare step Function (e.g. ``rk4_step(f)``), usable
    at any step size (``airframe``: whose parameters and limits it uses)."""
    from uavdyn.model.equations import as_structure

    return DiscreteModel(function, StateLayout(as_structure(kind)), airframe=airframe,
                         description=description)


def physics_step(airframe: Airframe | ModelStructure, tableau: ButcherTableau = RK4,
                 with_position: bool = False, substeps: int = 1, fitting=(),
                 name: str | None = None, dt: float | None = None) -> DiscreteModel:
    """The physics step of an airframe, actuator lags and transport delays included, as a
    :class:`DiscreteModel`.

    Parameters
    ----------
    airframe : Airframe or ModelStructure
        The airframe (its values decide the structure: a lag of 0 adds no state) or a
        structure.
    tableau : ButcherTableau
        The RK method (default classical RK4).
    with_position : bool
        Carry the ``[x_n, h]`` states.
    substeps : int
        RK steps per call (the delay buffers shift once per call).
    fitting : sequence of str
        Parameters about to be identified (their terms are kept even at a value of 0).
    name : str, optional
        Function name (default ``"<tableau>_step"``).
    dt : float, optional
        Pin the step size (e.g. the log interval that the delays were counted at).

    Returns
    -------
    DiscreteModel
        ``(x, u, p, dt) -> x_next`` on ``state_names`` (body, actuators, delay buffers).
    """
    airframe_obj = airframe if isinstance(airframe, Airframe) else None
    structure = (airframe if isinstance(airframe, ModelStructure)
                 else structure_of(airframe, fitting))
    function = physics_function(structure, tableau, with_position, substeps, name=name)
    label = f"physics {tableau.name}" + (f" x{substeps}" if substeps > 1 else "")
    return DiscreteModel(function, StateLayout(structure, (), with_position), dt=dt,
                         airframe=airframe_obj, description=label)


def actuator_history(structure: ModelStructure, controls, p, sample_dt: float) -> np.ndarray:
    """The actuator and delay-buffer states at every sample of a recorded command history
    (:meth:`StateLayout.history` of the physics structure)."""
    return StateLayout(structure).history(controls, p, sample_dt)


def augment_states(structure: ModelStructure, states, controls, p, sample_dt: float
                   ) -> np.ndarray:
    """Recorded body states with the actuator/buffer states the recorded commands imply
    appended (:meth:`StateLayout.states` of the physics structure)."""
    return StateLayout(structure).states(states, controls, p, sample_dt)
