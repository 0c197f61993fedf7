"""Batched Monte-Carlo rollouts as compiled CasADi Functions: one run (a ``mapaccum`` loop over
any step Function that also accumulates the run's statistics) mapped over a chunk of runs with
CasADi's ``thread`` parallelism and compiled to C.

One run, from its initial state ``x0``, trim command ``u0`` and parameters ``p``, flies the
shared command deviations ``du`` (``nu x N``, row k held over step k; the command is
``u0 + du_k`` saturated at the airframe's control limits) and, with turbulence, its own gusts
``g`` (``3 x N``, body-axis ``[u_g, w_g, q_g]`` held over each step). At every sample it
evaluates the airframe's own force Function at the air-relative state: pitch angle, angle of
attack, airspeed and load factor ``n = -Z / (m g)`` (physics forces: a hybrid step's learned
residual acceleration is not part of it). It returns

* ``stats``: :data:`STAT_NAMES` (extrema, time beyond each limit, divergence time or -1);
* ``hist``: :data:`SIGNALS` every ``stride`` steps (the envelope grid), ``x0`` first.

Divergence: a sample whose state or signals are non-finite or beyond
:data:`DIVERGENCE_BOUND`, or whose body states leave their physical ranges (a departure:
:func:`uavdyn.model.state_limits`), ends the statistics; its time is returned (never a silent
NaN, never a tumbling run's finite nonsense).

Gusts (:func:`gust_step`): the air-relative velocity ``[u - u_g, w - w_g, q - q_g]`` enters the
airframe's force model and the inertial state the rigid-body equations, as in the emulator; the
same library pieces (:func:`uavdyn.model.body_forces`, :func:`uavdyn.model.rigid_body_rates`,
the augmented RK step or the hybrid formulation's step), no second copy of the equations.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe, param_names
from uavdyn.integrate import DIVERGENCE_BOUND, augmented_rk_step, compile_function
from uavdyn.learned.weights import CorrectionNet
from uavdyn.model import (
    CASADI_OPS,
    ModelStructure,
    body_forces,
    build_model,
    rigid_body_rates,
    state_limits,
)

SIGNALS = ("theta", "q", "alpha", "airspeed", "load_factor")
SIGNAL_UNITS = ("rad", "rad/s", "rad", "m/s", "-")
STAT_NAMES = ("max_abs_pitch", "max_alpha", "min_airspeed", "max_load_factor",
              "min_load_factor", "time_pitch_over", "time_alpha_over", "time_airspeed_under",
              "time_load_over", "t_diverged")
N_LIMITS = 4  # pitch (rad), alpha (rad), airspeed minimum (m/s), load factor maximum
N_GUST = 3


def gust_step(structure: ModelStructure, net: CorrectionNet | None = None,
              name: str = "gust_step") -> ca.Function:
    """A step ``(x, [u; u_g; w_g; q_g], p, dt) -> x_next`` whose forces see the air-relative
    velocity (gusts held over the step), built from the library's model and step pieces.

    Parameters
    ----------
    structure : ModelStructure
        The physics structure (e.g. ``structure_of(airframe, fitting)``).
    net : CorrectionNet, optional
        A correction without a time input: the hybrid formulation's own step is used with
        the air-relative physics (the network sees the inertial state, as without gusts).
    """
    nz = structure.nx() if net is None else net.n_state
    z, uext = ca.SX.sym("x", nz), ca.SX.sym("u", structure.nu + N_GUST)
    p, dt = ca.SX.sym("p", structure.np), ca.SX.sym("dt")
    u, g = uext[:structure.nu], uext[structure.nu:]
    names = param_names(structure.kind)
    i_mass, i_jy, i_g = (names.index(n) for n in ("mass", "Jy", "gravity"))

    def rhs(x, u_eff, pp):
        x_air = ca.vertcat(x[0] - g[0], x[1] - g[1], x[2] - g[2], x[3])
        X, Z, M = body_forces(structure, x_air, u_eff, pp, CASADI_OPS)[:3]
        return rigid_body_rates(x, X, Z, M, pp[i_mass], pp[i_jy], pp[i_g], False, CASADI_OPS)

    if net is None:
        z_next = augmented_rk_step(structure, rhs, z, u, p, dt)
    else:
        layout = net.layout(structure) if net.formulation == "improved" else None
        z_next = net.form.step(rhs, z, u, p, dt, net.casadi, CASADI_OPS, None, layout)
    return ca.Function(name, [z, uext, p, dt], [z_next], ["x", "u", "p", "dt"], ["x_next"])


def _signals(forces: ca.Function, x, u, g, p, i_mass: int, i_g: int):
    """``(theta, q, alpha, V, n)`` at state ``x`` (air-relative with gusts ``g``)."""
    x_air = ca.vertcat(x[0] - g[0], x[1] - g[1], x[2] - g[2], x[3]) if g is not None else x[:4]
    _, Z, _, alpha, V, _ = forces(x_air, u, p)
    return ca.vertcat(x[3], x[2], alpha, V, -Z / (p[i_mass] * p[i_g]))


def _inside(x, signals, body_limits: list[float]):
    """1 while the run is alive: every state and signal finite and within
    :data:`DIVERGENCE_BOUND`, and the body states within their physical ranges
    (:func:`uavdyn.model.state_limits`: a run that leaves them has departed, however finite its
    numbers); false for NaN and inf."""
    ok = 1
    for e in ca.vertsplit(ca.vertcat(x, signals)):
        ok = ca.logic_and(ok, ca.fabs(e) <= DIVERGENCE_BOUND)
    for j, limit in enumerate(body_limits):
        ok = ca.logic_and(ok, ca.fabs(x[j]) <= limit)
    return ok


def _command(u_open, x, x_ref, feedback: np.ndarray | None, lo, hi):
    """The command applied: open loop ``u_open``, or with the state feedback on the body
    states, saturated at the airframe's control limits."""
    if feedback is not None:
        u_open = u_open - ca.mtimes(ca.DM(feedback), x[:4] - x_ref)
    return ca.fmin(ca.fmax(u_open, lo), hi)


def run_function(step: ca.Function, airframe: Airframe, structure: ModelStructure,
                 n_steps: int, stride: int, gusts: bool, name: str = "mc_run",
                 feedback: np.ndarray | None = None) -> ca.Function:
    """One Monte-Carlo run as an MX Function (see the module docstring).

    Inputs ``x0, u0, p, du[nu x N], (g[3 x N] with gusts), dt, limits[4]`` (and ``xref[4]``
    closed loop); outputs ``stats[len(STAT_NAMES)]`` and
    ``hist[len(SIGNALS) x (N // stride + 1)]``.

    Parameters
    ----------
    step : casadi.Function
        ``(x, u, p, dt) -> x_next`` (with gusts: ``u`` is ``[command; gust]``); not compiled
        (the whole run is compiled in one piece).
    airframe : Airframe
        Control limits and parameter names.
    structure : ModelStructure
        Structure of the force model used for the statistics.
    n_steps, stride : int
        Steps per run and steps between two history samples.
    gusts : bool
        Whether the step takes gust inputs.
    feedback : ndarray, shape (nu, 4), optional
        Closed loop: the command is ``u0 + du - K (x_body - xref)`` before saturation (a
        state feedback such as :func:`uavdyn.montecarlo.feedback.lqr_gain`), ``xref`` the run's
        trim body state; None flies the commands open loop.
    """
    return pieces_run(run_pieces(step, airframe, structure, gusts, name, feedback), n_steps,
                      stride, gusts, name, feedback is not None)


def pieces_run(pieces: RunPieces, n_steps: int, stride: int, gusts: bool, name: str,
               feedback: bool) -> ca.Function:
    """:func:`run_function` of a run's pieces (built once, shared with the native loop)."""
    if n_steps < 1 or stride < 1:
        raise ValueError(f"n_steps and stride must be >= 1, got {n_steps}, {stride}")
    stride = min(stride, n_steps)
    start, body = pieces.start, pieces.body
    nx, nu, n_p, n_in = pieces.nx, pieces.nu, pieces.np, pieces.n_in

    # the run: initial signals, K intervals of `stride` steps (history), then the tail
    X0, U0, P = ca.MX.sym("x0", nx), ca.MX.sym("u0", nu), ca.MX.sym("p", n_p)
    DU, DT, LIM = ca.MX.sym("du", nu, n_steps), ca.MX.sym("dt"), ca.MX.sym("limits", N_LIMITS)
    XR = ca.MX.sym("xref", 4)
    G = ca.MX.sym("g", N_GUST, n_steps) if gusts else None
    IN = ca.vertcat(DU, G) if gusts else DU
    a0, sig0 = start(X0, U0, P, DU[:, 0], G[:, 0] if gusts else ca.DM.zeros(N_GUST), DT, LIM,
                     XR if feedback else ca.DM.zeros(4))
    n_int = n_steps // stride
    if stride > 1:
        inner = body.mapaccum(f"{name}_inner", stride)
        a_sym, blk = ca.MX.sym("acc", body.size1_in(0)), ca.MX.sym("blk", n_in * stride)
        interval = ca.Function(f"{name}_interval", [a_sym, blk],
                               [inner(a_sym, ca.reshape(blk, n_in, stride))[:, -1]])
    else:
        interval = body
    A = interval.mapaccum(f"{name}_outer", n_int)(
        a0, ca.reshape(IN[:, :n_int * stride], n_in * stride, n_int))
    a_end = A[:, -1]
    tail = n_steps - n_int * stride
    if tail:
        a_end = body.mapaccum(f"{name}_tail", tail)(a_end, IN[:, n_int * stride:])[:, -1]
    sig_rows = ca.vertcat(*(A[i, :] for i in pieces.signal_rows))
    hist = ca.horzcat(sig0, sig_rows)
    stats = ca.vertcat(*(a_end[i] for i in pieces.stat_rows))
    inputs = [X0, U0, P, DU] + ([G] if gusts else []) + [DT, LIM]
    in_names = ["x0", "u0", "p", "du"] + (["g"] if gusts else []) + ["dt", "limits"]
    if feedback:
        inputs, in_names = [*inputs, XR], [*in_names, "xref"]
    return ca.Function(name, inputs, [stats, hist], in_names, ["stats", "hist"])


@dataclass(frozen=True)
class RunPieces:
    """A run's two SX pieces, shared by the ``mapaccum`` run and the native loop.

    Attributes
    ----------
    start : casadi.Function
        ``(x0, u0, p, du0, g0, dt, limits, xref) -> (acc0, signals0)``: the accumulator at the
        first sample and the first history column.
    body : casadi.Function
        ``(acc, [du_k; g_k]) -> acc_next``: one step, its signals and statistics.
    signal_rows, stat_rows : tuple of int
        Rows of the accumulator holding :data:`SIGNALS` and :data:`STAT_NAMES`.
    nx, nu, np, n_in, n_acc : int
        Sizes of the step's state, command, parameters, a sample's input and the accumulator.
    """

    start: ca.Function
    body: ca.Function
    signal_rows: tuple[int, ...]
    stat_rows: tuple[int, ...]
    nx: int
    nu: int
    np: int
    n_in: int
    n_acc: int


def run_pieces(step: ca.Function, airframe: Airframe, structure: ModelStructure, gusts: bool,
               name: str = "mc_run", feedback: np.ndarray | None = None) -> RunPieces:
    """The start and body of a run (see :func:`run_function`)."""
    nx, n_p = step.size1_in(0), step.size1_in(2)
    nu = structure.nu
    n_in = nu + (N_GUST if gusts else 0)
    names = param_names(structure.kind)
    i_mass, i_g = names.index("mass"), names.index("gravity")
    forces = build_model(structure).forces
    body_limits = list(state_limits(structure.kind).values())  # u, w, q, theta
    lo = ca.DM([b[0] for b in airframe.control_bounds()])
    hi = ca.DM([b[1] for b in airframe.control_bounds()])
    ns = len(STAT_NAMES) - 1  # the divergence time is kept apart
    # accumulator: x, u0, stats, current signals (alpha, V, n), t, t_div, p, dt, limits, xref
    sizes = [nx, nu, ns, 3, 1, 1, n_p, 1, N_LIMITS, 4]
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    acc = ca.SX.sym("acc", int(offsets[-1]))
    x, u0, s, _, t, t_div, p, dt, lim, xr = (acc[int(offsets[i]):int(offsets[i + 1])]
                                             for i in range(len(sizes)))
    inp = ca.SX.sym("in", n_in)
    u = _command(u0 + inp[:nu], x, xr, feedback, lo, hi)
    g = inp[nu:] if gusts else None
    x_next = step(x, ca.vertcat(u, g) if gusts else u, p, dt)
    sig = _signals(forces, x_next, u, g, p, i_mass, i_g)
    theta_abs, alpha, V, n = ca.fabs(sig[0]), sig[2], sig[3], sig[4]
    ok = _inside(x_next, sig, body_limits)
    live = ca.logic_and(ok, t_div < 0)
    stats = ca.vertcat(ca.fmax(s[0], theta_abs), ca.fmax(s[1], alpha), ca.fmin(s[2], V),
                       ca.fmax(s[3], n), ca.fmin(s[4], n),
                       s[5] + dt * (theta_abs > lim[0]), s[6] + dt * (alpha > lim[1]),
                       s[7] + dt * (V < lim[2]), s[8] + dt * (n > lim[3]))
    t_next = t + dt
    acc_next = ca.vertcat(x_next, u0, ca.if_else(live, stats, s), sig[2:], t_next,
                          ca.if_else(ca.logic_and(t_div < 0, ca.logic_not(ok)), t_next, t_div),
                          p, dt, lim, xr)
    body = ca.Function(f"{name}_step", [acc, inp], [acc_next])

    x0, uu0, pp, du0 = (ca.SX.sym(nm, k) for nm, k in (("x0", nx), ("u0", nu), ("p", n_p),
                                                          ("du0", nu)))
    g0, dt0, lim0, xr0 = (ca.SX.sym(nm, k) for nm, k in (("g0", N_GUST), ("dt", 1),
                                                          ("limits", N_LIMITS), ("xref", 4)))
    u_first = _command(uu0 + du0, x0, xr0, feedback, lo, hi)
    sig0 = _signals(forces, x0, u_first, g0 if gusts else None, pp, i_mass, i_g)
    ok0 = _inside(x0, sig0, body_limits)
    s0 = ca.vertcat(ca.fabs(sig0[0]), sig0[2], sig0[3], sig0[4], sig0[4], 0, 0, 0, 0)
    a0 = ca.vertcat(x0, uu0, s0, sig0[2:], 0, ca.if_else(ok0, -1, 0), pp, dt0, lim0, xr0)
    start = ca.Function(f"{name}_start", [x0, uu0, pp, du0, g0, dt0, lim0, xr0], [a0, sig0])
    o = [int(v) for v in offsets]
    return RunPieces(start, body, (o[0] + 3, o[0] + 2, o[3], o[3] + 1, o[3] + 2),
                     tuple(range(o[2], o[3])) + (o[5],), nx, nu, n_p, n_in, o[-1])


def batch_function(run: ca.Function, n_runs: int, threads: int = 1, compile: bool = True,
                   name: str | None = None) -> ca.Function:
    """``run`` mapped over ``n_runs`` runs (inputs side by side; ``du``, ``dt`` and ``limits``
    shared) with CasADi's ``thread`` parallelism on ``threads`` threads, compiled to C (cached
    on disk by content hash; the generated code starts its own POSIX threads).

    Raises
    ------
    ValueError
        If ``n_runs`` or ``threads`` is smaller than 1.
    """
    if n_runs < 1 or threads < 1:
        raise ValueError(f"n_runs and threads must be >= 1, got {n_runs}, {threads}")
    shared = [i for i, nm in enumerate(run.name_in()) if nm in ("du", "dt", "limits")]
    mapped = run.map(name or f"{run.name()}_x{n_runs}_t{threads}", "thread" if threads > 1
                     else "serial", n_runs, shared, [],
                     {"max_num_threads": threads} if threads > 1 else {})
    return compile_function(mapped) if compile else mapped
