"""Starts fitted by a model to the records that follow them, many windows at once.

A run started from one recorded sample carries that sample's noise through its whole horizon
(2 mrad in pitch and 5 mrad/s in pitch rate give about 3 mrad at 1 s, ten times a calm
sortie's model error); comparing two models from such starts, the noise adds an error common
to both, and a learned correction can even earn a gain by damping it out, which makes the
true dynamics worse (issue 40, ``analysis/start_noise.py``). Here each window's start is the
body state that makes the model's own trajectory fit the window's first ``span`` records
best, each channel weighted by its white noise (output-error least squares, Gauss-Newton with
the exact CasADi Jacobian; actuator, delay and memory states come from the commands and are
kept), as output-error identification does for its windows. A start fitted by one model is
biased by that model's own error only, so each model scored gets its own
(:func:`estimate_start` for one free run; the safe trainer's validation windows for the
physics and each candidate correction). Where the model does not explain the span to within
the noise (a gust, a manoeuvre it gets wrong) the record is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from uavdyn.integrate.codegen import compile_function
from uavdyn.integrate.compiler import QUICK_FLAGS
from uavdyn.integrate.discrete import DiscreteModel, model_function
from uavdyn.integrate.rollout import rollout

N_BODY = 4
GAUSS_NEWTON_STEPS = 2
NOISE_FLOOR = 1e-9  # relative to the channel's largest magnitude: noise-free records


@dataclass(frozen=True)
class StartFits:
    """Fitted body states at the window starts and how well the model explains each span."""

    body: np.ndarray      # (W, 4) the start that fits best (the record where not consistent)
    chi2: np.ndarray      # (W,) weighted squared residual per degree of freedom
    span: int             # records fitted per window, its start included

    @property
    def consistent(self) -> np.ndarray:
        """Whether the model explains each span to within the noise (W,): its residual per
        degree of freedom below 1 plus 3 standard deviations of that statistic for white
        noise. Elsewhere the record is the start (:attr:`body`)."""
        dof = max(N_BODY * (self.span - 1), 1)
        return self.chi2 < 1.0 + 3.0 * np.sqrt(2.0 / dof)


def start_fit_function(step: ca.Function, span: int, compiled: bool = True) -> ca.Function:
    """``(body, rest, u[nu x span-1], p, dt, y[4 x span], w[4]) -> (r, J)``: the weighted
    residual of ``step``'s trajectory from ``[body; rest]`` against the records ``y`` (the
    start's own record first) and its Jacobian in ``body``; compiled to C (or the VM with one
    warning where no compiler exists), or left to the VM with ``compiled=False``."""
    nz, nu, n_p = (step.size1_in(i) for i in range(3))
    body, rest = ca.MX.sym("body", N_BODY), ca.MX.sym("rest", nz - N_BODY)
    u, p, dt = ca.MX.sym("u", nu, span - 1), ca.MX.sym("p", n_p), ca.MX.sym("dt")
    y, w = ca.MX.sym("y", N_BODY, span), ca.MX.sym("w", N_BODY)
    states = rollout(step, span - 1)(ca.vertcat(body, rest), u, p, dt)
    traj = ca.horzcat(body, states[:N_BODY, :])
    r = ca.vec((traj - y) * ca.repmat(w, 1, span))
    fit = ca.Function("start_fit", [body, rest, u, p, dt, y, w], [r, ca.jacobian(r, body)],
                      ["body", "rest", "u", "p", "dt", "y", "w"], ["r", "J"])
    return compile_function(fit, QUICK_FLAGS) if compiled else fit


def fit_starts(fit: ca.Function, z0: np.ndarray, u: np.ndarray, y: np.ndarray,
               p: np.ndarray, dt: float, noise: np.ndarray, span: int,
               iterations: int = GAUSS_NEWTON_STEPS, gate: bool = True) -> StartFits:
    """The body state at each window's start that fits the window's first ``span`` records
    best through the step of ``fit`` (:func:`start_fit_function` of the same ``span``).

    Parameters
    ----------
    fit : casadi.Function
        :func:`start_fit_function` of the model's step.
    z0 : ndarray, shape (W, nz)
        The step's state at each start from the records (body states first).
    u : ndarray, shape (W, >= span - 1, nu)
        Each window's commands (row k held over sample k).
    y : ndarray, shape (W, >= span - 1, >= 4)
        Each window's records after each sample.
    p : ndarray, shape (n_p, W)
        Each window's parameters (the step's ``p`` input).
    dt : float
        The sample step.
    noise : ndarray, shape (W, 4)
        White-noise standard deviation of the body states' records (the fit's weights).
    span : int
        Records fitted per window, the start's own included (>= 2).
    iterations : int
        Gauss-Newton steps at most (fewer once every step is below 1e-8 noise deviations).
    gate : bool
        Keep the record where the model does not explain the span
        (:attr:`StartFits.consistent`); without, only a fit that is not finite is refused.

    Returns
    -------
    StartFits
    """
    W, nz = z0.shape
    records = np.concatenate([z0[:, None, :N_BODY], y[:, :span - 1, :N_BODY]], axis=1)
    floor = NOISE_FLOOR * (1.0 + np.max(np.abs(records), axis=(0, 1)))
    weight = 1.0 / np.maximum(np.asarray(noise, float), floor)                 # (W, 4)
    mapped = fit.map(W)
    args = (z0[:, N_BODY:].T, u[:, :span - 1].reshape(W * (span - 1), -1).T,
            np.asarray(p, float), float(dt), records.reshape(W * span, N_BODY).T, weight.T)
    body = z0[:, :N_BODY].copy()
    for _ in range(max(int(iterations), 1)):
        r, J = mapped(body.T, *args)
        r = np.asarray(r).T                                                   # (W, 4 span)
        J = np.asarray(J).reshape(-1, W, N_BODY).transpose(1, 0, 2)           # (W, 4 span, 4)
        JtJ = np.einsum("wrc,wrd->wcd", J, J)  # >= diag(weight^2): the start's own record
        with np.errstate(invalid="ignore", over="ignore"):
            step = -np.linalg.solve(JtJ, np.einsum("wrc,wr->wc", J, r)[..., None])[..., 0]
        body = body + step
        if np.all(np.abs(step) <= 1e-8 * np.abs(1.0 / weight)):
            break
    # the residual at the last step's end, linearised (the spans are short: the trajectory
    # is near-linear in its start, and two steps leave it converged far below the noise)
    with np.errstate(invalid="ignore", over="ignore"):
        r_end = r + np.einsum("wrc,wc->wr", J, step)
        chi2 = np.sum(r_end**2, axis=1) / max(N_BODY * (span - 1), 1)
    chi2 = np.where(np.isfinite(chi2), chi2, np.inf)  # a diverged fit: never consistent
    fits = StartFits(body, chi2, span)
    keep = fits.consistent if gate else np.isfinite(chi2) & np.all(np.isfinite(body), axis=1)
    return StartFits(np.where(keep[:, None], body, z0[:, :N_BODY]), chi2, span)


def with_starts(z0: np.ndarray, fits: StartFits) -> np.ndarray:
    """``z0`` with its body states replaced by the fitted ones."""
    out = np.array(z0, float, copy=True)
    out[:, :N_BODY] = fits.body
    return out


def start_fit_summary(fits: StartFits, z0: np.ndarray, noise: np.ndarray) -> dict:
    """The share of starts fitted and their RMS shift from the records in noise standard
    deviations, for the run's history."""
    ok = fits.consistent
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(noise[ok] > 0, (fits.body[ok] - z0[ok, :N_BODY]) / noise[ok], 0.0)
    rms = np.sqrt(np.mean(shift**2, axis=0)) if len(shift) else np.zeros(N_BODY)
    return {"span_samples": int(fits.span),
            "share_fitted": round(float(np.mean(ok)) if len(ok) else 0.0, 4),
            "rms_shift_in_noise_std": dict(zip(("u", "w", "q", "theta"),
                                               (round(float(v), 3) for v in rms)))}


def estimate_start(step: DiscreteModel | ca.Function, z0, controls, observed, p, dt: float, scale,
                   iterations: int = 8) -> np.ndarray:
    """The start of a free run that best explains the first recorded samples.

    A free run started from one recorded sample carries that sample's noise through the whole
    run (a lightly damped phugoid keeps it for the run's length), and so does every model
    started there: comparing two models' free runs, the start's noise adds an error common to
    both that pulls their ratio towards 1. Fitted through the model to ``n + 1`` samples, the
    start is about ``sqrt(n)`` times less noisy. Output-error least squares on the body states
    (:func:`uavdyn.integrate.start_fit.fit_starts`, one window); the other entries of ``z0``
    (actuator, delay or memory states) are kept.

    Parameters
    ----------
    step : casadi.Function
        ``(z, u, p, dt) -> z_next`` (no time input).
    z0 : array_like, shape (nz,)
        Start from the first recorded sample; its 4 body states are fitted.
    controls : array_like, shape (n, nu)
        Commands held over the first ``n`` intervals.
    observed : array_like, shape (n + 1, >= 4)
        Recorded states at the first ``n + 1`` samples (row 0 is the start's own sample).
    p : array_like
        Parameter vector.
    dt : float
        Step size (one step per sample interval).
    scale : array_like, shape (4,)
        Expected noise of each body state (the residual weights ``1 / scale``), positive.
    iterations : int
        Gauss-Newton iterations at most.

    Returns
    -------
    ndarray, shape (nz,)
        ``z0`` with its body states replaced by the fitted start (kept where the fit is not
        finite).
    """
    z0 = np.asarray(z0, float).ravel()
    controls = np.atleast_2d(np.asarray(controls, float))
    scale = np.asarray(scale, float).ravel()
    if len(scale) != N_BODY:
        raise ValueError(f"scale must give the noise of the {N_BODY} body states, got "
                         f"{len(scale)}")
    n = len(controls)
    observed = np.asarray(observed, float)[:n + 1, :N_BODY]
    fit = start_fit_function(model_function(step), n + 1, compiled=False)
    record = np.concatenate([observed[0], z0[N_BODY:]])  # the start's own sample
    fits = fit_starts(fit, record[None, :], controls[None, :, :], observed[None, 1:, :],
                      np.asarray(p, float).reshape(-1, 1), dt, scale[None, :], n + 1,
                      iterations=iterations, gate=False)
    if not np.isfinite(fits.chi2[0]):
        return z0.copy()
    return np.concatenate([fits.body[0], z0[N_BODY:]])
