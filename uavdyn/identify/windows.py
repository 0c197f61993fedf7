"""Data windows of output-error identification, and the model's predictions over them.

A window is ``L`` samples of one sortie restarted from the recorded body state at its first
sample. What the model sees as commands is data: a transport delay of ``d`` samples is the
recorded command ``d`` samples earlier (the first command before the sortie start, the rest
state of :meth:`uavdyn.integrate.StateLayout.history`), so the delay buffers of the
augmented step are never unknowns. An actuator lag's state at the window start depends on its
time constant; it is rebuilt from the (delayed) commands of a pre-roll of ``M`` samples before
the window (:func:`window_preroll`), symbolically where the time constant is being fitted.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import FlightDataError, Sortie, Windows
from uavdyn.flightdata import make_windows as cut_windows
from uavdyn.identify.errors import IdentifyError
from uavdyn.integrate import StateLayout, compile_function, predict_windows, rollout
from uavdyn.integrate.augmented import actuators_after, physics_function
from uavdyn.integrate.compiler import QUICK_FLAGS
from uavdyn.model import ModelStructure, sortie_params, structure_of
from uavdyn.model.atmosphere import isa_density_ratio
from uavdyn.model.ops import CASADI_OPS, NUMPY_OPS

COMPILE_FLAGS = QUICK_FLAGS  # the fit's libraries
N_BODY = 4  # u, w, q, theta: the states compared with the recorded ones


def density_ratio(airframe: Airframe, sortie: Sortie) -> float:
    """Factor on ``rho`` for this sortie: the ISA ratio at its altitude when the airframe's
    atmosphere is ``"isa"`` (sea level without an altitude), else 1."""
    altitude = sortie.altitude_m
    if airframe.atmosphere != "isa" or altitude is None:
        return 1.0
    return float(isa_density_ratio(altitude, NUMPY_OPS))


def delayed_commands(controls: np.ndarray, delays) -> np.ndarray:
    """The commands as a model with transport delays sees them: column ``c`` shifted by
    ``delays[c]`` samples, the first command before the first sample."""
    out = np.array(controls, dtype=float, copy=True)
    n = len(out)
    for c, d in enumerate(delays):
        if d:
            out[:, c] = controls[np.maximum(np.arange(n) - d, 0), c]
    return out


def window_commands(windows: Windows, delays) -> np.ndarray:
    """The windows' commands as the delayed model sees them ``(W, L, nu)``."""
    shifted = [delayed_commands(s.controls, delays) for s in windows.sorties]
    L = windows.length
    return np.array([shifted[i][k:k + L] for i, k in windows.starts])


def window_preroll(windows: Windows, samples: int, delays, channels) -> np.ndarray:
    """The (delayed) commands of ``channels`` over the ``samples`` samples before each window
    start ``(W, samples, len(channels))``; before the sortie start, the first command (the
    actuator rests on it)."""
    shifted = [delayed_commands(s.controls, delays)[:, list(channels)] for s in windows.sorties]
    out = np.empty((windows.count, samples, len(channels)))
    for w, (i, k) in enumerate(windows.starts):
        rows = np.maximum(np.arange(k - samples, k), 0)
        out[w] = shifted[i][rows]
    return out


def window_density_ratios(windows: Windows, airframe: Airframe) -> np.ndarray:
    """The ``rho`` factor of each window's sortie ``(W,)``."""
    per = [density_ratio(airframe, s) for s in windows.sorties]
    return np.array([per[i] for i, _ in windows.starts])


def make_windows(sorties: list[Sortie], window_samples: int, stride: int = 1) -> Windows:
    """Back-to-back windows of ``window_samples`` grid intervals (every ``stride`` log
    samples) from every sortie (:func:`uavdyn.flightdata.make_windows`).

    Raises
    ------
    IdentifyError
        If no window fits in the sorties.
    """
    try:
        return cut_windows(sorties, window_samples, stride)
    except FlightDataError as exc:
        raise IdentifyError(str(exc)) from None


_STEPS: dict = {}
_ACTUATOR_STEPS: dict = {}


def actuator_states(structure, controls: np.ndarray, p: np.ndarray, sample_dt: float
                    ) -> np.ndarray:
    """The actuator and delay-buffer states at every sample of a recorded command history
    (:meth:`uavdyn.integrate.StateLayout.history`, at rest on the first command)."""
    return StateLayout(structure).history(controls, p, sample_dt)


def compiled_step(structure, substeps: int) -> ca.Function:
    """The structure's physics step compiled to C (once per process and structure; the disk
    cache keeps the library across runs)."""
    key = (structure, int(substeps))
    if key not in _STEPS:
        _STEPS[key] = compile_function(physics_function(structure, substeps=substeps),
                                       flags=COMPILE_FLAGS, warn=False)
    return _STEPS[key]


def physics_windows(airframe: Airframe, windows: Windows, sample_dt: float, substeps: int
                    ) -> np.ndarray:
    """The airframe's predicted body states over each window ``(W, L, 4)``: its own discrete
    step (:func:`uavdyn.integrate.physics_step`, ``substeps`` RK steps per sample, actuator
    lags and delay buffers as augmented states) restarted from the recorded state, with the
    actuator and buffer states rebuilt exactly from each sortie's command history, and each
    sortie's density (:func:`uavdyn.model.sortie_params`), by
    :func:`uavdyn.integrate.predict_windows` on two threads."""
    structure = structure_of(airframe)
    layout = StateLayout(structure)
    per_sortie = {}
    starts, params = [], []
    for i, k in windows.starts:
        if i not in per_sortie:
            s = windows.sorties[i]
            p = sortie_params(airframe, s.altitude_m)
            per_sortie[i] = (layout.states(s.states, s.controls, p, sample_dt), p)
        z, p = per_sortie[i]
        starts.append(z[k])
        params.append(p)
    pred = predict_windows(compiled_step(structure, substeps), np.array(starts), windows.u,
                           np.array(params), sample_dt, threads=2)
    return pred[..., :N_BODY]


def window_function(step: ca.Function, structure: ModelStructure, rho_index: int | None,
                    length: int, preroll: int, sample_dt: float) -> ca.Function:
    """One window's prediction as an MX Function ``(p, ratio, x0, v, u) -> y (4 x L)``: ``p``
    with ``rho`` times ``ratio`` (the sortie's density factor; ``rho_index`` None: unscaled),
    each lagged actuator started by the step's own exact actuator recursion (the lag, or the
    rate-limited lag of a slewed control) over the pre-roll commands ``v`` (``n_lag x
    preroll``, at rest on the first), then ``step`` rolled over the commands ``u`` (``nu x L``,
    delays already applied), one call per sample. Without lags there is no ``v`` input."""
    n_lag, n_p = structure.n_actuator, structure.np
    nx, nu = step.size1_in(0), step.size1_in(1)
    p = ca.MX.sym("p", n_p)
    ratio = ca.MX.sym("ratio")
    x0 = ca.MX.sym("x0", N_BODY)
    u = ca.MX.sym("u", nu, length)
    mask = np.zeros(n_p)
    if rho_index is not None:
        mask[rho_index] = 1.0
    pw = p * (1.0 + (ratio - 1.0) * ca.DM(mask))
    inputs, names = [p, ratio, x0], ["p", "ratio", "x0"]
    if n_lag:
        v = ca.MX.sym("v", n_lag, preroll)
        # only the actuators' own parameters ride along (time constants, slew times)
        used = sorted({*structure.tau_indices,
                       *(k for k in structure.slew_indices if k is not None)})
        a, q, vk = ca.SX.sym("a", n_lag), ca.SX.sym("q", len(used)), ca.SX.sym("vk", n_lag)
        commands = [vk[0] * 0.0] * nu  # only the lagged controls' rows are read
        for j, c in enumerate(structure.lag_indices):
            commands[c] = vk[j]
        moved = actuators_after(structure, [a[j] for j in range(n_lag)], commands,
                                {i: q[j] for j, i in enumerate(used)}, sample_dt, CASADI_OPS)
        lag = ca.Function("lag", [ca.vertcat(a, q), vk], [ca.vertcat(*moved, q)])
        history = lag.mapaccum("preroll", preroll)(
            ca.vertcat(v[:, 0], *[pw[i] for i in used]), v)
        z0 = ca.vertcat(x0, history[:n_lag, -1])
        inputs, names = [*inputs, v], [*names, "v"]
    else:
        z0 = x0
    if z0.size1() != nx:
        raise ValueError(f"step state has {nx} rows; the window builds {z0.size1()} (a delay "
                         "structure must not reach the fitting graph: delays are data here)")
    y = rollout(step, length)(z0, u, pw, sample_dt)[:N_BODY, :]
    return ca.Function("window", [*inputs, u], [y], [*names, "u"], ["y"])


def inside_envelope(airframe: Airframe, windows: Windows) -> np.ndarray:
    """Which windows the model's structure can explain: for a fixed wing, those whose angle of
    attack stays below the onset of its stall blend (:func:`stall_onset`; the quasi-steady
    model holds; past it, the flow separates with a lag and hysteresis the model does not
    have). Every multirotor window
    is inside."""
    if airframe.kind != "fixed_wing":
        return np.ones(windows.count, bool)
    x = np.concatenate([windows.x0[:, None, :], windows.y], axis=1)
    alpha = np.arctan2(x[..., 1], x[..., 0])
    return np.max(np.abs(alpha), axis=1) < stall_onset(airframe)


def stall_onset(airframe: Airframe) -> float:
    """The angle of attack where the model's stall blend starts to act: 1 % of the way to
    separated flow, ``alpha0 - ln(99) / M_blend``. Between it and ``alpha0`` the quasi-steady
    blend is already changing the forces, and real separation there lags and overshoots
    (hysteresis), so those windows would bias the attached-flow derivatives."""
    P = airframe.params
    return float(P.alpha0 - math.log(99.0) / max(P.M_blend, 1e-9))


def training_windows(airframe: Airframe, train: list[Sortie], L: int, stride: int,
                      max_windows: int | None, log: dict) -> Windows:
    """The training windows inside the model's envelope (:func:`inside_envelope`), at most
    ``max_windows`` evenly spread over the data; ``log`` records what was left out."""
    w_train = make_windows(train, L, stride)
    inside = inside_envelope(airframe, w_train)
    if not inside.all():
        if not inside.any():
            raise IdentifyError("every training window reaches the stall (the onset of the "
                                "stall blend, alpha = "
                                f"{math.degrees(stall_onset(airframe)):.1f} deg): the model's "
                                "quasi-steady aerodynamics cannot be fitted to these data")
        log["left_out"] = {
            "windows": int((~inside).sum()), "of": int(w_train.count),
            "sorties": sorted({w_train.sorties[i].name for i, _ in
                               np.asarray(w_train.starts)[~inside]}),
            "why": f"angle of attack past the onset of the stall blend, "
                   f"{math.degrees(stall_onset(airframe)):.1f} deg (alpha0 = "
                   f"{math.degrees(airframe.params.alpha0):.1f} deg): dynamic stall (lag and "
                   "hysteresis of the separation) is not in the model and would bias every "
                   "aerodynamic estimate"}
        w_train = w_train.subset(np.flatnonzero(inside))
    if max_windows is not None and w_train.count > max_windows:
        keep = np.unique(np.linspace(0, w_train.count - 1, max_windows).round().astype(int))
        w_train = w_train.subset(keep)
    return w_train


def fit_summary(nominal: Airframe, fitted: Airframe, sorties: list[Sortie], interval: float,
                 substeps: int, L: int, stride: int) -> dict:
    """Pitch RMSE over the windows of each sortie, nominal vs fitted airframe (each with its
    own discrete step: lags, delays and sortie densities included). Where windows reach past
    the stall onset (:func:`inside_envelope`; the fit leaves them out), the same pooled over
    the windows inside too (``theta_rmse_inside``, with the count left out), so a fit that
    improves what it was fitted to is not read as worse because of what it may not model."""
    per, inside_rows, n_out = [], [], 0
    for s in sorties:
        try:
            w = make_windows([s], L, stride)
        except IdentifyError:
            continue  # a sortie shorter than one window
        row = {"sortie": s.name, "condition": s.meta.get("condition", "")}
        inside = inside_envelope(nominal, w)
        n_out += int((~inside).sum())
        inside_row = {}
        for label, af in (("nominal", nominal), ("identified", fitted)):
            err = physics_windows(af, w, interval, substeps)[..., 3] - w.y[..., 3]
            row[f"theta_rmse_{label}"] = _rmse(err)
            if inside.any():
                inside_row[label] = _rmse(err[inside])
        per.append(row)
        if inside_row:
            inside_rows.append(inside_row)
    out = {"per_sortie": per, "theta_rmse": _pooled(per, "theta_rmse_")}
    if n_out and inside_rows:
        out["theta_rmse_inside"] = _pooled(inside_rows, "")
        out["windows_past_stall_onset"] = n_out
    return out


def _rmse(err: np.ndarray) -> float:
    """Root mean square of ``err``; inf where a run left the finite numbers."""
    with np.errstate(all="ignore"):
        value = float(np.sqrt(np.mean(err**2)))
    return value if math.isfinite(value) else math.inf


def _pooled(rows: list[dict], prefix: str) -> dict:
    """The root mean square over sorties of each label's per-sortie RMSE."""
    return {label: float(np.sqrt(np.mean([r[prefix + label] ** 2 for r in rows])))
            if rows else math.nan for label in ("nominal", "identified")}
