"""Real-time iteration (SQP-RTI) of the tracking MPC: one condensed QP per control step,
linearised about the rollout of the shifted previous plan from the measured state.

Per step: ONE compiled Function (:func:`qp_function`) rolls the prediction model out along the
warm-start plan, takes every stage Jacobian at once (``mapaccum`` over the horizon), condenses
the Gauss-Newton QP onto the control increments (plus one slack per soft state bound) and
returns its matrices; a CasADi ``conic`` solver with the fixed sparsity solves it. The Function
is generated as C, compiled with ``-O3`` and cached on disk by the hash of its source
(:func:`uavdyn.integrate.compile_function`), so a second construction loads the library instead
of compiling it. From Python a step is one call (:func:`packed_qp_function`'s one input vector,
the QP matrices passed to the solver inside CasADi): each crossing of CasADi's Python layer
costs conversions that added up to about a quarter of a solve.

With the shift switched off, repeated calls at one state are Gauss-Newton SQP iterations with
full steps, which converge to the optimum of the full SQP (:class:`uavdyn.mpc.TrackingMPC`) on
the same :class:`uavdyn.mpc.problem.TrackingProblem`.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from uavdyn.integrate import compile_function
from uavdyn.interrupts import reraise_interrupt
from uavdyn.mpc.policy import Controller, SolveOutcome
from uavdyn.mpc.problem import TrackingProblem

SOLVED_STATUS = "solved"  # the status of a solve the strict solver returned from
# the status of a full SQP stopped at its iteration limit after lowering the merit (applied)
ITERATION_LIMIT = "iteration limit (merit lowered)"
QP_SOLVERS = ("daqp", "qrqp", "osqp", "highs", "qpoases", "proxqp", "piqp", "hpipm")
_QUIET = {
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False,
             "error_on_fail": False},
    "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-7, "eps_rel": 1e-7, "polish": True,
                      "max_iter": 20000}, "error_on_fail": False},
    "highs": {"highs": {"output_flag": False}, "error_on_fail": False},
    "qpoases": {"printLevel": "none", "error_on_fail": False},
    "daqp": {"error_on_fail": False},
    "proxqp": {"error_on_fail": False},
    "piqp": {"error_on_fail": False},
    "hpipm": {"error_on_fail": False},
}

QP_OUTPUTS = ("H", "g", "A", "lba", "uba", "lbx", "ubx", "X", "check")


def qp_function(problem: TrackingProblem, name: str = "mpc_rti_qp") -> ca.Function:
    """The condensed Gauss-Newton QP of one real-time iteration as one MX Function.

    ``(x0, U, u_prev, refs, w) -> (H, g, A, lba, uba, lbx, ubx, X, check)``: ``U``
    (``nu x N``) is the plan linearised about, ``refs`` the ``3 x N`` references (pitch,
    altitude, speed), ``w`` the three tracking weights. The QP variables are the plan's
    increments ``vec(dU)`` then the slacks; ``X`` is the predicted rollout ``nx x (N+1)``;
    ``check`` the sum of every QP matrix entry and every predicted state (non-finite iff any
    of them is). The graph is :func:`linearisation_function`'s followed by
    :func:`condensing_function`'s, inlined.
    """
    x0, U, u_prev, refs, w = _qp_symbols(problem)
    X, A, B = problem.stage_jac.mapaccum("mpc_roll", problem.N)(x0, U)
    return ca.Function(name, [x0, U, u_prev, refs, w],
                       _condensed(problem, x0, U, u_prev, refs, w, X, A, B),
                       ["x0", "U", "u_prev", "refs", "w"], list(QP_OUTPUTS))


def linearisation_function(problem: TrackingProblem, name: str = "mpc_rti_lin"
                           ) -> ca.Function:
    """The first half of :func:`qp_function`: ``(x0, U) -> (X, A, B)``, the rollout
    ``X`` (``nx x N``, after each interval) with every stage Jacobian ``A`` (``nx x nx N``) and
    ``B`` (``nx x nu N``). Apart so that the C export can time it on its own."""
    x0, U = _qp_symbols(problem)[:2]
    X, A, B = problem.stage_jac.mapaccum("mpc_roll", problem.N)(x0, U)
    return ca.Function(name, [x0, U], [X, A, B], ["x0", "U"], ["X", "A", "B"])


def condensing_function(problem: TrackingProblem, name: str = "mpc_rti_condense"
                        ) -> ca.Function:
    """The second half of :func:`qp_function`: ``(x0, U, u_prev, refs, w, X, A, B)`` (the
    linearisation's outputs last, with its sparsity: a caller passes its nonzeros on as they
    are) ``-> (H, g, A, lba, uba, lbx, ubx, X, check)``."""
    syms = _qp_symbols(problem)
    lin = linearisation_function(problem)
    X, A, B = (ca.MX.sym(n, lin.sparsity_out(i)) for i, n in enumerate(("X", "A", "B")))
    return ca.Function(name, [*syms, X, A, B], _condensed(problem, *syms, X, A, B),
                       ["x0", "U", "u_prev", "refs", "w", "X_lin", "A_lin", "B_lin"],
                       list(QP_OUTPUTS))


def _qp_symbols(problem: TrackingProblem) -> list[ca.MX]:
    """``x0, U, u_prev, refs, w`` of the QP Functions."""
    N, nx, nu = problem.N, problem.nx, problem.nu
    return [ca.MX.sym("x0", nx), ca.MX.sym("U", nu, N), ca.MX.sym("u_prev", nu),
            ca.MX.sym("refs", 3, N), ca.MX.sym("w", 3)]


def _condensed(problem: TrackingProblem, x0, U, u_prev, refs, w, X, A, B) -> list:
    """The QP's matrices (:data:`QP_OUTPUTS`) from the linearisation ``X, A, B``."""
    N, nx, nu, ns = problem.N, problem.nx, problem.nu, problem.ns
    cfg = problem.config
    r, Jr, c, Jc = problem.output_jac.map(N)(X, refs, ca.repmat(w, 1, N))
    # condensing, forward: G = d x_{k+1} / d [u_0 .. u_k] (nx x nu (k+1)), one product per
    # stage; the residual and soft-bound rows of stage k are (sparse) J_k G
    rows_r, rows_c = [], []
    G = None
    for k in range(N):
        Bk = B[:, k * nu:(k + 1) * nu]
        G = Bk if G is None else ca.horzcat(ca.mtimes(A[:, k * nx:(k + 1) * nx], G), Bk)
        rest = nu * (N - k - 1)
        rows_r.append(ca.horzcat(ca.mtimes(Jr[:, k * nx:(k + 1) * nx], G), ca.MX(3, rest)))
        rows_c.append(ca.horzcat(ca.mtimes(Jc[:, k * nx:(k + 1) * nx], G), ca.MX(ns, rest)))
    My, Mc = ca.vertcat(*rows_r), ca.vertcat(*rows_c)  # stage-major rows
    D, E, e = (ca.DM(a) for a in problem.control_residual_matrices())
    u_vec = ca.vec(U)
    ru = ca.mtimes(D, u_vec) + ca.mtimes(E, u_prev) + e
    Huu = 2 * (ca.mtimes(My.T, My) + ca.mtimes(D.T, D))
    gu = 2 * (ca.mtimes(My.T, ca.vec(r)) + ca.mtimes(D.T, ru))
    H = ca.diagcat(Huu, 2 * cfg.w_slack_l2 * ca.MX.eye(ns))
    g = ca.vertcat(gu, cfg.w_slack_l1 * ca.MX.ones(ns))
    R, F = (ca.DM(a) for a in problem.rate_matrix())
    rb = ca.DM(problem.rate_bounds())
    du = ca.mtimes(R, u_vec) + ca.mtimes(F, u_prev)
    S = ca.DM(np.kron(np.ones((N, 1)), np.eye(ns)))
    Acon = ca.vertcat(ca.horzcat(ca.MX(R), ca.MX(nu * N, ns)),
                      ca.horzcat(Mc, ca.MX(S)), ca.horzcat(Mc, -ca.MX(S)))
    cv = ca.vec(c)
    low = ca.DM(np.tile(problem.soft_low, N))
    high = ca.DM(np.tile(problem.soft_high, N))
    big = ca.inf * ca.DM.ones(N * ns)
    lba = ca.vertcat(-rb - du, low - cv, -big)
    uba = ca.vertcat(rb - du, big, high - cv)
    lo, hi = (ca.DM(np.tile(problem.bounds[:, i], N)) for i in (0, 1))
    lbx = ca.vertcat(lo - u_vec, ca.DM.zeros(ns))
    ubx = ca.vertcat(hi - u_vec, ca.inf * ca.DM.ones(ns))
    Xall = ca.horzcat(x0, X)
    # one number that is non-finite when any QP matrix or the rollout is
    check = ca.sum1(ca.sum2(H)) + ca.sum1(g) + ca.sum1(ca.sum2(Acon)) + ca.sum1(ca.sum2(Xall))
    return [H, g, Acon, lba, uba, lbx, ubx, Xall, check]


def packed_qp_function(func: ca.Function) -> ca.Function:
    """:func:`qp_function` with its inputs in one vector (``x0``, ``vec(U)``, ``u_prev``,
    ``vec(refs)``, ``w``) and its rollout and check in one output (``vec(X)`` then
    ``check``): a call from Python converts one array in and one out instead of five and two
    (each conversion costs about 20 us in CasADi's Python layer)."""
    sizes = [func.numel_in(i) for i in range(func.n_in())]
    v = ca.MX.sym("v", sum(sizes))
    cuts = np.concatenate([[0], np.cumsum(sizes)]).astype(int).tolist()
    parts = [ca.reshape(p, func.size1_in(i), func.size2_in(i))
             for i, p in enumerate(ca.vertsplit(v, cuts))]
    out = func.call(parts)
    return ca.Function(f"{func.name()}_packed", [v],
                       [*out[:-2], ca.vertcat(ca.vec(out[-2]), out[-1])],
                       ["v"], [*func.name_out()[:-2], "X_check"])


class RTIController(Controller):
    """SQP real-time-iteration tracking MPC (see the module docstring).

    Parameters
    ----------
    problem : TrackingProblem
        The tracking problem (``problem.config.qp_solver`` chooses the QP solver,
        ``problem.config.compile`` whether the QP Function is compiled).
    shift : bool
        Shift the previous plan one interval before linearising (closed-loop use); ``False``
        makes repeated calls at one state Gauss-Newton SQP iterations.

    Raises
    ------
    ValueError
        For an unknown QP solver.
    """

    def __init__(self, problem: TrackingProblem, shift: bool = True):
        cfg = problem.config
        if cfg.qp_solver not in QP_SOLVERS:
            raise ValueError(f"qp_solver must be one of {QP_SOLVERS}, got {cfg.qp_solver!r}")
        func = packed_qp_function(qp_function(problem, f"mpc_rti_qp_{problem.kind}_n"
                                                       f"{problem.N}"))
        self.qp_data = compile_function(func) if cfg.compile else func
        opts = dict(_QUIET.get(cfg.qp_solver, {}))
        opts.update(cfg.solver_options)
        self.qp = ca.conic("mpc_rti_qp", cfg.qp_solver,
                           {"h": func.sparsity_out(0), "a": func.sparsity_out(2)}, opts)
        self._defaults = [ca.DM()] * (self.qp.n_in() - 7)
        # the QP data passed straight to a solver that raises on failure, inside one Function:
        # one conversion in, three out, instead of the QP matrices crossing into Python and
        # back (about 75 us); a failure is solved again apart, for its status
        strict = ca.conic("mpc_rti_qp_strict", cfg.qp_solver,
                          {"h": func.sparsity_out(0), "a": func.sparsity_out(2)},
                          {**opts, "error_on_fail": True})
        packed = ca.MX.sym("v", func.size1_in(0))
        H, g, A, lba, uba, lbx, ubx, X_check = self.qp_data(packed)
        sol = strict(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        self._step = ca.Function(f"{func.name()}_step", [packed],
                                 [sol["x"], sol["cost"], X_check])
        self.shift = shift
        super().__init__(problem)

    def _start_plan(self, u_prev) -> np.ndarray:
        if self.shift or self._plan is None:
            return self.warm_plan(u_prev)
        return np.clip(self._plan, self.bounds[:, :1], self.bounds[:, 1:])

    def _solve(self, x0, u_prev, refs, weights) -> SolveOutcome:
        return self._iteration(x0, self._start_plan(u_prev), u_prev, refs, weights)[0]

    def _iteration(self, x0, Ub, u_prev, refs, weights) -> tuple[SolveOutcome, ca.DM | float]:
        """One real-time iteration about the plan ``Ub``: the outcome (plan ``Ub + dU``) and
        the QP's objective (the predicted change of the Gauss-Newton cost; a 1 x 1 ``DM``,
        converted by the caller that needs it). One call of the QP data and the solver; where
        it raises (non-finite data the solver refuses), the two apart say what failed."""
        packed = np.concatenate([x0, Ub.ravel(order="F"), u_prev, refs.ravel(order="F"),
                                 weights])
        try:
            v, cost, X_check = self._step.call([packed])
        except RuntimeError as exc:  # the solver failed or refused the data (or Ctrl-C)
            reraise_interrupt(exc)
            return self._iteration_apart(packed, Ub)
        X_check = X_check.full().ravel()
        X = X_check[:-1].reshape((len(x0), self.N + 1), order="F")
        if not np.isfinite(X_check[-1]):
            return SolveOutcome(Ub, X, False, "non-finite linearisation", 0), 0.0
        return self._outcome(Ub, X, v, SOLVED_STATUS), cost

    def _iteration_apart(self, packed: np.ndarray, Ub: np.ndarray
                         ) -> tuple[SolveOutcome, ca.DM | float]:
        """:meth:`_iteration` with the QP data checked before the solver sees them."""
        H, g, A, lba, uba, lbx, ubx, X_check = self.qp_data.call([packed])
        X_check = X_check.full().ravel()
        X = X_check[:-1].reshape((self.nx, self.N + 1), order="F")
        if not np.isfinite(X_check[-1]):
            return SolveOutcome(Ub, X, False, "non-finite linearisation", 0), 0.0
        return self._solve_qp(Ub, X, [H, g, A, lba, uba, lbx, ubx] + self._defaults)

    def _outcome(self, Ub: np.ndarray, X: np.ndarray, v: ca.DM,
                 solved: str | None = None) -> SolveOutcome:
        """The plan ``Ub + dU`` from the solver's variables ``v``; its status is ``solved``
        (the strict solver returned) or the solver's own (:attr:`qp`'s statistics)."""
        v = v.full().ravel()
        if solved is None:
            stats = self.qp.stats()
            success, status = bool(stats.get("success", False)), str(stats.get("return_status",
                                                                                  ""))
        else:
            success, status = True, solved
        nU = self.nu * self.N
        U = Ub + v[:nU].reshape((self.nu, self.N), order="F")
        return SolveOutcome(U, X, success, status, 1, v[nU:])

    def _solve_qp(self, Ub: np.ndarray, X: np.ndarray, qp_args: list
                  ) -> tuple[SolveOutcome, ca.DM]:
        """Solve the condensed QP (``conic`` inputs in order: h, g, a, lba, uba, lbx, ubx,
        then defaults) and return the new plan ``Ub + dU`` and the QP objective."""
        out = self.qp.call(qp_args)
        return self._outcome(Ub, X, out[0]), out[1]

    def iterate(self, x0, u_prev, theta_ref, h_ref, speed_ref, weights=None,
                iterations: int = 20, tol: float = 1e-9):
        """Gauss-Newton SQP at one state: repeated unshifted real-time iterations (full steps)
        until the plan changes by less than ``tol`` (max abs); returns the last
        :class:`MPCResult`. The controller's plan and carried states are reset first."""
        shift, self.shift = self.shift, False
        self.reset()
        try:
            extra = self.actuator_states(u_prev) if self.n_extra else None
            last = None
            for _ in range(iterations):
                res = self.solve(x0, u_prev, theta_ref, h_ref, speed_ref, weights, extra)
                if not res.success:
                    return res
                if last is not None and np.max(np.abs(res.predicted_controls - last)) < tol:
                    return res
                last = res.predicted_controls
            return res
        finally:
            self.shift = shift


class SQPController(RTIController):
    """Full SQP: Gauss-Newton SQP iterations on the same condensed QP as the real-time
    iteration, each step scaled by a backtracking line search on the exact-penalty merit
    (:meth:`uavdyn.mpc.problem.TrackingProblem.merit_function`, the nonlinear rollout), until
    the plan changes by less than ``config.sqp_tol`` or the QP predicts no relative decrease
    above 1e-10 (success), or a failed line search (failure).
    Warm-started from the shifted previous plan. Gauss-Newton converges linearly where the
    optimal residuals are large (a step reference): expect tens of iterations there, and
    more with a hybrid prediction, whose network's curvature Gauss-Newton leaves out.

    At ``config.sqp_max_iter`` iterations the last plan linearised about is applied (status
    :data:`ITERATION_LIMIT`) if the line search lowered the merit below the warm start's:
    every iterate keeps the hard bounds and the rollout is exact, so that plan is better
    by the controller's own measure than the fallback, which is the warm start itself.
    Otherwise the solve fails (``"maximum iterations"``).
    """

    ARMIJO = 1e-4
    MIN_STEP = 1.0 / 1024
    STATIONARY = 1e-10  # predicted decrease, relative to the merit

    def __init__(self, problem: TrackingProblem, shift: bool = True):
        super().__init__(problem, shift)
        func = problem.merit_function(f"mpc_merit_{problem.kind}_n{problem.N}")
        self.merit = compile_function(func) if problem.config.compile else func

    def _solve(self, x0, u_prev, refs, weights) -> SolveOutcome:
        cfg = self.config
        U = self._start_plan(u_prev)
        args = [x0, None, u_prev, refs, weights]

        def merit(plan):
            args[1] = plan
            return float(self.merit.call(args)[0])

        m0 = m_start = merit(U)
        last = None  # the last plan linearised about, its rollout and merit
        for it in range(1, cfg.sqp_max_iter + 1):
            out, qp_obj = self._iteration(x0, U, u_prev, refs, weights)
            if not out.success:
                out.iterations = it
                return out
            dU = out.U - U
            if np.max(np.abs(dU)) < cfg.sqp_tol:
                return SolveOutcome(out.U, out.X, True, "converged", it, out.slack)
            decrease = max(-float(qp_obj), 0.0)
            if decrease <= self.STATIONARY * (1.0 + abs(m0)):  # no descent left to find
                return SolveOutcome(U, out.X, True, "converged (stationary)", it, out.slack)
            last = (U, out.X, m0)
            alpha = 1.0
            while True:
                m = merit(U + alpha * dU)
                if np.isfinite(m) and m <= m0 - self.ARMIJO * alpha * decrease:
                    break
                alpha *= 0.5
                if alpha < self.MIN_STEP:
                    return SolveOutcome(U, out.X, False, "line search failed", it, out.slack)
            U, m0 = U + alpha * dU, m
            if alpha * np.max(np.abs(dU)) < cfg.sqp_tol:
                return SolveOutcome(U, out.X, True, "converged", it, out.slack)
        if last is not None and last[2] < m_start:
            return SolveOutcome(last[0], last[1], True, ITERATION_LIMIT, cfg.sqp_max_iter)
        return SolveOutcome(U, None, False, "maximum iterations", cfg.sqp_max_iter)
