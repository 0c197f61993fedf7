"""The status policy every MPC mode shares: a failed solve is never applied; the controller falls
back to the shifted previous plan (the last successful plan's next control), then to the last
applied control, and counts which one it used. (A full SQP stopped at its iteration limit with
the merit lowered is not a failure: :class:`uavdyn.mpc.rti.SQPController`.)

:class:`Controller` is the base of both modes: it carries the step's extra states, builds the
references over the horizon, times the whole solve (what a flight computer waits for), marks a
solve with a non-finite plan as failed, and applies the policy. Subclasses implement
:meth:`Controller._solve` only.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass

import numpy as np

from uavdyn.mpc.problem import TrackingProblem

SOLVED, SHIFTED, HELD = "solved", "shifted", "held"
SOURCES = (SOLVED, SHIFTED, HELD)


@dataclass
class MPCResult:
    """One MPC step: the control to apply, where it came from and how the solver did.

    Attributes
    ----------
    u : ndarray
        The control to apply: the solved plan's first control, or a fallback.
    source : str
        ``"solved"``, ``"shifted"`` (the previous successful plan's next control) or
        ``"held"`` (the last applied control).
    success : bool
        Whether the solver succeeded (and its plan is finite).
    solve_time_s : float
        Wall time of the whole :meth:`Controller.solve` call.
    iterations : int
        SQP iterations (1 for a real-time iteration; -1 if unknown).
    status : str
        The solver's return status.
    predicted_states : ndarray or None
        MPC states ``nx x (N+1)`` of the solver's plan (RTI: the rollout it linearised about).
    predicted_controls : ndarray or None
        The solver's plan ``nu x N`` (whatever the status; never applied when failed).
    """

    u: np.ndarray
    source: str
    success: bool
    solve_time_s: float
    iterations: int
    status: str
    predicted_states: np.ndarray | None
    predicted_controls: np.ndarray | None


@dataclass
class SolveOutcome:
    """What a mode's ``_solve`` returns to the policy."""

    U: np.ndarray
    X: np.ndarray | None
    success: bool
    status: str
    iterations: int
    slack: np.ndarray | None = None


class Controller:
    """Common part of the MPC modes (see the module docstring). ``problem`` is the
    :class:`uavdyn.mpc.problem.TrackingProblem` both modes share."""

    def __init__(self, problem: TrackingProblem):
        self.problem = problem
        self.config = problem.config
        self.kind = problem.kind
        self.p = problem.p
        self.u_trim = problem.u_trim
        self.bounds = problem.bounds
        self.rates = problem.rates
        self.N, self.nx, self.nu = problem.N, problem.nx, problem.nu
        self.n_extra = problem.n_extra
        self.counts: Counter = Counter()
        self.reset()

    # ---- state the controller carries -------------------------------------------------------
    def reset(self) -> None:
        """Forget the plan, the warm start and the carried states (e.g. before a new flight);
        the fallback counters are kept (:attr:`counts`)."""
        self._plan: np.ndarray | None = None  # last successful plan
        self._plan_X: np.ndarray | None = None
        self._age = 0  # intervals since that plan was solved
        self._extra: np.ndarray | None = None

    @property
    def last_actuators(self) -> np.ndarray | None:
        """The extra states the last solve started from (None: none yet)."""
        return None if self._extra is None else self._extra.copy()

    def actuator_states(self, u_prev) -> np.ndarray:
        """The extra states (actuators, buffers, command memory) at this solve, from the
        controller's own commands: at rest on ``u_prev`` after a reset, else the last solve's
        advanced by ``u_prev`` (the command applied over the interval since)."""
        layout = self.problem.model.layout
        if self._extra is None:
            return layout.rest(u_prev)
        return layout.advance(self._extra, u_prev, self.p, self.config.dt)

    def warm_plan(self, u_prev) -> np.ndarray:
        """The plan a solve starts from: the last successful plan shifted to now (its last
        control repeated), else ``u_prev`` held; clipped to the control bounds."""
        N = self.N
        if self._plan is None or self._age + 1 >= N:
            U = np.tile(np.asarray(u_prev, float)[:, None], (1, N))
        else:
            s = self._age + 1
            U = np.hstack([self._plan[:, s:], np.repeat(self._plan[:, -1:], s, axis=1)])
        return np.clip(U, self.bounds[:, :1], self.bounds[:, 1:])

    def references(self, theta_ref, h_ref, speed_ref) -> np.ndarray:
        """``3 x N`` references (scalars held over the horizon)."""
        refs = np.empty((3, self.N))
        refs[0], refs[1], refs[2] = theta_ref, h_ref, speed_ref  # scalars broadcast
        return refs

    # ---- one MPC step --------------------------------------------------------------------
    def solve(self, x0, u_prev, theta_ref, h_ref, speed_ref,
              weights: tuple[float, float, float] | None = None,
              actuators=None) -> MPCResult:
        """One MPC step from the measured ``x0 = [u, w, q, theta, h]`` with ``u_prev`` the
        command applied over the last interval; references over the horizon (arrays of N, or
        scalars held); ``weights`` = (pitch, altitude, speed) overrides the config's.

        Returns the control to apply: the plan's first control if the solve succeeded, else
        the previous successful plan's next control, else ``u_prev`` (counted in
        :attr:`counts`).

        Raises
        ------
        ValueError
            On a state of the wrong size or wrong carried states.
        """
        t0 = time.perf_counter()
        cfg = self.config
        weights = weights if weights is not None else (cfg.w_theta, cfg.w_h, cfg.w_speed)
        x0 = np.asarray(x0, float).ravel()
        if x0.shape != (5,):
            raise ValueError(f"x0 must be [u, w, q, theta, h] (5 values), got shape {x0.shape}")
        u_prev = np.asarray(u_prev, float).ravel()
        if self.n_extra:
            extra = (self.actuator_states(u_prev) if actuators is None
                     else np.asarray(actuators, float).ravel())
            if extra.shape != (self.n_extra,):
                raise ValueError(f"actuators must be {self.n_extra} values, got {extra.shape}")
            self._extra = extra
            x0 = np.concatenate([x0, extra])
        refs = self.references(theta_ref, h_ref, speed_ref)
        out = self._solve(x0, u_prev, refs, np.asarray(weights, float))
        success = out.success
        status = out.status
        if not (np.all(np.isfinite(out.U)) and (out.X is None or np.all(np.isfinite(out.X)))):
            success, status = False, f"non-finite plan ({status})"
        if success:
            self._plan, self._plan_X, self._age = out.U.copy(), out.X, 0
            u, source = out.U[:, 0].copy(), SOLVED
        else:
            self._age += 1
            if self._plan is not None and self._age < self.N:
                u, source = self._plan[:, self._age].copy(), SHIFTED
            else:
                u, source = u_prev.copy(), HELD
        self.counts[source] += 1
        return MPCResult(u=u, source=source, success=success,
                         solve_time_s=time.perf_counter() - t0, iterations=out.iterations,
                         status=status, predicted_states=out.X, predicted_controls=out.U)

    def _solve(self, x0: np.ndarray, u_prev: np.ndarray, refs: np.ndarray,
               weights: np.ndarray) -> SolveOutcome:  # pragma: no cover - abstract
        raise NotImplementedError
