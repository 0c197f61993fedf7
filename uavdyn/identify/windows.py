"""Data windows of output-error identification, and the model's predictions over them.

A window is ``L`` samples of one sortie restarted from the recorded body state at its first
sample. What the model sees as commands is data: a transport delay of ``d`` samples is the
recorded command ``d`` samples earlier (the first command before the sortie start, the rest
state of :func:`uavdyn.integrate.augmented.actuator_history`), so the delay buffers of the
augmented step are never unknowns. An actuator lag's state at the window start depends on its
time constant; it is rebuilt from the (delayed) commands of a pre-roll of ``M`` samples before
the window (:meth:`Windows.preroll`), symbolically where the time constant is being fitted.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.identify.errors import IdentifyError
from uavdyn.integrate import compile_function, rollout
from uavdyn.integrate.augmented import actuator_rest, augmented_rk_step, physics_function
from uavdyn.model import sortie_params, structure_of
from uavdyn.model.atmosphere import isa_density_ratio
from uavdyn.model.ops import NUMPY_OPS

N_BODY = 4  # u, w, q, theta: the states compared with the recorded ones


def sortie_altitude(sortie: Sortie) -> float | None:
    """The sortie's altitude for the standard atmosphere (manifest ``altitude_m``; None if the
    manifest does not give one)."""
    entry = sortie.meta.get("manifest_entry", {}) or {}
    value = entry.get("altitude_m", sortie.meta.get("altitude_m"))
    return None if value is None else float(value)


def density_ratio(airframe: Airframe, sortie: Sortie) -> float:
    """Factor on ``rho`` for this sortie: the ISA ratio at its altitude when the airframe's
    atmosphere is ``"isa"`` (sea level without an altitude), else 1."""
    altitude = sortie_altitude(sortie)
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


@dataclass
class Windows:
    """Windows of ``length`` samples: ``starts[w] = (sortie index, first sample)`` into
    ``sorties`` (already subsampled to the grid interval)."""

    sorties: list[Sortie]
    starts: np.ndarray
    length: int

    @property
    def count(self) -> int:
        return len(self.starts)

    @property
    def sortie(self) -> list[str]:
        """The name of the sortie of each window."""
        return [self.sorties[i].name for i, _ in self.starts]

    def subset(self, keep) -> Windows:
        return Windows(self.sorties, self.starts[np.asarray(keep, int)], self.length)

    @property
    def x0(self) -> np.ndarray:
        """Recorded body state at each window start ``(W, 4)``."""
        return np.array([self.sorties[i].states[k] for i, k in self.starts])

    @property
    def y(self) -> np.ndarray:
        """Recorded body states after each sample ``(W, L, 4)``."""
        L = self.length
        return np.array([self.sorties[i].states[k + 1:k + L + 1] for i, k in self.starts])

    @property
    def u(self) -> np.ndarray:
        """Recorded commands, row k held over sample k ``(W, L, nu)``."""
        L = self.length
        return np.array([self.sorties[i].controls[k:k + L] for i, k in self.starts])

    def controls(self, delays) -> np.ndarray:
        """Commands as the delayed model sees them ``(W, L, nu)``."""
        shifted = [delayed_commands(s.controls, delays) for s in self.sorties]
        L = self.length
        return np.array([shifted[i][k:k + L] for i, k in self.starts])

    def preroll(self, samples: int, delays, channels) -> np.ndarray:
        """The (delayed) commands of ``channels`` over the ``samples`` samples before each
        window start ``(W, samples, len(channels))``; before the sortie start, the first
        command (the actuator rests on it)."""
        shifted = [delayed_commands(s.controls, delays)[:, list(channels)] for s in self.sorties]
        out = np.empty((self.count, samples, len(channels)))
        for w, (i, k) in enumerate(self.starts):
            rows = np.maximum(np.arange(k - samples, k), 0)
            out[w] = shifted[i][rows]
        return out

    def density_ratios(self, airframe: Airframe) -> np.ndarray:
        """The ``rho`` factor of each window's sortie ``(W,)``."""
        per = [density_ratio(airframe, s) for s in self.sorties]
        return np.array([per[i] for i, _ in self.starts])


def make_windows(sorties: list[Sortie], window_samples: int, stride: int = 1) -> Windows:
    """Non-overlapping windows of ``window_samples`` grid intervals (every ``stride`` log
    samples) from every sortie, each starting at a recorded state."""
    grid = [s if stride == 1 else Sortie(s.name, s.kind, s.time[::stride], s.states[::stride],
                                         s.controls[::stride], s.mission, s.meta)
            for s in sorties]
    starts = [(i, k) for i, s in enumerate(grid)
              for k in range(0, len(s.states) - window_samples, window_samples)]
    if not starts:
        raise IdentifyError(f"no window of {window_samples} samples fits in the given sorties")
    return Windows(grid, np.array(starts, dtype=int), int(window_samples))


_STEPS: dict = {}
_ACTUATOR_STEPS: dict = {}


@lru_cache(maxsize=64)
def _rollout(step: ca.Function, samples: int) -> ca.Function:
    """``rollout`` of a step over ``samples`` steps, built once per step and length."""
    return rollout(step, samples)


def actuator_states(structure, controls: np.ndarray, p: np.ndarray, sample_dt: float
                    ) -> np.ndarray:
    """The actuator and delay-buffer states at every sample of a recorded command history
    (``N x (n_actuator + n_buffer)``), at rest on the first command: the same numbers as
    :func:`uavdyn.integrate.augmented.actuator_history`, computed by CasADi's loop over the
    step's own actuator update (:func:`~uavdyn.integrate.augmented.augmented_rk_step` with no
    body dynamics) instead of a Python loop (a 60 s sortie: milliseconds, not a quarter
    second)."""
    controls = np.atleast_2d(np.asarray(controls, float))
    n_aug = structure.n_actuator + structure.n_buffer
    if not n_aug or len(controls) < 2:
        return np.tile(actuator_rest(structure, controls[0]), (len(controls), 1))
    if structure not in _ACTUATOR_STEPS:
        z = ca.SX.sym("z", N_BODY + n_aug)
        u, pp, dt = ca.SX.sym("u", structure.nu), ca.SX.sym("p", structure.np), ca.SX.sym("dt")
        z_next = augmented_rk_step(structure, lambda x, ue, pe: x * 0.0, z, u, pp, dt)
        _ACTUATOR_STEPS[structure] = ca.Function("actuators", [z, u, pp, dt], [z_next])
    z0 = np.concatenate([np.zeros(N_BODY), actuator_rest(structure, controls[0])])
    rows = np.array(_rollout(_ACTUATOR_STEPS[structure], len(controls) - 1)(
        z0, controls[:-1].T, p, sample_dt))
    return np.vstack([z0[N_BODY:], rows[N_BODY:].T])


def compiled_step(structure, substeps: int) -> ca.Function:
    """The structure's physics step compiled to C (once per process and structure; the disk
    cache keeps the library across runs)."""
    key = (structure, int(substeps))
    if key not in _STEPS:
        _STEPS[key] = compile_function(physics_function(structure, substeps=substeps),
                                       flags=("-O1", "-fPIC", "-shared"), warn=False)
    return _STEPS[key]


def predict_windows(airframe: Airframe, windows: Windows, sample_dt: float, substeps: int
                    ) -> np.ndarray:
    """The airframe's predicted body states over each window ``(W, L, 4)``: its own discrete
    step (:func:`uavdyn.integrate.physics_step`, ``substeps`` RK steps per sample, actuator
    lags and delay buffers as augmented states) restarted from the recorded state, with the
    actuator and buffer states rebuilt exactly from each sortie's command history, and each
    sortie's density (:func:`uavdyn.model.sortie_params`)."""
    structure = structure_of(airframe)
    starts, params = [], []
    per_sortie = {}
    for i, k in windows.starts:
        if i not in per_sortie:
            s = windows.sorties[i]
            p = sortie_params(airframe, sortie_altitude(s))
            per_sortie[i] = (np.hstack([s.states, actuator_states(structure, s.controls, p,
                                                                    sample_dt)]), p)
        z, p = per_sortie[i]
        starts.append(z[k])
        params.append(p)
    W, L = windows.count, windows.length
    sim = _rollout(compiled_step(structure, substeps), L).map(W, "thread", 2)
    u = windows.u.reshape(W * L, -1).T
    with np.errstate(all="ignore"):
        pred = np.array(sim(np.array(starts).T, u, np.array(params).T, sample_dt))
    return pred[:N_BODY].T.reshape(W, L, N_BODY)


def free_run_sortie(airframe: Airframe, sortie: Sortie, substeps: int) -> np.ndarray:
    """The airframe's open-loop replay of a whole sortie from its first recorded state
    ``(N - 1, 4)`` (states after each sample)."""
    w = Windows([sortie], np.array([[0, 0]]), len(sortie.states) - 1)
    return predict_windows(airframe, w, sortie.dt, substeps)[0]


def window_function(step: ca.Function, n_p: int, tau_indices, rho_index: int | None,
                    length: int, preroll: int, sample_dt: float) -> ca.Function:
    """One window's prediction as an MX Function ``(p, ratio, x0, v, u) -> y (4 x L)``: ``p``
    with ``rho`` times ``ratio`` (the sortie's density factor; ``rho_index`` None: unscaled),
    each lagged actuator started by the exact lag recursion
    ``a_{k+1} = v_k + (a_k - v_k) exp(-T/tau)`` over the pre-roll commands ``v``
    (``n_lag x preroll``, at rest on the first), then ``step`` rolled over the commands ``u``
    (``nu x L``, delays already applied), one call per sample. Without lags there is no ``v``
    input."""
    n_lag = len(tau_indices)
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
        a, e, vk = (ca.MX.sym("a", n_lag), ca.MX.sym("e", n_lag), ca.MX.sym("vk", n_lag))
        lag = ca.Function("lag", [ca.vertcat(a, e), vk], [ca.vertcat(vk + (a - vk) * e, e)])
        decay = ca.exp(-sample_dt / ca.vertcat(*[pw[i] for i in tau_indices]))
        history = lag.mapaccum("preroll", preroll)(ca.vertcat(v[:, 0], decay), v)
        z0 = ca.vertcat(x0, history[:n_lag, -1])
        inputs, names = [*inputs, v], [*names, "v"]
    else:
        z0 = x0
    if z0.size1() != nx:
        raise ValueError(f"step state has {nx} rows; the window builds {z0.size1()} (a delay "
                         "structure must not reach the fitting graph: delays are data here)")
    y = rollout(step, length)(z0, u, pw, sample_dt)[:N_BODY, :]
    return ca.Function("window", [*inputs, u], [y], [*names, "u"], ["y"])
